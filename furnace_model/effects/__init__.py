"""The unmodelled effects of CONTRACTS.md section 4, one class in one module each, and the
registry that the plant simulator, the scenario loader, the diagnosis and the selfcheck
read. A furnace's own effect is written the same way in the user's file and registered by
`plugins.load_file` or an installed package's `furnace_model.effects` entry point."""

from __future__ import annotations

from .base import KELVIN, Clues, Drawn, Effect, Option, Theta, Trial, Tried
from .burner_nonlinearity import BurnerNonlinearity
from .dead_time import DeadTime
from .fuel_change import FuelChange
from .radiation import Radiation
from .sensor_drift import SensorDrift
from .sensor_lag import SensorLag
from .wall_storage import WallStorage
from .zone_burners import ZoneBurners
from .zone_losses import ZoneLosses

EFFECTS: dict[str, type[Effect]] = {cls.name: cls for cls in (
    ZoneBurners, ZoneLosses, SensorLag, DeadTime, WallStorage, Radiation,
    BurnerNonlinearity, FuelChange, SensorDrift)}
"""Every registered effect by name: the contract's nine in the contract's order, then the
plug-ins in the order they were loaded."""

BUILT_IN: tuple[str, ...] = tuple(EFFECTS)

_PAPER_CHANNELS = {"U_BURNERS": slice(0, 3), "U_AIR": 3, "N_INPUTS": 4}
"""The paper's furnace's input channels, for plug-ins that address them by number; an effect
reads its own furnace's from `Effect.u_burners`, `u_air`, `n_inputs`."""


def __getattr__(name: str) -> object:
    if name in _PAPER_CHANNELS:
        import warnings

        warnings.warn(f"furnace_model.effects.{name} is the paper's furnace's input channel; "
                      f"an effect reads its own furnace's from self.{name.lower()}",
                      DeprecationWarning, stacklevel=2)
        return _PAPER_CHANNELS[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

__all__ = ["BUILT_IN", "EFFECTS", "KELVIN", "Clues", "Drawn", "Effect", "Option", "Theta",
           "Trial", "Tried",
           "BurnerNonlinearity", "DeadTime", "FuelChange",
           "Radiation", "SensorDrift", "SensorLag", "WallStorage", "ZoneBurners", "ZoneLosses"]
