"""Zones besides those the furnace description has losing heat lose heat to ambient through
their walls (the paper: only the preheating zone, eq. 6)."""

from __future__ import annotations

from ..simulation.furnace import PAPER, Furnace
from ..simulation.parameters import Param
from .base import Effect, Option

ZONES = PAPER.zones
LOSING = ("soak", "heat")
"""The paper's zones that do not lose heat to ambient in its model."""


def losing(furnace: Furnace) -> tuple[str, ...]:
    """The zones the description does not have losing heat to ambient: where this effect
    can add a loss."""
    return tuple(z for i, z in enumerate(furnace.zones) if i not in furnace.ambient)


class ZoneLosses(Effect):
    name = "zone_losses"
    physics = "a zone besides preheating loses heat to ambient through its walls"
    option_specs = {"zones": Option(LOSING, "choices", choices=ZONES,
                                        doc="zones that lose heat (soak, heat)")}
    null = {"g_soak": 0.0, "g_heat": 0.0}
    ranges = {"g": (0.002, 0.01)}
    zone_affine = True
    one_place_at_a_time = True
    """On a larger furnace one zone's wall loss, fitted as a loss in every zone that might
    lose heat, spreads over zones that do not and is not found (seen on the six-zone
    furnace: losses on all four, the gap left unexplained)."""

    @classmethod
    def refusal(cls, furnace):
        if not losing(furnace):
            return "every zone of it already loses heat to ambient (its `ambient` list)"
        return None

    @classmethod
    def specs(cls, furnace):
        if furnace == PAPER:
            return cls.option_specs
        z = losing(furnace)
        return {"zones": Option(z, "choices", choices=furnace.zones,
                                doc=f"zones that lose heat ({', '.join(z)})")}

    @classmethod
    def physics_for(cls, furnace):
        if furnace == PAPER:
            return cls.physics
        ambient = [furnace.zones[i] for i in furnace.ambient]
        return (f"a zone besides {' and '.join(ambient)} loses heat to ambient through its "
                "walls")

    @property
    def nulls(self):
        return {f"g_{z}": 0.0 for z in self.options["zones"]}

    def _params(self):
        allowed = losing(self.furnace)
        bad = [z for z in self.options["zones"] if z not in allowed]
        if bad:
            raise ValueError(f"zone_losses applies to {' and '.join(allowed)}, not {bad}")
        self.options["zones"] = tuple(z for z in self.furnace.zones if z in self.options["zones"])
        return tuple(Param(f"g_{z}", 0.002, 1e-6, 1.0, doc=f"{z}-zone wall loss rate to ambient")
                     for z in self.options["zones"])

    @classmethod
    def options_from_params(cls, given):
        zones = tuple(z[2:] for z in given if z.startswith("g_"))
        return {"zones": zones} if zones else {}

    def extend(self, A, B, C, theta, first):
        for z in self.options["zones"]:
            i, g = self.furnace.zones.index(z), theta[f"g_{z}"]
            A[:, i, i] -= g
            B[:, i, self.u_air] += g

    @classmethod
    def draw(cls, rng, form, duration_min, furnace=PAPER):
        """The paper's furnace: both its zones in the candidate's form, one in the other;
        any other: one zone (the one whose walls lose heat)."""
        if furnace == PAPER:
            zones = (("soak",), ("heat",))[int(rng.integers(2))] if form == "other" else LOSING
        else:
            can = losing(furnace)
            zones = (can[int(rng.integers(len(can)))],)
        return cls(zones=zones, furnace=furnace), {f"g_{z}": cls.uniform(rng, "g")
                                                    for z in zones}
