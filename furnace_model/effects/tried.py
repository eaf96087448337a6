"""How the diagnosis tries an effect: the part of an effect class (`Effect.tried`) that says
which strengths must be determined away from no effect, the form it is fitted in first and
the further laws, where its search starts (`Trial`, read off the data the diagnosis hands it
as `Clues`) and within which boxes.

The default part tries the effect in its first form from the fitted baseline, with no
further law; an effect declares its own (`Tried(null=..., ...)`, or a subclass where the
data choose the form or the start) and the diagnosis asks the part, never the effect."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from ..simulation.furnace import Furnace
from .part import Part

if TYPE_CHECKING:
    from ..experiment import Experiment
    from .base import Effect


@dataclass
class Clues:
    """What the diagnosis has read off the data before it tries the candidates, for any
    effect to use: an effect may start its search from them (a drifting thermocouple's
    onset) or choose its form. What only one effect reads (a thermocouple departing from
    its partner) its part works out from these, so that nothing here serves one effect."""

    fit_data: list[Experiment]
    records: list[Experiment]
    """The fitted records, then the held-out ones."""
    bent: bool = False
    """The baseline fits the fitted data worse than their noise allows: it has bent to
    absorb something, and a warm start from it may sit in a side valley."""
    predictions: list[np.ndarray] = field(default_factory=list)
    """The baseline's zone predictions on `records` (N, zones) each, as the thermocouples
    read them (its offsets included)."""
    furnace: Furnace = field(kw_only=True)

    @cached_property
    def residuals(self) -> list[np.ndarray]:
        """The baseline's zone residuals on `records` (N, zones) each."""
        return [e.zone_temp - p for e, p in zip(self.records, self.predictions, strict=True)]


@dataclass
class Trial:
    """How the diagnosis tries an effect: in which form, and from where."""

    options: dict[str, Any] = field(default_factory=dict)
    start: dict[str, float] = field(default_factory=dict)
    """Starting values of parameters, over the fitted baseline's."""
    start_on: list[Experiment] | None = None
    """Parts of the fitted records whose own baseline fit, with what they determine, is the
    start instead, the rest of the parameters searched (where they determine nothing, the
    fitted baseline's); fitted in the candidate's task, beside the other candidates."""


@dataclass
class Tried(Part):
    null: dict[str, float] = field(default_factory=dict)
    """Strength parameters and the value at which the effect vanishes (NaN: the parameter
    must merely be determined, either because the baseline is not nested in the extension
    or because it is felt only where the effect is). A candidate earns credit only when one
    of them is determined away from its null."""
    candidate_options: dict[str, Any] = field(default_factory=dict)
    """The diagnosis's own formulation (its first law)."""
    further_laws: tuple[dict[str, Any], ...] = ()
    """Other forms the diagnosis fits when the first law removes part of the gap."""
    zone_affine: bool = False
    """Its parameters enter the zones' equations linearly and it adds no state, no input
    change and no sensor error: the integrated equations' least squares (equationerror)
    estimate them with the network's."""
    one_place_at_a_time: bool = False
    """On any network but eq. 11's, the further laws put the effect in one place at a time
    (one zone of its `zones` option, unless `laws_for` says otherwise) and are fitted even
    when the first law, the effect everywhere at once, does not help: on a network of many
    zones an effect in one of them may leave the candidate no better than the baseline."""
    blends: bool = False
    """The further laws lie on one scale, so that a blend of two stands for a law between."""

    def nulls(self, effect: Effect) -> dict[str, float]:
        """`null` for this effect's own parameters (their names may follow its zones)."""
        return self.null

    def candidate_for(self, furnace: Furnace) -> dict[str, Any]:
        """The diagnosis's own formulation on this furnace (`candidate_options`)."""
        return dict(self.candidate_options)

    def laws_for(self, furnace: Furnace) -> tuple[dict[str, Any], ...]:
        """The further laws on this furnace: `further_laws`, or with `one_place_at_a_time`
        on a network other than eq. 11's, each zone of the `zones` option's default."""
        if furnace.paper_structure or not self.one_place_at_a_time:
            return self.further_laws
        return tuple({"zones": (z,)} for z in self.effect.specs(furnace)["zones"].default)

    def law_options(self, law: dict[str, Any], first: dict[str, Any]) -> dict[str, Any]:
        """A further law's options, given those the first law was fitted with: the law's
        own, unless the trial read a setting off the data that every law keeps."""
        return dict(law)

    def laws_always(self, furnace: Furnace) -> bool:
        """Whether the further laws are fitted even when the first law does not help: where
        each puts the effect somewhere else (one zone's wall, one thermocouple), not in
        another form, the first law need not show it at all."""
        return self.one_place_at_a_time and not furnace.paper_structure

    def trial(self, clues: Clues) -> Trial:
        """How the diagnosis tries the effect on these data."""
        return Trial(self.candidate_for(clues.furnace))

    def search_bounds(self, fit_data: Sequence[Experiment]) -> dict[str, tuple[float, float]]:
        """Search boxes narrower than the parameters' own, where the data set them (a time
        within the fitted records, not 0-1e6 min)."""
        return {}

    def named(self, options: dict[str, Any], params: dict[str, float],
              records: Sequence[Experiment]) -> dict[str, Any]:
        """The options to report for a fit with `options` and `params`: among laws that fit
        the zone means alike (any thermocouple of a zone drifting at the same rate), the
        one the records' own readings name."""
        return options

    def starts(self, effect: Effect, given: dict[str, float],
               bounds: dict[str, tuple[float, float]]) -> list[dict[str, float]]:
        """Further starts of this form's own parameters where the data leave them ambiguous
        (an onset nothing places has a side valley wherever it meets a step of the record);
        `given`: the start the diagnosis has (what the data placed, or a fit's values),
        `bounds`: the search box. The candidate is polished from each too and the best fit
        kept."""
        return []
