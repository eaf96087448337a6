"""Zones besides those the furnace description has losing heat lose heat to ambient through
their walls (the paper: only the preheating zone, eq. 6)."""

from __future__ import annotations

from ..simulation.furnace import Furnace
from ..simulation.parameters import Param
from .base import Effect, Option
from .drawn import Drawn
from .tried import Tried


def losing(furnace: Furnace) -> tuple[str, ...]:
    """The zones the description does not have losing heat to ambient: where this effect
    can add a loss."""
    return tuple(z for i, z in enumerate(furnace.zones) if i not in furnace.ambient)


class TriedZoneLosses(Tried):
    def nulls(self, effect):
        return {f"g_{z}": 0.0 for z in effect.options["zones"]}


class DrawnZoneLosses(Drawn):
    def draw(self, rng, form, duration_min, furnace):
        """Eq. 11's network: both zones that might lose heat in the candidate's form (its
        first law), one in the other; any other network: one zone (the one whose walls lose
        heat), which the candidate finds among its further laws."""
        can = losing(furnace)
        if furnace.paper_structure and form != "other":
            zones = can
        else:
            zones = (can[int(rng.integers(len(can)))],)
        return self.effect(zones=zones, furnace=furnace), {f"g_{z}": self.uniform(rng, "g")
                                                           for z in zones}


class ZoneLosses(Effect):
    name = "zone_losses"
    physics = "a zone besides preheating loses heat to ambient through its walls"
    # On a larger furnace one zone's wall loss, fitted as a loss in every zone that might
    # lose heat, spreads over zones that do not and is not found (seen on the six-zone
    # furnace: losses on all four, the gap left unexplained): one place at a time.
    tried = TriedZoneLosses(null={"g_soak": 0.0, "g_heat": 0.0}, zone_affine=True,
                            one_place_at_a_time=True)
    drawn = DrawnZoneLosses(ranges={"g": (0.002, 0.01)})

    @classmethod
    def refusal(cls, furnace):
        if not losing(furnace):
            return "every zone of it already loses heat to ambient (its `ambient` list)"
        return None

    @classmethod
    def specs(cls, furnace):
        """`zones`: any the description does not have losing heat, all of them by default."""
        z = losing(furnace)
        return {"zones": Option(z, "choices", choices=furnace.zones,
                                doc=f"zones that lose heat ({', '.join(z)})")}

    @classmethod
    def physics_for(cls, furnace):
        if furnace.paper_structure:
            return cls.physics
        ambient = [furnace.zones[i] for i in furnace.ambient]
        return (f"a zone besides {' and '.join(ambient)} loses heat to ambient through its "
                "walls")

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
