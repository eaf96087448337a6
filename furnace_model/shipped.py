"""The files the product ships beside its code, found the same way from a clone and from an
installed wheel: furnace descriptions, scenarios, example gateway configs, the Foxglove
layout and the systemd unit.

The repository's config/ and systemd/ are their one source. furnace_model/shipped_files/
holds two links to them (config, systemd), and pyproject.toml declares what lies behind the
links as package data, so a wheel carries the same files under the same relative paths. A
file is therefore named by its path in the repository (`config/furnaces/paper.yaml`) and
read through importlib.resources, whatever the install: a source tree on PYTHONPATH, an
editable install or a wheel in site-packages.

The daemon's half uses this module too (its example configs, the unit): furnace_daq may
import furnace_model, and the files are one set.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from .errors import FurnaceError

FURNACES = "config/furnaces"
"""The shipped furnace descriptions, named by their stem (`six-zone`)."""

SCENARIOS = "config/scenarios"
"""The shipped scenarios, named by their stem (`paper_exp1`)."""


def shipped(relative: str) -> Path:
    """A shipped file or directory by its path in the repository (`config/gateway.yaml`,
    `systemd/furnace-daq.service`). Package data is read in place, which needs the package
    on a file system: pip unpacks wheels, so only a zipped import is refused."""
    root = files(__package__).joinpath("shipped_files")
    if not isinstance(root, Path):
        raise FurnaceError(f"{__package__} is imported from an archive ({root}): install it "
                           "with pip so that its shipped files are on disk")
    return root.joinpath(relative)


def shipped_names(directory: str) -> list[str]:
    """The names of the YAML files shipped in `directory` (FURNACES, SCENARIOS), sorted."""
    return sorted(p.stem for p in shipped(directory).glob("*.yaml"))


def shipped_named(directory: str, name: str) -> Path | None:
    """The file `name` names in the shipped `directory`, with or without its .yaml; None
    when there is none (the caller says what it was looking for)."""
    if not name or Path(name).name != name:  # a path, not a name
        return None
    folder = shipped(directory)
    for candidate in (folder / name, folder / f"{name}.yaml"):
        if candidate.is_file():
            return candidate
    return None
