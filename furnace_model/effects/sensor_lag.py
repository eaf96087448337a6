"""Thermocouples read a lag of the gas temperature (sheath, junction)."""

from __future__ import annotations

import numpy as np

from ..parameters import Param
from .base import Effect, Option


class SensorLag(Effect):
    name = "sensor_lag"
    physics = "thermocouples read a first-order lag of the zone gas temperature"
    option_specs = {"order": Option(1, "integer", lo=1, hi=4, doc="cascaded stages")}
    null = {"tau_lag": 0.0}
    ranges = {"tau_lag": (4.0, 20.0)}

    def _params(self):
        return (Param("tau_lag", 2.0, 0.01, 120.0, unit="min", doc="thermocouple time constant"),)

    @property
    def state_zones(self):
        return tuple(z for _ in range(self.options["order"]) for z in range(3))

    def extend(self, A, B, C, theta, first):
        # `order` cascaded stages (sheath, then junction) whose time constants add up to
        # tau_lag: the same mean delay, a sharper lag. Unequal stages keep A diagonalisable.
        order = self.options["order"]
        shares = np.arange(1, order + 1, dtype=float)
        shares /= shares.sum()
        for z in range(3):
            prev = z
            for k in range(order):
                i = first + 3 * k + z
                rate = 1.0 / (shares[k] * theta["tau_lag"])
                A[:, i, i] -= rate
                A[:, i, prev] += rate
                prev = i
            C[:, z, :] = 0.0
            C[:, z, prev] = 1.0

    @classmethod
    def draw(cls, rng, form, duration_min):
        effect = cls(order=int(rng.integers(2, 4)) if form == "other" else 1)
        return effect, {"tau_lag": cls.uniform(rng, "tau_lag")}
