"""Thermocouples read a lag of the gas temperature (sheath, junction)."""

from __future__ import annotations

import numpy as np

from ..simulation.parameters import Param
from .base import Effect, Option
from .drawn import Drawn
from .tried import Tried


class TriedSensorLag(Tried):
    def candidate_for(self, furnace):
        return {} if furnace.paper_structure else {"zones": furnace.zones}


class DrawnSensorLag(Drawn):
    def draw(self, rng, form, duration_min, furnace):
        order = int(rng.integers(2, 4)) if form == "other" else 1
        if furnace.paper_structure:
            effect = self.effect(order=order, furnace=furnace)
        else:
            # one zone's thermocouples (a lagging thermocouple where the zone has one)
            zone = furnace.zones[int(rng.integers(furnace.n_zones))]
            effect = self.effect(order=order, zones=(zone,), furnace=furnace)
        return effect, {"tau_lag": self.uniform(rng, "tau_lag")}


class SensorLag(Effect):
    """The thermocouples of some zones (every zone by default) read a lag of their zone.

    The model reads a zone through the mean of its thermocouples, so a lag is a zone's: on
    a zone of one thermocouple it is that thermocouple's; a single lagging thermocouple of a
    pair shows as a lag of the pair's mean, which is not first-order."""

    name = "sensor_lag"
    physics = "thermocouples read a first-order lag of the zone gas temperature"
    option_specs = {"order": Option(1, "integer", lo=1, hi=4, doc="cascaded stages")}
    # A lag shared by the zones of a larger furnace does not fit one lagging zone (one time
    # constant for six zones that mostly have none): one place at a time.
    tried = TriedSensorLag(null={"tau_lag": 0.0}, one_place_at_a_time=True)
    drawn = DrawnSensorLag(ranges={"tau_lag": (4.0, 20.0)})

    @classmethod
    def specs(cls, furnace):
        """Eq. 11's network: every zone lags, with the options and JSON of the contract;
        any other: `zones`, whose thermocouples lag."""
        if furnace.paper_structure:
            return cls.option_specs
        z = furnace.zones
        return {**cls.option_specs,
                "zones": Option(z, "choices", choices=z, doc="zones whose thermocouples lag")}

    @classmethod
    def physics_for(cls, furnace):
        return cls.physics if furnace.paper_structure else (
            "a zone's thermocouples read a first-order lag of its gas temperature")

    def _params(self):
        return (Param("tau_lag", 2.0, 0.01, 120.0, unit="min", doc="thermocouple time constant"),)

    @property
    def _lagged(self) -> list[int]:
        zones = self.options.get("zones", self.furnace.zones)
        return [self.furnace.zones.index(z) for z in zones]

    @property
    def state_zones(self):
        return tuple(z for _ in range(self.options["order"]) for z in self._lagged)

    def extend(self, A, B, C, theta, first):
        # `order` cascaded stages (sheath, then junction) whose time constants add up to
        # tau_lag: the same mean delay, a sharper lag. Unequal stages keep A diagonalisable.
        order = self.options["order"]
        shares = np.arange(1, order + 1, dtype=float)
        shares /= shares.sum()
        lagged = self._lagged
        for j, z in enumerate(lagged):
            prev = z
            for k in range(order):
                i = first + len(lagged) * k + j
                rate = 1.0 / (shares[k] * theta["tau_lag"])
                A[:, i, i] -= rate
                A[:, i, prev] += rate
                prev = i
            C[:, z, :] = 0.0
            C[:, z, prev] = 1.0
