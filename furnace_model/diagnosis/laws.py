"""An effect in several laws: the further laws worth fitting, and a law between two of them
(their predictions blended with one weight)."""

from __future__ import annotations

import numpy as np

from ..effects import EFFECTS
from ..experiment import Experiment
from ..simulation.furnace import Furnace
from .candidate import CandidateResult
from .credit import helps
from .fitting import rmse_per_zone


def further_laws(fitted: list[CandidateResult], furnace: Furnace
                 ) -> list[tuple[CandidateResult, dict]]:
    """The further laws to fit (`Tried.further_laws`), each with the candidate it starts
    from: only for a candidate that helps in its first law, since the nonlinear ones are
    slow. A furnace's radiation exponent, burner curve or storing walls are its own: the
    laws are fitted warm from the effect's first law (and from scratch on a bent baseline,
    see `diagnose`), and the best kept, or a blend of two (`between_laws`). An effect whose
    laws put it elsewhere, not in another form (`Tried.laws_always`: one zone's wall or lag
    on a furnace of many zones, a drifting thermocouple of a zone of one), has them fitted
    whatever its first law does."""
    out = []
    for c in fitted:
        tried = EFFECTS[c.effects[0]].tried
        if helps(c) or (tried.laws_always(furnace) and not c.note.startswith("fit failed")):
            first = c.options.get(c.effects[0], {})
            laws = (tried.law_options(opts, first) for opts in tried.laws_for(furnace))
            out += [(c, law) for law in laws if law != first]
    return out


def between_laws(same: list[CandidateResult], fit_data: list[Experiment],
                 hold: list[Experiment]) -> CandidateResult | None:
    """An effect's law between two of the candidate's (a burner curve between a straight
    line and an exponential): the two laws' predictions blended with one weight stand for
    the law between them to first order. The weight is fitted on the fitted and held-out
    data together (one number against thousands of samples, as the held-out offsets are):
    where both laws fit the fitted data to the noise, those data cannot choose between them
    (a burner curve fitted on up to 10 burners), and the held-out data, which carry the
    extrapolation, set it. None when every pair's best weight is one law alone."""
    ok = [c for c in same if c.identifiable and c.holdout_pred]
    best: CandidateResult | None = None
    for i, p in enumerate(ok):
        for q in ok[i + 1:]:
            w = blend_weight(p.fit_pred + p.holdout_pred, q.fit_pred + q.holdout_pred,
                             fit_data + hold)
            if not 0.0 < w < 1.0:
                continue
            mix = _blend(p, q, w, fit_data, hold)
            if best is None or mix.rmse_holdout_pooled() < best.rmse_holdout_pooled():
                best = mix
    return best


def blend_weight(p: list[np.ndarray], q: list[np.ndarray], data: list[Experiment]) -> float:
    """Least-squares weight w of q in (1 - w) p + w q against the zone readings."""
    num = den = 0.0
    for e, a, b in zip(data, p, q, strict=True):
        d, r = b - a, e.zone_temp - a
        m = np.isfinite(d) & np.isfinite(r)
        num += float(np.sum(d[m] * r[m]))
        den += float(np.sum(d[m] * d[m]))
    return float(np.clip(num / den, 0.0, 1.0)) if den > 0 else 0.0


def _blend(p: CandidateResult, q: CandidateResult, w: float, fit_data: list[Experiment],
           hold: list[Experiment]) -> CandidateResult:
    """The blend as a candidate: the parameters and intervals of its larger part, the fit
    error of the blended predictions, one parameter more than either law."""
    n = p.effects[0]
    major = p if w <= 0.5 else q
    fit_pred = [(1 - w) * a + w * b for a, b in zip(p.fit_pred, q.fit_pred, strict=True)]
    hold_pred = [(1 - w) * a + w * b for a, b in zip(p.holdout_pred, q.holdout_pred, strict=True)]
    laws = f"{opts_text(p.options[n])} ({1 - w:.2f}) and {opts_text(q.options[n])} ({w:.2f})"
    zones = fit_data[0].furnace.zones
    return CandidateResult(
        effects=p.effects, params=dict(major.params), ci95=dict(major.ci95),
        rmse_fit_c=rmse_per_zone(fit_data, fit_pred, zones),
        rmse_holdout_c=rmse_per_zone(hold, hold_pred, zones),
        identifiable=True, fit_pred=fit_pred, holdout_pred=hold_pred,
        note=f"law between {laws}, weighted on the fitted and held-out data together",
        options={n: {"between": [p.options[n], q.options[n]], "weight": w}},
        # the blend's fit error is at most the weighted one (the squared error is convex)
        sse_fit=(1 - w) * p.sse_fit + w * q.sse_fit, n_obs=major.n_obs,
        n_params=major.n_params + 1, rho1=major.rho1, rho1_holdout=major.rho1_holdout,
        n_holdout=major.n_holdout, carried_c=dict(major.carried_c),
        elapsed_s=p.elapsed_s + q.elapsed_s)


def laws_named(same: list[CandidateResult], furnace: Furnace) -> str:
    """The laws one effect was fitted in, each by its options; the one tried in the effect's
    own options (most effects' first) by what those are, not left blank."""
    n = same[0].effects[0]
    own = opts_text(EFFECTS[n](furnace=furnace).options)
    return ", ".join(opts_text(c.options.get(n, {})) or own for c in same)


def opts_text(opts: dict) -> str:
    return ", ".join(f"{k} {v:g}" if isinstance(v, float) else f"{k} fitted" if v is None
                     else f"{k} {' '.join(v)}" if isinstance(v, tuple) else f"{k} {v}"
                     for k, v in opts.items())
