"""The verdict and its sentence: no gap, the effects that explain it, or an error none of the
candidates brings down to the noise, with where it lies."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from ..effects import EFFECTS
from ..identification.residuals import ZONE_WORDS
from ..simulation.furnace import Furnace
from ..simulation.structure import ModelStructure
from .candidate import CandidateResult
from .credit import near_floor
from .locate import Located, where_lines
from .words import zones_words


@dataclass
class Verdict:
    status: str  # no_gap | explained | unexplained
    effects: list[str]
    shrink_pct: float
    sentence: str
    gap_closed_pct: float = 0.0
    """Share of the baseline's held-out squared error above the noise floor that the kept
    effects remove: 100 when they explain it all, whatever the noise level (shrink_pct, the
    plain RMSE reduction, cannot pass 1 - floor / baseline RMSE)."""
    unmodelled_inputs: list[str] = field(default_factory=list)
    """Logged signals the model does not use that the error follows
    (`furnace_model.diagnosis.signals`)."""


def judge(base: CandidateResult, kept: CandidateResult | None,
          candidates: list[CandidateResult], floor: dict[str, float], near: dict[str, float],
          gap: tuple[str, ...], where: list[Located], missing: Sequence[str] = (),
          *, furnace: Furnace) -> Verdict:
    """The verdict and its sentence; `missing`: zones whose burners fire only in the
    held-out data."""
    zones = furnace.zones
    fl = ", ".join(f"{z} {floor[z]:.1f}" for z in zones)
    rb = ", ".join(f"{z} {base.rmse_holdout_c[z]:.1f}" for z in zones)
    model = ("The paper's model" if furnace.paper_structure  # eq. 11, whatever the zone names
             else f"The model of furnace '{furnace.name}'")
    if not gap:
        carried = max(base.carried_c.values(), default=0.0)
        also = (f", and up to {carried:.1f} °C that the fitted parameters' own uncertainty "
                f"carries onto the held-out data" if carried >= 0.05 else "")
        return Verdict("no_gap", [], 0.0,
                       f"{model} already predicts the held-out data as well as the "
                       f"thermocouples allow (held-out RMSE {rb} °C against a noise floor of "
                       f"{fl} °C{also}): there is no model error to explain, and no candidate "
                       f"effect was tried.")
    if kept is not None and near_floor(kept, near):
        best = kept
        physics = "; and ".join(EFFECTS[n].physics_for(furnace) for n in best.effects)
        one = len(best.effects) == 1
        what, it = ("an effect", "it") if one else (f"{len(best.effects)} effects", "them")
        worst = max(gap, key=lambda z: base.rmse_holdout_c[z] / max(floor[z], 1e-9))
        return Verdict(
            "explained", list(best.effects), best.shrink_pct, gap_closed_pct=best.gap_closed_pct,
            sentence=
            f"The model's error comes from {what} it leaves out: {physics} "
            f"({', '.join(best.effects)}). Adding {it} cuts the held-out error in the "
            f"{ZONE_WORDS[worst]} zone from {base.rmse_holdout_c[worst]:.1f} to "
            f"{best.rmse_holdout_c[worst]:.1f} °C (pooled over zones {best.shrink_pct:.0f}% "
            f"smaller), down to about the thermocouple noise of {floor[worst]:.1f} °C."
            + _unseen_words(best, furnace))
    worst = max(gap, key=lambda z: base.rmse_holdout_c[z] / max(floor[z], 1e-9))
    place = ""
    if where:
        w = where_lines(where, zones)[0]
        who = w.who if w.who.startswith("thermocouple") else f"the {w.who}"
        if w.kind == "throughout":
            place = f" It lies in {who} throughout {w.experiment} ({w.regime})."
        else:
            how = "shows first and most sharply" if w.kind == "change" else "lies mainly"
            place = f" It {how} in {who}, {w.span} of {w.experiment} ({w.regime})."
    best = candidates[0] if candidates else None
    tried = (f" The best candidate, {best.label}, only reaches {best.rmse_holdout_pooled():.1f} "
             f"°C." if best is not None else "")
    return Verdict(
        "unexplained", [], 0.0,
        f"The model's held-out error is real ({base.rmse_holdout_c[worst]:.1f} °C in the "
        f"{ZONE_WORDS[worst]} zone against a noise floor of {floor[worst]:.1f} °C), but "
        f"none of the candidate effects brings it down to the noise.{place}{tried}"
        + (f" The held-out data fire {zones_words(list(missing))}-zone burners, which the "
           f"fitted data never fire: what those burners do cannot be learnt from the fitted "
           f"data. Given together as DATA, without --holdout, the experiments are split so "
           f"that the fitted ones fire every burner the held-out one does." if missing else ""))


def _unseen_words(c: CandidateResult, furnace: Furnace) -> str:
    if not c.held_out_fitted:
        return ""
    docs = {p.name: p.doc.split(": ")[-1] for p in ModelStructure(furnace=furnace).params}  # words, not 1/C1
    what = "; ".join(f"{n} ({docs[n]})" for n in c.held_out_fitted)
    it = "it" if len(c.held_out_fitted) == 1 else "them"
    return (f" With {' and '.join(c.effects)} in the model, the fitted data do not show {what} "
            f"at all: the held-out check estimated {it} on the held-out data.")
