"""The refractory wall of a zone stores heat: one more, slow state per zone."""

from __future__ import annotations

import numpy as np

from ..simulation.parameters import Param
from .base import Effect, Option
from .drawn import Drawn
from .tried import Tried


class TriedWallStorage(Tried):
    def candidate_for(self, furnace):
        return {"zones": furnace.zones}

    def laws_for(self, furnace):
        """A wall in each zone alone, on every network: a wall that stores much heat in one
        zone only cannot be fitted by one exchange rate shared by all (seen on the paper's
        furnace: a preheating-zone wall left 1.8 °C held out against a floor of 1.1 with
        walls in all zones)."""
        return tuple({"zones": (z,)} for z in furnace.zones)


class DrawnWallStorage(Drawn):
    def draw(self, rng, form, duration_min, furnace):
        """On eq. 11's network the candidate's form is a wall in every zone; on any other,
        a wall in one zone (the zone whose lining stores heat), which the candidate finds
        among its further laws."""
        wall = self.effect
        values = {"k_gw": self.uniform(rng, "k_gw"), "k_wg": self.uniform(rng, "k_wg")}
        zs = furnace.zones
        if form != "other":
            if furnace.paper_structure:
                return wall(furnace=furnace), values
            return wall(zones=(zs[int(rng.integers(len(zs)))],), furnace=furnace), values
        # A wall of two layers, in every zone or in one: the candidate's walls have one.
        zones = (zs, *((z,) for z in zs))[int(rng.integers(len(zs) + 1))]
        values |= {"k_wb": self.uniform(rng, "k_wb"), "k_bw": self.uniform(rng, "k_bw")}
        return wall(zones=zones, layers=2, furnace=furnace), values


class WallStorage(Effect):
    name = "wall_storage"
    physics = "the refractory wall of a zone stores heat: one more, slow state"
    option_specs = {
        "layers": Option(1, "integer", lo=1, hi=2,
                         doc="2: a hot face and a slower back layer behind it")}
    # The release rate stays determined when the exchange rate trades with the zone's own
    # rates (seen with a preheating-zone wall): either shows the wall.
    tried = TriedWallStorage(null={"k_gw": 0.0, "k_wg": float("nan")},
                             one_place_at_a_time=True)
    drawn = DrawnWallStorage(ranges={"k_gw": (0.02, 0.2), "k_wg": (0.001, 0.01),
                                     "k_wb": (0.002, 0.02), "k_bw": (0.0003, 0.003)})

    @classmethod
    def specs(cls, furnace):
        z = furnace.zones
        return {"zones": Option(z, "choices", choices=z, doc="zones with a storing wall"),
                **cls.option_specs}

    def _params(self):
        face = (Param("k_gw", 0.05, 1e-5, 10.0, doc="gas-to-wall exchange rate, seen from the gas"),
                Param("k_wg", 0.002, 1e-6, 1.0, doc="wall-to-gas exchange rate, seen from the wall"))
        if self.options["layers"] == 1:
            return face
        return face + (
            Param("k_wb", 0.005, 1e-6, 1.0, doc="hot face to back layer, seen from the face"),
            Param("k_bw", 0.001, 1e-6, 1.0, doc="back layer to hot face, seen from the back"))

    @property
    def state_zones(self):
        zones = self.furnace.zones
        return tuple(zones.index(z) for z in self.options["zones"]) * self.options["layers"]

    def extend(self, A, B, C, theta, first):
        zones = [self.furnace.zones.index(z) for z in self.options["zones"]]
        for j, z in enumerate(zones):
            face = first + j
            exchange(A, z, face, theta["k_gw"], theta["k_wg"])
            if self.options["layers"] == 2:
                exchange(A, face, face + len(zones), theta["k_wb"], theta["k_bw"])


def exchange(A: np.ndarray, i: int, j: int, k_ij: np.ndarray, k_ji: np.ndarray) -> None:
    """Heat exchange between states i and j, at rate k_ij seen from i and k_ji seen from j."""
    A[:, i, i] -= k_ij
    A[:, i, j] += k_ij
    A[:, j, j] -= k_ji
    A[:, j, i] += k_ji
