"""The builders of deb/build_deb.py (the wheel from this tree, the Debian package), for the
tests of what an installation carries (test_wheel, test_deb). deb/ is not a package: the
script is loaded from its file."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_spec = importlib.util.spec_from_file_location("build_deb", ROOT / "deb" / "build_deb.py")
build_deb = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(build_deb)

build_wheel = build_deb.build_wheel


def shipped_in_tree() -> list[str]:
    """The files the wheel must ship: every file of config/ and the systemd unit, by their
    paths in the repository."""
    return sorted(p.relative_to(ROOT).as_posix()
                  for p in [*(ROOT / "config").rglob("*"), *(ROOT / "systemd").glob("*")]
                  if p.is_file())
