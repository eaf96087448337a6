"""One thermocouple of a pair drifts away from its partner."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from .. import SENSORS, ZONES
from ..parameters import Param
from .base import Clues, Effect, Option, Trial

if TYPE_CHECKING:
    from ..experiment import Experiment

MAX_RATE = 0.2
"""°C/min: a drift faster than 12 °C an hour is a broken thermocouple, not a drift."""


class SensorDrift(Effect):
    name = "sensor_drift"
    physics = "one thermocouple of a pair drifts away from its partner"
    option_specs = {"sensor": Option("heat_2", "choice", choices=SENSORS,
                                         doc="the drifting thermocouple")}
    null = {"drift_rate": 0.0}
    ranges = {"drift_rate": (0.005, 0.03), "t_drift_frac": (0.15, 0.6)}

    def _params(self):
        return (
            Param("drift_rate", 0.01, -1.0, 1.0, log=False, unit="°C/min",
                  doc="rate at which the sensor's error grows"),
            Param("t_drift", 0.0, 0.0, 1e6, log=False, unit="min", doc="when the drift starts"),
        )

    def sensor_offsets(self, theta, t):
        P = theta["drift_rate"].shape[0]
        out = np.zeros((P, t.size, len(SENSORS)))
        ramp = np.maximum(t[None, :] - theta["t_drift"][:, None], 0.0)
        out[:, :, SENSORS.index(self.options["sensor"])] = theta["drift_rate"][:, None] * ramp
        return out

    @classmethod
    def trial(cls, clues: Clues) -> Trial:
        """On the thermocouple found drifting, from the onset and rate of the hinge fitted to
        its pair's difference; else on the one whose pair's difference changes most."""
        for f in clues.faults:
            if f.kind == "drift":
                exp = clues.records[f.experiment]
                t0, t1 = float(exp.t_min[f.i0]), float(exp.t_min[-1])
                return Trial({"sensor": f.sensor},
                             {"t_drift": t0, "drift_rate": f.size_c / max(t1 - t0, 1.0)})
        return Trial({"sensor": most_changed_pair(clues.records)})

    @classmethod
    def search_bounds(cls, fit_data):
        """The onset lies within the fitted records (minutes from each record's start)."""
        return {"t_drift": (min(float(e.t_min[0]) for e in fit_data),
                            max(float(e.t_min[-1]) for e in fit_data)),
                "drift_rate": (-MAX_RATE, MAX_RATE)}

    @classmethod
    def draw(cls, rng, form, duration_min):
        effect = cls(sensor=SENSORS[int(rng.integers(len(SENSORS)))])
        sign = 1.0 if rng.uniform() < 0.5 else -1.0
        return effect, {"drift_rate": sign * cls.uniform(rng, "drift_rate"),
                        "t_drift": round(cls.uniform(rng, "t_drift_frac") * duration_min)}


def most_changed_pair(records: Sequence[Experiment]) -> str:
    """The second thermocouple of the pair whose difference changes most from a record's
    start to its end (for the zone mean either of a pair is the same candidate, with the
    sign of the rate flipped)."""
    best, name = -1.0, "heat_2"
    for w, z in enumerate(ZONES):
        for e in records:
            pair = e.tc[:, 2 * w:2 * w + 2]
            ok = np.all(np.isfinite(pair), axis=1)
            if ok.sum() < 50:
                continue
            d = pair[ok, 0] - pair[ok, 1]
            n = d.size // 5
            change = abs(np.median(d[-n:]) - np.median(d[:n]))
            if change > best:
                best, name = change, f"{z}_2"
    return name
