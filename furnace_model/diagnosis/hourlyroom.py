"""A record shaped like a measured building's, with known truth: one zone, one sensor, hourly
rows over weeks, a heat input modulated every hour and a measured disturbance (solar gain)
that moves every hour. The plant runs by the minute with each input held for its hour, as
the record logs it, so that the model is the plant's and its intervals can be held to the
truth; what is hourly is only what the record keeps."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from ..effects import EFFECTS
from ..experiment import Experiment
from ..simulation.furnacefile import parse_furnace
from ..simulation.plant import Plant
from ..simulation.scenario import SensorSpec
from ..simulation.structure import Inputs, ModelStructure

ROOM = """
name: room
zones:
  - {name: room, burners: 1, thermocouples: 1, heat: {kind: rate, unit: kW, max: 12}}
disturbances:
  - {name: solar, unit: W/m2, zones: [room], range: [0, 1000]}
"""
"""The room's description (the furnace-file format)."""

TRUTH = {"loss_room": 1 / 1500, "gain_room": 2.2e-3, "gain_solar_room": 5e-6}
"""The baseline's true values: a loss of 1/1500 per minute, a heating gain, the sun's."""

EFFECT_TRUTH = {"wall_storage": {"k_gw": 2e-3, "k_wg": 6e-4}, "sensor_lag": {"tau_lag": 45.0}}
"""The values of the effects a room record can carry: a heavy wall, a sensor in a housing."""


def hourly_room(seed: int, effects: tuple[str, ...] = (), days: int = 28,
                sample_min: int = 60, values: Mapping[str, float] | None = None
                ) -> Experiment:
    """A heated room: heating modulated every hour around a daily cycle, sun by day with the
    weather of the day, ambient in a daily cycle; `effects` among EFFECT_TRUTH's, `values`
    true values over TRUTH's and theirs.
    `sample_min` below 60: a row every so many minutes, and the heating moved with each row
    (a controller modulating it), so that every row is an input change."""
    unknown = [e for e in effects if e not in EFFECT_TRUTH]
    if unknown:
        raise ValueError(f"a room record carries {sorted(EFFECT_TRUTH)}, not {unknown}")
    held = min(sample_min, 60)
    if sample_min < 1 or 60 % held:
        raise ValueError(f"sample_min {sample_min}: rows every whole minutes that divide an hour")
    furnace = parse_furnace(ROOM)
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, days * 1440 + 1)
    hours = np.floor(t / 60)
    heat = np.clip(6 + 3 * np.sin(2 * np.pi * np.floor(t / held) / (1440 // held) + 1)
                   + np.repeat(rng.normal(0, 1.5, t.size // held + 1), held)[:t.size], 0, 12)
    sun = np.clip(800 * np.sin(2 * np.pi * (hours % 24 - 6) / 24), 0, None) \
        * np.repeat(rng.uniform(0.3, 1.0, t.size // 1440 + 1), 1440)[:t.size]
    air = 5 + 5 * np.sin(2 * np.pi * hours / 24 - 2)
    inputs = Inputs.from_samples(t, heat[:, None], air, disturbances=sun[:, None])
    structure = ModelStructure([EFFECTS[e](zones=("room",), furnace=furnace) for e in effects],
                               furnace=furnace)
    truth = {**structure.defaults(), **TRUTH}
    for e in effects:
        truth.update(EFFECT_TRUTH[e])
    truth.update(values or {})
    plant = Plant(structure, truth, SensorSpec(noise_sd_c=0.05, bias_sd_c=0.1), seed)
    run = plant.run(inputs, np.arange(0.0, days * 1440 + 1, float(sample_min)), np.array([18.0]),
                    pd.Timestamp("2026-01-05T00:00:00Z"))
    return run.to_experiment(f"room-{seed}")
