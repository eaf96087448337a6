"""The optional parts of the installation (pyproject.toml's extras), and the one message a
command gives when it needs one that is not installed.

The gateway's daemon installs with `pip install furnace-daq` alone: polling, logging and
the online refit need none of the extras, which weigh far more than the daemon (dask,
pyarrow and matplotlib add about 300 MB to its 420 MB; docs/operations.md). A command that needs one checks
before it starts its work, so that an operator reads which extra to install instead of an
ImportError's traceback, and a long job never fails at its last step.
"""

from __future__ import annotations

import sys
from importlib.util import find_spec

from .errors import FurnaceError

DISTRIBUTION = "furnace-daq"

EXTRAS: dict[str, tuple[str, ...]] = {
    "parquet": ("pyarrow",),
    "report": ("matplotlib",),
    "fleet": ("dask", "distributed", "pyarrow", "matplotlib"),
}
"""Each extra and the modules a command checks for it (pyproject.toml lists the
distributions; `fleet` includes `report` and `parquet`: its jobs write both)."""


class MissingExtra(FurnaceError):
    """A command needs an extra that is not installed."""

    def __init__(self, extra: str, what: str, missing: list[str]):
        self.extra = extra
        super().__init__(f"{what} needs {', '.join(missing)}, which this installation lacks: "
                         f"install {DISTRIBUTION}[{extra}] (pip install "
                         f"'{DISTRIBUTION}[{extra}]')")


def missing(extra: str) -> list[str]:
    """The modules of `extra` that cannot be imported here."""
    return [name for name in EXTRAS[extra] if not _importable(name)]


def _importable(name: str) -> bool:
    if name in sys.modules:  # None there is Python's mark of an import refused
        return sys.modules[name] is not None
    return find_spec(name) is not None


def require(extra: str, what: str) -> None:
    """Raise MissingExtra naming `extra` when `what` (the command or output that needs it,
    as the user named it) cannot run in this installation."""
    lacking = missing(extra)
    if lacking:
        raise MissingExtra(extra, what, lacking)
