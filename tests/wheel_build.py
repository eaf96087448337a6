"""The wheel as `pip wheel` builds it from this tree, for the tests of what an installation
carries (test_wheel, test_deb).

Built from a copy of the tree's sources: setuptools writes build/ and *.egg-info beside the
sources it builds, and two test workers building in the checkout at once would share them."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "README.md", "furnace_model", "furnace_daq", "config", "systemd")
"""What the build reads: the packages, and the directories their links lead to."""


def build_wheel(work: Path) -> Path:
    """Build the wheel into `work`/dist (no network: no build isolation, no dependencies)."""
    tree = work / "tree"
    tree.mkdir(parents=True)
    for name in SOURCES:
        source = ROOT / name
        if source.is_dir():
            shutil.copytree(source, tree / name, symlinks=True,
                            ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(source, tree / name)
    dist = work / "dist"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps",
                    "--no-build-isolation", "--wheel-dir", str(dist), str(tree)],
                   check=True, capture_output=True, text=True, timeout=120)
    (wheel,) = dist.glob("furnace_daq-*.whl")
    return wheel


def shipped_in_tree() -> list[str]:
    """The files the wheel must ship: every file of config/ and the systemd unit, by their
    paths in the repository."""
    return sorted(p.relative_to(ROOT).as_posix()
                  for p in [*(ROOT / "config").rglob("*"), *(ROOT / "systemd").glob("*")]
                  if p.is_file())
