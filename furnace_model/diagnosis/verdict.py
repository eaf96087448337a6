"""The verdict and its sentence: no gap, the effects that explain it, the effects that
explain part of it and what remains, or an error none of the candidates touches, with where
it lies."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from ..effects import EFFECTS
from ..identification.residuals import ZONE_WORDS
from ..simulation.furnace import Furnace
from ..simulation.structure import ModelStructure
from .candidate import CandidateResult
from .credit import credited, near_floor, step_closed_pct
from .locate import Located, where_lines
from .words import capital, model_words, temp_c, zones_words

STATUSES = ("no_gap", "explained", "explained_in_part", "unexplained")
NAMING = ("explained", "explained_in_part")
"""The verdicts that name effects: each earned its credit."""


@dataclass
class Part:
    """One kept effect of a partial explanation, in the order the stepwise search added it:
    what adding it to the effects before it did to the held-out error."""

    effect: str
    gap_closed_pct: float
    """Share of the baseline's held-out squared error above the floor this step removed; the
    parts add up to the verdict's `gap_closed_pct`."""
    shrink_pct: float
    """This step's cut of the pooled held-out RMSE, in percent of the baseline's; the parts
    add up to the verdict's `shrink_pct`."""
    rmse_holdout_c: dict[str, float]
    """Held out per zone with the effects up to and including this one."""


@dataclass
class Remaining:
    """What a partial explanation leaves: the kept model's held-out error against the floor,
    and where it lies."""

    rmse_holdout_c: dict[str, float]
    noise_floor_c: dict[str, float]
    where: list[Located]
    where_from: str
    """'kept': located on the kept model's held-out residual; 'baseline': the baseline's
    entries, where the kept model's residual could not be located."""


@dataclass
class Verdict:
    status: str  # one of STATUSES
    effects: list[str]
    shrink_pct: float
    sentence: str
    gap_closed_pct: float = 0.0
    """Share of the baseline's held-out squared error above the noise floor that the kept
    effects remove: 100 when they explain it all, whatever the noise level (shrink_pct, the
    plain RMSE reduction, cannot pass 1 - floor / baseline RMSE)."""
    parts: list[Part] = field(default_factory=list)
    """`explained_in_part`: each kept effect's share, in the order it was added."""
    remaining: Remaining | None = None
    """`explained_in_part`: what the kept effects leave."""
    unmodelled_inputs: list[str] = field(default_factory=list)
    """Logged signals the model does not use that the error follows
    (`furnace_model.diagnosis.signals`)."""


def judge(base: CandidateResult, kept: CandidateResult | None,
          candidates: list[CandidateResult], floor: dict[str, float], near: dict[str, float],
          gap: tuple[str, ...], where: list[Located], missing: Sequence[str] = (),
          *, furnace: Furnace, steps: Sequence[CandidateResult] = (),
          locate_remaining: Callable[[CandidateResult], list[Located] | None] | None = None
          ) -> Verdict:
    """The verdict and its sentence; `missing`: zones whose burners fire only in the
    held-out data. `steps`: the kept set after each effect the stepwise search added (the
    last is `kept`), for the parts of a partial explanation; `locate_remaining`: where the
    residual of a model lies, on the held-out data."""
    zones = furnace.zones
    fl = ", ".join(f"{z} {temp_c(floor[z])}" for z in zones)
    rb = ", ".join(f"{z} {temp_c(base.rmse_holdout_c[z])}" for z in zones)
    model = capital(model_words(furnace))
    if not gap:
        carried = max(base.carried_c.values(), default=0.0)
        also = (f", and up to {temp_c(carried)} °C that the fitted parameters' own "
                f"uncertainty carries onto the held-out data" if carried >= 0.05 else "")
        return Verdict("no_gap", [], 0.0,
                       f"{model} already predicts the held-out data as well as the "
                       f"thermocouples allow (held-out RMSE {rb} °C against a noise floor of "
                       f"{fl} °C{also}): there is no model error to explain, and no candidate "
                       f"effect was tried.")
    worst = max(gap, key=lambda z: base.rmse_holdout_c[z] / max(floor[z], 1e-9))
    missing_words = (
        f" The held-out data fire {zones_words(list(missing))}-zone burners, which the "
        f"fitted data never fire: what those burners do cannot be learnt from the fitted "
        f"data. Given together as DATA, without --holdout, the experiments are split so "
        f"that the fitted ones fire every burner the held-out one does." if missing else "")
    if kept is not None and near_floor(kept, near):
        best = kept
        physics = "; and ".join(EFFECTS[n].physics_for(furnace) for n in best.effects)
        one = len(best.effects) == 1
        what, it = ("an effect", "it") if one else (f"{len(best.effects)} effects", "them")
        return Verdict(
            "explained", list(best.effects), best.shrink_pct, gap_closed_pct=best.gap_closed_pct,
            sentence=
            f"The model's error comes from {what} it leaves out: {physics} "
            f"({', '.join(best.effects)}){_found_words(best)}. Adding {it} cuts the held-out "
            f"error in the {ZONE_WORDS[worst]} zone from {temp_c(base.rmse_holdout_c[worst])} to "
            f"{temp_c(best.rmse_holdout_c[worst])} °C (pooled over zones "
            f"{best.shrink_pct:.0f}% smaller), {_down_to(best, floor, near, worst)}."
            + _unseen_words(best, furnace))
    if kept is not None and credited(kept):
        return _in_part(base, kept, floor, worst, where, furnace, steps, candidates,
                        locate_remaining, missing_words)
    place = _place(where, zones)
    best = candidates[0] if candidates else None
    tried = (f" The best candidate, {best.label}, only reaches "
             f"{temp_c(best.rmse_holdout_pooled())} °C." if best is not None else "")
    return Verdict(
        "unexplained", [], 0.0,
        f"The model's held-out error is real ({temp_c(base.rmse_holdout_c[worst])} °C in the "
        f"{ZONE_WORDS[worst]} zone against a noise floor of {temp_c(floor[worst])} °C), but "
        f"none of the candidate effects brings it down to the noise."
        + (f" It {place}." if place else "") + tried + missing_words)


def _down_to(best: CandidateResult, floor: dict[str, float], near: dict[str, float],
             zone: str) -> str:
    """Where an explaining model's held-out error ends: at the noise, or, past it, within
    what its own parameters' uncertainty carries there (never the noise alone: a number
    told must be true for the record)."""
    carried = best.carried_c.get(zone, 0.0)
    if best.rmse_holdout_c[zone] <= near[zone] or carried < 0.05:
        return f"down to about the thermocouple noise of {temp_c(floor[zone])} °C"
    return (f"within what the thermocouple noise of {temp_c(floor[zone])} °C and the fitted "
            f"parameters' own uncertainty (up to {temp_c(carried)} °C there) allow")


def _in_part(base: CandidateResult, kept: CandidateResult, floor: dict[str, float],
             worst: str, where: list[Located], furnace: Furnace,
             steps: Sequence[CandidateResult], candidates: list[CandidateResult],
             locate_remaining: Callable[[CandidateResult], list[Located] | None] | None,
             missing_words: str) -> Verdict:
    """`explained_in_part`: the kept effects earn credit but leave the held-out error off
    the floor. Measured records (one thermocouple a zone, hourly readings, inputs nobody
    logs) seldom let any model reach it, and an effect that closes two thirds of the gap is
    worth naming, with what it leaves."""
    parts = _parts(base, kept, floor, steps, candidates)
    remaining = remaining_of(kept, floor, where, locate_remaining)
    physics = "; and ".join(EFFECTS[n].physics_for(furnace) for n in kept.effects)
    one = len(kept.effects) == 1
    what, they_leave = (("an effect", "it leaves") if one
                        else (f"{len(kept.effects)} effects", "they leave"))
    first, *more = parts
    closes = (f"Adding {'it' if one else first.effect} closes {first.gap_closed_pct:.0f}% of "
              f"the held-out gap above the noise floor"
              + "".join(f", {p.effect} a further {p.gap_closed_pct:.0f}%" for p in more))
    zones = furnace.zones
    rest = max(zones, key=lambda z: kept.rmse_holdout_c[z] / max(floor[z], 1e-9))
    place = _place(remaining.where, zones)
    if place and remaining.where_from == "kept":
        place = f" It {place}."
    elif place:
        place = (f" Its place was not found on the residual {they_leave}; the baseline's "
                 f"error {place}.")
    sentence = (
        f"The model's error comes in part from {what} it leaves out: {physics} "
        f"({', '.join(kept.effects)}){_found_words(kept)}. {closes}"
        + ("" if one else f" ({kept.gap_closed_pct:.0f}% together)")
        + f": the held-out error in the {ZONE_WORDS[worst]} zone falls from "
        f"{temp_c(base.rmse_holdout_c[worst])} to {temp_c(kept.rmse_holdout_c[worst])} °C "
        f"(pooled over zones {kept.shrink_pct:.0f}% smaller). What remains is not explained: "
        f"{temp_c(kept.rmse_holdout_c[rest])} °C held out in the {ZONE_WORDS[rest]} zone "
        f"against a noise floor of {temp_c(floor[rest])} °C, and no further candidate "
        f"closes most of it.{place}"
        + _unseen_words(kept, furnace) + missing_words)
    return Verdict("explained_in_part", list(kept.effects), kept.shrink_pct, sentence,
                   gap_closed_pct=kept.gap_closed_pct, parts=parts, remaining=remaining)


def remaining_of(c: CandidateResult, floor: dict[str, float], where: list[Located],
                 locate_remaining: Callable[[CandidateResult], list[Located] | None] | None
                 ) -> Remaining:
    """What a model that explains part of the gap leaves: located on its own held-out
    residual, else the baseline's `where`, said to be the baseline's."""
    found = locate_remaining(c) if locate_remaining is not None else None
    if found:
        return Remaining(dict(c.rmse_holdout_c), dict(floor), found, "kept")
    return Remaining(dict(c.rmse_holdout_c), dict(floor), list(where), "baseline")


def _parts(base: CandidateResult, kept: CandidateResult, floor: dict[str, float],
           steps: Sequence[CandidateResult], candidates: list[CandidateResult]) -> list[Part]:
    """Each kept effect's step: the kept set with the effects up to it (from `steps`, else
    the candidate of those effects) against the set before it."""
    chain: list[CandidateResult] = []
    for i in range(1, len(kept.effects) + 1):
        prefix = kept.effects[:i]
        if i == len(kept.effects):
            chain.append(kept)
            continue
        stepped = [c for c in steps if c.effects == prefix]
        same = stepped[-1:] or sorted((c for c in candidates if c.effects == prefix),
                                      key=lambda c: c.evidence)
        if not same:  # no record of the step: it is said together with the next
            continue
        chain.append(same[0])
    parts, prev = [], base
    rb = base.rmse_holdout_pooled()
    done = 0
    for c in chain:
        new = c.effects[done:]
        parts.append(Part("+".join(new), step_closed_pct(c, prev, base, floor),
                          100.0 * (prev.rmse_holdout_pooled() - c.rmse_holdout_pooled()) / rb
                          if rb > 0 else 0.0, dict(c.rmse_holdout_c)))
        prev, done = c, len(c.effects)
    return parts


def _place(where: list[Located], zones: tuple[str, ...]) -> str:
    """Where the first located entry lies, as the end of a sentence ("lies mainly in the
    heating zone, 120-300 min of exp2 (...)"); empty without one."""
    if not where:
        return ""
    w = where_lines(where, zones)[0]
    who = w.who if w.who.startswith("thermocouple") else f"the {w.who}"
    if w.kind == "throughout":
        return f"lies in {who} throughout {w.experiment} ({w.regime})"
    how = "shows first and most sharply" if w.kind == "change" else "lies mainly"
    return f"{how} in {who}, {w.span} of {w.experiment} ({w.regime})"


def _found_words(c: CandidateResult) -> str:
    """": " and what the fitted effects say the plant has (`Effect.found`), where they say."""
    said = [w for w in (EFFECTS[n].found_within(c.params, c.options.get(n, {}), c.ci95)
                        for n in c.effects) if w]
    return f": {'; '.join(said)}" if said else ""


def _unseen_words(c: CandidateResult, furnace: Furnace) -> str:
    if not c.held_out_fitted:
        return ""
    docs = {p.name: p.doc.split(": ")[-1] for p in ModelStructure(furnace=furnace).params}  # words, not 1/C1
    what = "; ".join(f"{n} ({docs[n]})" for n in c.held_out_fitted)
    it = "it" if len(c.held_out_fitted) == 1 else "them"
    return (f" With {' and '.join(c.effects)} in the model, the fitted data do not show {what} "
            f"at all: the held-out check estimated {it} on the held-out data.")
