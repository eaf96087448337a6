"""Zones besides preheating lose heat to ambient through their walls (the paper: only the
preheating zone, eq. 6)."""

from __future__ import annotations

from .. import ZONES
from ..parameters import Param
from .base import U_AIR, Effect, Option

LOSING = ("soak", "heat")


class ZoneLosses(Effect):
    name = "zone_losses"
    physics = "a zone besides preheating loses heat to ambient through its walls"
    option_specs = {"zones": Option(LOSING, "choices", choices=ZONES,
                                        doc="zones that lose heat (soak, heat)")}
    null = {"g_soak": 0.0, "g_heat": 0.0}
    ranges = {"g": (0.002, 0.01)}

    def _params(self):
        bad = [z for z in self.options["zones"] if z not in LOSING]
        if bad:
            raise ValueError(f"zone_losses applies to soak and heat, not {bad}")
        return tuple(Param(f"g_{z}", 0.002, 1e-6, 1.0, doc=f"{z}-zone wall loss rate to ambient")
                     for z in self.options["zones"])

    @classmethod
    def options_from_params(cls, given):
        zones = tuple(z for z in LOSING if f"g_{z}" in given)
        return {"zones": zones} if zones else {}

    def extend(self, A, B, C, theta, first):
        for z in self.options["zones"]:
            i, g = ZONES.index(z), theta[f"g_{z}"]
            A[:, i, i] -= g
            B[:, i, U_AIR] += g

    @classmethod
    def draw(cls, rng, form, duration_min):
        zones = (("soak",), ("heat",))[int(rng.integers(2))] if form == "other" else LOSING
        return cls(zones=zones), {f"g_{z}": cls.uniform(rng, "g") for z in zones}
