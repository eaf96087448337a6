"""Whether a candidate effect earns credit: the one rule the verdict keeps effects by, and
the one the report, the text summary and the JSON show, so that they cannot disagree.

A candidate earns credit when the data determine its own strength, it lowers the
information criterion on the fitted data (dBIC < 0) and it removes at least half of the
baseline's held-out error above the noise floor. A candidate that makes the held-out error
worse closes a negative share of the gap and never earns it; it is said to make it worse
when that shows in a printed percent.

A candidate's own parameters must be determined and away from the value at which the
effect vanishes: an extension that improves the fit with an interval reaching "no effect"
has merely bent to the noise or to another effect. Its intervals are linearised; a
candidate held from credit by them alone is judged again on its profiled ones
(`fitting.profile_strength`).

A candidate is also measured against the noise: a zone has a gap when its held-out error
stands clear of the noise floor (`GAP_RATIO`), and a candidate explains it when it comes
near the floor in every zone (`NEAR_RATIO`). The search ranks candidates, and decides what
is worth a further law or a further effect, by the same rules.
"""

from __future__ import annotations

import re

import numpy as np

from ..identification.noisefloor import GAP_Z
from ..identification.result import FitResult
from .candidate import CandidateResult

UNDETERMINED = "the data do not determine it"
"""How the notes say that an effect's strength is not determined (`identifiable`)."""
MAX_RATIO = 4.0
"""A positive strength parameter counts as determined when its 95% interval spans less than
this factor: one that could be anything from a trace to a flood is not an estimate."""
CARRIED_Z = GAP_Z
"""The level at which a fit's parameter uncertainty is carried onto the held-out records
(`carried.carried_error`): the quantile norm.cdf of this many standard deviations."""
NEAR_RATIO = 1.5
"""An extension whose held-out RMSE is within this multiple of the floor in every zone
explains the gap (or within `NEAR_Z` standard errors of the ratio, if that is further)."""
NEAR_Z = 4.0
MIN_GAP_CLOSED = 50.0
"""Percent of the baseline's held-out error above the floor an effect must remove to count;
for a further effect in a stepwise combination, of the error the kept ones leave."""
RULE = (f"strength determined by the data, dBIC < 0 on the fitted data and at least "
        f"{MIN_GAP_CLOSED:.0f}% of the held-out gap above the noise floor closed")
"""The rule in the words the report and the text summary print beside each candidate."""


def shortfall(c: CandidateResult) -> list[str]:
    """What keeps `c` from credit, in words; empty when it earns it."""
    if not np.isfinite(c.gap_closed_pct) or not np.isfinite(c.delta_bic):
        return ["its fit failed"]
    out = []
    if not c.identifiable:
        out.append("its strength is not determined by the data")
    if c.delta_bic >= 0:
        out.append(f"the information criterion is not lower (dBIC {c.delta_bic:+.0f})")
    if c.shrink_pct <= -0.5:  # worse by at least a percent, as it is printed
        out.append(f"it makes the held-out error worse ({-c.shrink_pct:.0f}% larger)")
    elif c.gap_closed_pct < MIN_GAP_CLOSED:
        closed = max(c.gap_closed_pct, 0.0)
        out.append(f"it closes {closed:.0f}% of the held-out gap above the noise floor, under "
                   f"{MIN_GAP_CLOSED:.0f}%")
    return out


def credited(c: CandidateResult) -> bool:
    return not shortfall(c)


def identifiable(fr: FitResult, effects: tuple[str, ...]) -> tuple[bool, str]:
    """Whether every effect has a strength parameter that the data determine away from the
    value at which it vanishes; else the reason, in words."""
    notes = []
    for name in effects:
        effect = next(e for e in fr.structure.effects if e.name == name)
        box = {p.name: p for p in effect.params}
        ok_any, why = False, []
        for pname, null in effect.tried.nulls(effect).items():
            if pname not in box:
                continue
            # Under the candidate's own noise (white): whether the records pin its strength
            # down; a residual the other effects of a combination leave would otherwise
            # hide a first effect that the data do determine.
            p, (lo, hi), v = box[pname], fr.ci95_white[pname], fr.params[pname]
            at_edge = lo <= p.lo * (1 + 1e-6) or hi >= p.hi * (1 - 1e-6) if p.log else \
                lo <= p.lo + 1e-9 * (p.hi - p.lo) or hi >= p.hi - 1e-9 * (p.hi - p.lo)
            if p.log:
                wide = not (lo > 0 and hi / lo < MAX_RATIO)
            else:
                wide = not np.isnan(null) and lo <= null <= hi
            if wide or at_edge:
                why.append(f"{pname} = {v:.4g} with 95% interval [{lo:.3g}, {hi:.3g}]"
                           + (" reaching its search bound" if at_edge and not wide else ""))
            else:
                ok_any = True
        if not ok_any:
            notes.append(f"{name}: {UNDETERMINED} ({'; '.join(why)})")
    return not notes, "; ".join(notes)


def strength_rejudged(c: CandidateResult, judged: CandidateResult) -> None:
    """c judged again on whether the data determine its strength (`judged`, from
    `fitting.profile_strength`): its words on that replaced by the new judgement's, and
    where its strength is now determined, the profiled intervals that show it."""
    note = c.note
    for name in c.effects:
        note = re.sub(rf"(^|; ){re.escape(name)}: {UNDETERMINED} \([^()]*\)", "", note)
    now = judged.note
    if judged.identifiable:
        shown = "; ".join(f"{n} in [{lo:.4g}, {hi:.4g}]" for n, (lo, hi) in judged.ci95.items())
        now = (f"strength determined on its profiled intervals ({shown}; 95%, white noise), "
               "which its linearised ones spread along a direction the data leave nearly flat")
    c.identifiable = judged.identifiable
    c.note = "; ".join(x for x in (now, note.removeprefix("; ")) if x)


def delta_bic(c: CandidateResult, ref: CandidateResult) -> float:
    """The change of BIC on the fitted data from `ref` to `c` (which extends it), in c's
    effective samples (`CandidateResult.n_eff`): counted as independent, autocorrelated
    residuals would make any lower fit error look like evidence. The one BIC of the
    diagnosis: against the baseline for credit, against the kept set for a further effect."""
    neff = c.n_eff()
    return float(neff * np.log(c.sse_fit / ref.sse_fit) + (c.n_params - ref.n_params) * np.log(neff))


def gap_closed_pct(c: CandidateResult, ref: CandidateResult, floor: dict[str, float]) -> float:
    """Percent of ref's held-out squared error above the noise floor (pooled over zones)
    that c removes: 100 when c reaches the floor, whatever the noise level; 0 when ref is at
    the floor already, since there is nothing to close."""
    rr, rc = ref.rmse_holdout_pooled(), c.rmse_holdout_pooled()
    excess = rr * rr - float(np.mean([f ** 2 for f in floor.values()]))
    return float(100.0 * (rr * rr - rc * rc) / excess) if excess > 0 else 0.0


def step_closed_pct(c: CandidateResult, prev: CandidateResult, base: CandidateResult,
                    floor: dict[str, float]) -> float:
    """Percent of the *baseline's* held-out squared error above the noise floor that c
    removes beyond prev (c extends prev by one effect): the steps of a stepwise combination,
    each against the one before, add up to the combination's `gap_closed_pct`, so that a
    partial explanation can say how much of the gap each kept effect closes."""
    rb, rp, rc = (x.rmse_holdout_pooled() for x in (base, prev, c))
    excess = rb * rb - float(np.mean([f ** 2 for f in floor.values()]))
    return float(100.0 * (rp * rp - rc * rc) / excess) if excess > 0 else 0.0


def score_against(c: CandidateResult, base: CandidateResult, floor: dict[str, float]) -> None:
    """Fill the candidate's comparison with the baseline: held-out RMSE shrink (pooled over
    zones), the share of the baseline's held-out gap above the noise floor it closes, and
    the change of BIC on the fitted data with an effective sample size."""
    rb, rc = base.rmse_holdout_pooled(), c.rmse_holdout_pooled()
    if not np.isfinite(rc):
        c.shrink_pct = c.gap_closed_pct = c.delta_bic = float("nan")
        c.evidence = float("inf")
        return
    c.shrink_pct = float(100.0 * (1.0 - rc / rb)) if rb > 0 else 0.0
    c.gap_closed_pct = gap_closed_pct(c, base, floor)
    c.delta_bic = delta_bic(c, base) if c.n_obs and c.sse_fit > 0 and base.sse_fit > 0 else 0.0
    # Held-out evidence: the Gaussian log-likelihood ratio on data the fit has not seen,
    # counted in effective samples; with the fit's BIC it ranks candidates whose held-out
    # errors are within noise of each other (a lag and a dead time both near the floor).
    # A parameter estimated on the held-out data is charged as BIC charges one.
    rho = c.rho1_holdout
    n_ho = c.n_holdout * (1 - rho) / (1 + rho)
    c.evidence = c.delta_bic + (n_ho * np.log(rc * rc / (rb * rb)) if rb > 0 and rc > 0 else 0.0)
    if n_ho > 1:
        c.evidence += (len(c.held_out_fitted) - len(base.held_out_fitted)) * np.log(n_ho)


def helps(c: CandidateResult) -> bool:
    """Closes part of the gap and lowers the BIC: worth a further law."""
    return c.gap_closed_pct > 0 and c.delta_bic < 0


def rank(c: CandidateResult) -> tuple:
    r = c.rmse_holdout_pooled()
    return (not credited(c), c.evidence if credited(c) else (r if np.isfinite(r) else np.inf))


def near_floor(c: CandidateResult, near: dict[str, float]) -> bool:
    """Held out within `near` (noisefloor.limits at NEAR_RATIO), widened by what its own
    parameters carry, in every zone."""
    allowed = c.allowed(near)
    return all(c.rmse_holdout_c[z] <= allowed[z] for z in near)


def closes(c: CandidateResult, kept: CandidateResult, floor: dict[str, float]) -> bool:
    """Whether c (kept plus one effect) earns credit against kept as a candidate does
    against the baseline: its own strength determined, a lower BIC on the fitted data, and
    at least `MIN_GAP_CLOSED` of the held-out gap kept leaves closed."""
    if not c.identifiable or not np.isfinite(c.sse_fit) or not np.isfinite(kept.sse_fit):
        return False
    return gap_closed_pct(c, kept, floor) >= MIN_GAP_CLOSED and delta_bic(c, kept) < 0
