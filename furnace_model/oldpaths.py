"""Module paths from before the package was split into identification, simulation and log:
plug-ins and scripts written against them (`from furnace_model.lti import Drive`) keep
working, with a DeprecationWarning naming the new path.

A finder on `sys.meta_path` answers only for these names, and hands back the module at its
new path, so the old and the new name are one module object: nothing is loaded twice.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

MOVED: dict[str, str] = {
    "logschema": "log.schema",
    "logread": "log.read",
    "logresample": "log.resample",
    "logsalvage": "log.salvage",
    "logexperiment": "log.experiment",
    "furnace": "simulation.furnace",
    "network": "simulation.network",
    "parameters": "simulation.parameters",
    "lti": "simulation.lti",
    "response": "simulation.response",
    "structure": "simulation.structure",
    "plant": "simulation.plant",
    "scenario": "simulation.scenario",
    "fit": "identification.fit",
    "ga": "identification.ga",
    "profile": "identification.profile",
    "uncertainty": "identification.uncertainty",
    "criteria": "identification.criteria",
    "equationerror": "identification.equationerror",
    "carried": "identification.carried",
    "prediction": "identification.prediction",
    "scores": "identification.scores",
    "autoregression": "identification.autoregression",
    "plausible": "identification.plausible",
    "noisefloor": "identification.noisefloor",
    "residuals": "identification.residuals",
    "selfcheck": "diagnosis.selfcheck",
}
"""Old name under `furnace_model` -> new name under it."""


class _OldPaths(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    def find_spec(self, fullname, path=None, target=None):
        prefix, _, rest = fullname.partition(".")
        if prefix != "furnace_model" or rest not in MOVED:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec):
        new = f"furnace_model.{MOVED[spec.name.partition('.')[2]]}"
        warnings.warn(f"{spec.name} is now {new}", DeprecationWarning, stacklevel=2)
        return importlib.import_module(new)

    def exec_module(self, module) -> None:
        """The module at its new path is already executed."""


def install() -> None:
    if not any(isinstance(f, _OldPaths) for f in sys.meta_path):
        sys.meta_path.append(_OldPaths())
