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
    """Whether `name` is a registered effect; an unknown one first loads the installed
    plug-ins, which costs their imports only when a name needs them."""
    if name in EFFECTS or name in PLUGGED:
        return True
    sync_plugins(installed=True)
    return name in PLUGGED


def sync_plugins(installed: bool = False) -> None:
    """Mirror the library's registry after plug-ins were loaded (and load the installed ones)."""
    from ..effects import EFFECTS as REGISTERED
    from ..effects import plugins

    if installed:
        plugins.load_installed()
    PLUGGED[:] = [n for n in REGISTERED if n not in EFFECTS]

OUT_OF_LIBRARY: tuple[str, ...] = ("door_open", "tc_reads_low")
"""`furnace_model.selfcheck.OUT_OF_LIBRARY`: perturbations no candidate expresses."""

NOISE: tuple[str, ...] = ("white", "low-pass", "noisier-holdout")
"""`furnace_model.selfcheck.NOISE`: the thermocouples a selfcheck case may have."""

METHODS: tuple[str, ...] = ("fast", "ga")
"""`furnace_model.fit.METHODS`."""
