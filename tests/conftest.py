"""Shared fixtures: paths and small known-truth data sets."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "config" / "scenarios"


@pytest.fixture
def root() -> Path:
    return ROOT


@pytest.fixture
def scenarios() -> Path:
    return SCENARIOS


FIRST = ("test_coverage.py",)
"""Modules that take a minute or more on one worker: collected first, so that pytest-xdist
(`--dist loadfile`, which hands out modules in collection order) starts them at once and
the rest of the suite runs beside them, not after them on an otherwise idle core."""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: item.path.name not in FIRST)
