"""Parts made from an effect class that declares no parts but the attributes and
classmethods the plug-in API also allows on the class itself (`null`, `candidate_options`,
`further_laws`, `zone_affine`, `one_place_at_a_time`, `blends`, `candidate_for`,
`laws_for`, `laws_always`, `trial`, `search_bounds`, `starts`, `nulls`; `ranges`, `draw`,
`check_furnace`), so that such a plug-in keeps working unchanged.

A class that defines any of them and declares no part of that kind gets one that reads
them (`old_part`); whatever it does not define comes from the part it inherits, so that a
plug-in written as a variant of a built-in effect keeps the built-in's search boxes."""

from __future__ import annotations

import copy
import inspect
from typing import TYPE_CHECKING, Any

import numpy as np

from ..simulation.furnace import Furnace
from .drawn import Drawn
from .part import Part
from .tried import Clues, Trial, Tried

if TYPE_CHECKING:
    from ..experiment import Experiment
    from .base import Effect

TRIED_DATA = ("null", "candidate_options", "further_laws", "zone_affine",
              "one_place_at_a_time", "blends")
TRIED_METHODS = ("nulls", "candidate_for", "laws_for", "laws_always", "trial",
                 "search_bounds", "starts")
DRAWN_DATA = ("ranges",)
DRAWN_METHODS = ("draw", "check_furnace")


def _old(cls: type | None, name: str) -> Any:
    """The class's own attribute `name` (the effect base defines none of these)."""
    return getattr(cls, name, None)


class OldTried(Tried):
    """A `Tried` that asks the effect class's own classmethods where it has them."""

    def nulls(self, effect: Effect) -> dict[str, float]:
        if _old(self.effect, "nulls") is not None:
            return effect.nulls
        return super().nulls(effect)

    def candidate_for(self, furnace: Furnace) -> dict[str, Any]:
        old = _old(self.effect, "candidate_for")
        return old(furnace) if old else super().candidate_for(furnace)

    def laws_for(self, furnace: Furnace) -> tuple[dict[str, Any], ...]:
        old = _old(self.effect, "laws_for")
        return old(furnace) if old else super().laws_for(furnace)

    def laws_always(self, furnace: Furnace) -> bool:
        old = _old(self.effect, "laws_always")
        return old(furnace) if old else super().laws_always(furnace)

    def trial(self, clues: Clues) -> Trial:
        old = _old(self.effect, "trial")
        return old(clues) if old else super().trial(clues)

    def search_bounds(self, fit_data: list[Experiment]) -> dict[str, tuple[float, float]]:
        old = _old(self.effect, "search_bounds")
        return old(fit_data) if old else super().search_bounds(fit_data)

    def starts(self, effect: Effect, given: dict[str, float],
               bounds: dict[str, tuple[float, float]]) -> list[dict[str, float]]:
        if _old(self.effect, "starts") is not None:
            return effect.starts(given, bounds)
        return super().starts(effect, given, bounds)


class OldDrawn(Drawn):
    """A `Drawn` that asks the effect class's own `draw` and `check_furnace`. A `draw`
    that takes no furnace knows only the paper's: it draws on eq. 11's network alone."""

    @property
    def drawable(self) -> bool:
        return (_old(self.effect, "draw") is not None
                or super().draw.__func__ is not Drawn.draw)

    def draw(self, rng: np.random.Generator, form: str, duration_min: float,
             furnace: Furnace) -> tuple[Effect, dict[str, float]]:
        old = _old(self.effect, "draw")
        if old is None:
            return super().draw(rng, form, duration_min, furnace)
        params = inspect.signature(old).parameters.values()
        if any(p.name == "furnace" or p.kind is p.VAR_KEYWORD for p in params):
            return old(rng, form, duration_min, furnace=furnace)
        if furnace.paper_structure:
            return old(rng, form, duration_min)
        raise ValueError(f"{self.name}: its draw takes no furnace, so the selfcheck cannot "
                         f"draw it on furnace '{furnace.name}'")

    def check_furnace(self, furnace: Furnace) -> Furnace:
        old = _old(self.effect, "check_furnace")
        return old(furnace) if old else super().check_furnace(furnace)


_KINDS = {"tried": (TRIED_DATA, TRIED_METHODS, OldTried),
          "drawn": (DRAWN_DATA, DRAWN_METHODS, OldDrawn)}
_MIXED: dict[tuple[type, type], type] = {}


def old_part(cls: type[Effect], slot: str) -> Part | None:
    """The part `slot` ("tried" or "drawn") of `cls` made from the old attributes it
    defines itself; None when it defines none of them. Its class reads them first and the
    inherited part's class after (a built-in's own search boxes, say)."""
    data, methods, reader = _KINDS[slot]
    if not any(n in vars(cls) for n in (*data, *methods)):
        return None
    inherited = getattr(cls, slot)
    kind = type(inherited)
    if not issubclass(kind, reader):
        key = (reader, kind)
        if key not in _MIXED:
            _MIXED[key] = type(f"Old{kind.__name__}", (reader, kind), {"__module__": __name__})
        kind = _MIXED[key]
    part = copy.copy(inherited)
    part.__class__ = kind
    for n in data:
        if hasattr(cls, n):
            setattr(part, n, getattr(cls, n))
    part.effect = cls
    return part
