"""Each zone's burners heat their own zone (the paper counts every burner as zone-1 input)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..parameters import Param
from .base import Clues, Effect, Trial

if TYPE_CHECKING:
    from ..experiment import Experiment

MIN_HEAD_SAMPLES = 100
"""A record's soaking-burners-only start is fitted only when it is at least this long."""


class ZoneBurners(Effect):
    name = "zone_burners"
    physics = ("heating- and preheating-zone burners heat their own zone, with their own heat "
               "per burner, instead of counting as zone-1 input")
    null = {"f_heat": float("nan"), "f_preheat": float("nan")}
    ranges = {"f_heat": (0.5, 5.0), "f_preheat": (0.5, 5.0)}

    def _params(self):
        return (
            Param("f_heat", 0.15, 1e-4, 10.0, unit="°C/min per burner",
                  doc="heating-zone rise rate per heating-zone burner on"),
            Param("f_preheat", 0.15, 1e-4, 10.0, unit="°C/min per burner",
                  doc="preheating-zone rise rate per preheating-zone burner on"),
        )

    def extend(self, A, B, C, theta, first):
        B[:, 0, 1:3] = 0.0
        B[:, 1, 1] = theta["f_heat"]
        B[:, 2, 2] = theta["f_preheat"]

    @classmethod
    def trial(cls, clues: Clues) -> Trial:
        """Where the model errs because the heating- and preheating-zone burners heat their
        own zones, it is still right while only soaking-zone burners fire: on a bent
        baseline, start from the baseline fitted on each record up to the first other burner,
        keeping what those data determine (a and f; the rest, like the effect's own
        strengths, are searched). The baseline fitted on everything has bent to absorb the
        other burners (seen: f at its bound), a start from which the zone-burner fit stays
        in a side valley."""
        heads = soak_only_heads(clues.fit_data) if clues.bent else None
        start = clues.baseline_on(heads) if heads and clues.baseline_on else None
        return Trial(start=start, from_baseline=False) if start else Trial()

    @classmethod
    def draw(cls, rng, form, duration_min):
        return cls(), {"f_heat": cls.uniform(rng, "f_heat"),
                       "f_preheat": cls.uniform(rng, "f_preheat")}


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
