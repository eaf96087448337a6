"""Each zone's burners heat their own zone (the paper counts every burner as zone-1 input).

The effect is the other side of a description's `burner_heat`: it applies to a furnace
described with every burner heating the first zone (`first_zone`, the paper's convention),
and is refused on one whose description already has each zone's burners heat their own."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..simulation.furnace import Furnace
from ..simulation.parameters import Param
from .base import Effect
from .drawn import Drawn
from .tried import Clues, Trial, Tried

if TYPE_CHECKING:
    from ..experiment import Experiment

OTHER_RANGE = (0.1, 0.5)
"""°C/min per burner drawn for a zone's own burners on a network other than eq. 11's:
around the network's default heat per burner (network.GAIN) and up to five times it."""
PAPER_DOCS = {1: "heating-zone rise rate per heating-zone burner on",
              2: "preheating-zone rise rate per preheating-zone burner on"}
"""Eq. 11's zones 2 and 3 in the paper's words, by zone index."""
MIN_HEAD_SAMPLES = 100
"""A record's soaking-burners-only start is fitted only when it is at least this long."""


class TriedZoneBurners(Tried):
    def nulls(self, effect):
        return {f"f_{effect.furnace.zones[i]}": float("nan") for i in effect.own}

    def trial(self, clues: Clues) -> Trial:
        """Where the model errs because the heating- and preheating-zone burners heat their
        own zones, it is still right while only soaking-zone burners fire: on a bent
        baseline, start from the baseline fitted on each record up to the first other burner,
        keeping what those data determine (a and f; the rest, like the effect's own
        strengths, are searched). The baseline fitted on everything has bent to absorb the
        other burners (seen: f at its bound), a start from which the zone-burner fit stays
        in a side valley."""
        heads = soak_only_heads(clues.fit_data) if clues.bent else None
        return Trial(start_on=heads)


class DrawnZoneBurners(Drawn):
    def check_furnace(self, furnace: Furnace) -> Furnace:
        """A furnace described with own-zone burners is checked as its first-zone reading:
        the model counts every burner as first-zone input, the truth heats each zone with
        its own (this effect), which the diagnosis must find."""
        if furnace.burner_heat == "first_zone":
            return furnace
        return dataclasses.replace(furnace, name=f"{furnace.name}-first-zone",
                                   burner_heat="first_zone")

    def draw(self, rng, form, duration_min, furnace):
        """Each own-burner zone's heat per burner: from `ranges` on eq. 11's network, whose
        true values are Table V's; elsewhere from `OTHER_RANGE`, around the network's
        default gain."""
        effect = self.effect(furnace=furnace)
        if furnace.paper_structure:
            return effect, {p.name: self.uniform(rng, "f") for p in effect.params}
        return effect, {p.name: float(rng.uniform(*OTHER_RANGE)) for p in effect.params}


class ZoneBurners(Effect):
    name = "zone_burners"
    physics = ("heating- and preheating-zone burners heat their own zone, with their own heat "
               "per burner, instead of counting as zone-1 input")
    tried = TriedZoneBurners(null={"f_heat": float("nan"), "f_preheat": float("nan")},
                             zone_affine=True)
    drawn = DrawnZoneBurners(ranges={"f": (0.5, 5.0)})
    """`f`, on eq. 11's network: each own-burner zone's heat per burner, on Table V's
    scale."""

    @classmethod
    def refusal(cls, furnace):
        if furnace.burner_heat != "first_zone":
            return ("its description already has each zone's burners heat their own zone "
                    "(burner_heat: own_zone); zone_burners is that convention tried on a "
                    "furnace described with every burner heating the first zone "
                    "(burner_heat: first_zone)")
        if not any(furnace.burners[1:]):
            return "only its first zone has burners"
        return None

    @classmethod
    def physics_for(cls, furnace):
        if furnace.paper_structure:
            return cls.physics
        return (f"the burners of zones after {furnace.zones[0]} heat their own zone, with "
                f"their own heat per burner, instead of counting as {furnace.zones[0]}-zone "
                "input")

    @property
    def own(self) -> list[int]:
        """Zones after the first with burners of their own."""
        return [i for i in range(1, self.n_zones) if self.furnace.burners[i] > 0]

    def _params(self):
        zones = self.furnace.zones
        words = PAPER_DOCS if self.furnace.paper_structure else {}
        return tuple(Param(f"f_{zones[i]}", 0.15, 1e-4, 10.0, unit="°C/min per burner",
                           doc=words.get(i, f"{zones[i]}-zone rise rate per own burner on"))
                     for i in self.own)

    def extend(self, A, B, C, theta, first):
        B[:, 0, 1:self.n_zones] = 0.0
        for p, i in zip(self.params, self.own, strict=True):
            B[:, i, i] = theta[p.name]


def soak_only_heads(fit_data: Sequence[Experiment]) -> list[Experiment] | None:
    """Each record up to the first heating- or preheating-zone burner, where long enough and
    stepping; None when no other burner fires (the baseline is then as good a start)."""
    if not any(np.any(e.burners[:, 1:] > 0) for e in fit_data):
        return None
    heads = []
    for e in fit_data:
        other = np.nonzero((e.burners[:, 1:] > 0).any(axis=1))[0]
        head = e if not other.size else e.between(float(e.t_min[0]), float(e.t_min[other[0]]))
        if len(head) >= MIN_HEAD_SAMPLES and head.burner_steps > 0:
            heads.append(head)
    return heads or None
