"""The fleet's jobs, one module each. The command line lists this package's modules without
importing the heavy ones: a job module imports pandas, Dask and the model only inside its
functions, so `furnace-daq fleet --help` stays fast."""

from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType


def names() -> list[str]:
    """The jobs, in the order `furnace-daq fleet --help` lists them."""
    found = [m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")]
    order = {"refit": 0, "diagnose": 1, "selfcheck": 2}
    return sorted(found, key=lambda n: (order.get(n, len(order)), n))


def module(name: str) -> ModuleType:
    return importlib.import_module(f"{__name__}.{name}")
