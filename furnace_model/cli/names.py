"""Names the command line lists in `--help` and checks while reading arguments. The library
modules that define them load numpy and scipy, which would make `--help` several times
slower than the 0.3 s it promises, so they are repeated here; tests/test_cli_surface.py holds
each equal to its source."""

from __future__ import annotations

EFFECTS: tuple[str, ...] = (
    "zone_burners", "zone_losses", "sensor_lag", "dead_time", "wall_storage", "radiation",
    "burner_nonlinearity", "fuel_change", "sensor_drift")
"""`furnace_model.effects.BUILT_IN`: the contract's effect names, in its order."""

PLUGGED: list[str] = []
"""Effects of plug-ins registered in this process (--effects-from, installed packages)."""


def effect_names() -> tuple[str, ...]:
    return EFFECTS + tuple(PLUGGED)


def is_effect(name: str) -> bool:
    """Whether `name` is a registered effect or an installed plug-in's (entry points are
    named as their effects: read without loading them, or any library)."""
    if name in EFFECTS or name in PLUGGED:
        return True
    from importlib.metadata import entry_points

    return any(ep.name == name for ep in entry_points(group="furnace_model.effects"))


def sync_plugins(installed: bool = False) -> None:
    """Mirror the library's registry after plug-ins were loaded (and load the installed ones)."""
    from ..effects import EFFECTS as REGISTERED
    from ..effects import plugins

    if installed:
        plugins.load_installed()
    PLUGGED[:] = [n for n in REGISTERED if n not in EFFECTS]

OUT_OF_LIBRARY: tuple[str, ...] = ("door_open", "tc_reads_low")
"""`furnace_model.diagnosis.cases.OUT_OF_LIBRARY`: perturbations no candidate expresses."""

NOISE: tuple[str, ...] = ("white", "low-pass", "noisier-holdout")
"""`furnace_model.diagnosis.cases.NOISE`: the thermocouples a selfcheck case may have."""

METHODS: tuple[str, ...] = ("fast", "ga")
"""`furnace_model.identification.fit.METHODS`."""
