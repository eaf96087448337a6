"""How the selfcheck draws an effect at random: the part of an effect class (`Effect.drawn`)
that makes a furnace with the effect, in the diagnosis's form or in another one, with
strengths and timings from physically meaningful `ranges`, and says on which furnace the
diagnosis is checked for it.

The default part cannot draw: the selfcheck leaves such an effect out of its default rows
and refuses it by name. An effect that can be drawn declares a subclass with a `draw`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..simulation.furnace import Furnace
from .part import Part

if TYPE_CHECKING:
    from .base import Effect


@dataclass
class Drawn(Part):
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    """Ranges the selfcheck draws strengths and timings from (`draw`, `uniform`)."""

    @property
    def drawable(self) -> bool:
        """Whether the selfcheck can make a furnace with the effect at random."""
        return type(self).draw is not Drawn.draw

    def draw(self, rng: np.random.Generator, form: str, duration_min: float,
             furnace: Furnace) -> tuple[Effect, dict[str, float]]:
        """A furnace with the effect, at random: the effect (in the diagnosis's form, or with
        form "other" in a formulation its candidate does not use) and its parameter values,
        drawn from `ranges`; times within a heat-up of `duration_min`."""
        raise NotImplementedError(f"{self.name} has no random draw for the selfcheck")

    def check_furnace(self, furnace: Furnace) -> Furnace:
        """The furnace the selfcheck diagnoses this effect on, given the one it checks: the
        same, unless the effect is the other side of a convention the description fixes
        (zone_burners on a furnace whose burners heat their own zones)."""
        return furnace

    def uniform(self, rng: np.random.Generator, key: str) -> float:
        """A value drawn uniformly from `ranges[key]`."""
        lo, hi = self.ranges[key]
        return float(rng.uniform(lo, hi))
