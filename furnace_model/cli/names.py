"""Names the command line lists in `--help` and checks while reading arguments. The library
modules that define them load numpy and scipy, which would make `--help` several times
slower than the 0.3 s it promises, so they are repeated here; tests/test_cli_surface.py holds
each equal to its source."""

from __future__ import annotations

EFFECTS: tuple[str, ...] = (
    "zone_burners", "zone_losses", "sensor_lag", "dead_time", "wall_storage", "radiation",
    "burner_nonlinearity", "fuel_change", "sensor_drift")
"""`furnace_model.effects.EFFECTS`: the contract's effect names, in its order."""

OUT_OF_LIBRARY: tuple[str, ...] = ("door_open", "tc_reads_low")
"""`furnace_model.selfcheck.OUT_OF_LIBRARY`: perturbations no candidate expresses."""

NOISE: tuple[str, ...] = ("white", "low-pass", "noisier-holdout")
"""`furnace_model.selfcheck.NOISE`: the thermocouples a selfcheck case may have."""

METHODS: tuple[str, ...] = ("fast", "ga")
"""`furnace_model.fit.METHODS`."""
