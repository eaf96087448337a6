"""Candidate extensions of the paper's model: each fitted on the fit data, warm-started from
the baseline, and scored on held-out data, by an information criterion and by whether the
data determine the effect at all.

A candidate earns credit only when its own parameters are determined and away from the
value at which the effect vanishes: an extension that improves the fit with an interval
reaching "no effect" has merely bent to the noise or to another effect.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from . import ZONES
from .effects import EFFECTS, Effect
from .errors import FurnaceError
from .experiment import Experiment
from .fit import FitResult, fit
from .residuals import lag1
from .structure import ModelStructure

NULL: dict[str, dict[str, float]] = {
    "zone_losses": {"g_soak": 0.0, "g_heat": 0.0},
    "sensor_lag": {"tau_lag": 0.0},
    "dead_time": {"theta_dead": 0.0},
    "wall_storage": {"k_gw": 0.0, "k_wg": float("nan")},
    "radiation": {"rad_share": 0.0},
    "burner_nonlinearity": {"k_nl": 0.0},
    "fuel_change": {"fuel_ratio": 1.0},
    "sensor_drift": {"drift_rate": 0.0},
    "zone_burners": {"f_heat": float("nan"), "f_preheat": float("nan")},
}
"""Each effect's strength parameters and the value at which the effect vanishes (NaN: the
parameter must merely be determined, either because the baseline is not nested in the
extension or because it is felt only where the effect is: a wall's release rate, which
stays determined when its exchange rate trades with the zone's own rates, seen with a
preheating-zone wall)."""

MAX_RATIO = 4.0
"""A positive strength parameter counts as determined when its 95% interval spans less than
this factor: one that could be anything from a trace to a flood is not an estimate."""


@dataclass
class CandidateResult:
    effects: tuple[str, ...]
    params: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    rmse_fit_c: dict[str, float]
    rmse_holdout_c: dict[str, float]
    shrink_pct: float = 0.0
    delta_bic: float = 0.0
    identifiable: bool = True
    note: str = ""
    fit_pred: list[np.ndarray] = field(default_factory=list)
    holdout_pred: list[np.ndarray] = field(default_factory=list)
    # added fields (the JSON may carry them)
    options: dict[str, dict] = field(default_factory=dict)
    sse_fit: float = float("nan")
    n_obs: int = 0
    n_params: int = 0
    rho1: float = 0.0  # lag-1 autocorrelation of the fit residual
    rho1_holdout: float = 0.0
    n_holdout: int = 0
    evidence: float = 0.0  # lower is better: delta_bic plus the held-out log-likelihood ratio
    gap_closed_pct: float = 0.0
    held_out_fitted: tuple[str, ...] = ()  # parameters estimated on the held-out data too
    elapsed_s: float = 0.0
    warnings: list[str] = field(default_factory=list)

    @property
    def label(self) -> str:
        return "+".join(self.effects) or "baseline"

    def rmse_holdout_pooled(self) -> float:
        return pooled(self.rmse_holdout_c)

    def n_eff(self) -> float:
        """Effective sample size of the fit residual: autocorrelated samples carry less
        information than independent ones (AR(1) reading, n (1 - rho) / (1 + rho))."""
        return float(np.clip(self.n_obs * (1 - self.rho1) / (1 + self.rho1),
                             self.n_params + 10, max(self.n_obs, self.n_params + 10)))


def pooled(per_zone: dict[str, float]) -> float:
    v = [x for x in per_zone.values() if np.isfinite(x)]
    return float(np.sqrt(np.mean(np.square(v)))) if v else float("nan")


@dataclass
class Task:
    """One candidate to fit: picklable, so a process pool can take it. Fits are bounded by
    their iteration counts, never by the clock, so that a diagnosis does not depend on how
    busy the machine is."""

    effects: tuple[str, ...]
    options: dict[str, dict]
    fit_data: list[Experiment]
    holdout: list[Experiment]
    tail_of: list[int | None]  # per holdout: index of the fit experiment it continues
    init: dict[str, float] | None
    seed: int
    cold_too: bool = False
    """Also search from scratch (linear structures): worth it when the baseline bent far to
    absorb the effect (seen with strong zone burners: a = 1, d = 11), which can hold a warm
    start in a side valley."""
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    """Search boxes narrower than the effect's own: a time within the record, not 0-1e6 min."""
    cold_above: dict[str, float] | None = None
    """Per zone: the cold search is skipped when the warm fit is already below these."""
    generations: int | None = None
    """Generations of a search from scratch (init None); None: the fit's default."""


def structure_of(effects: tuple[str, ...], options: dict[str, dict]) -> ModelStructure:
    items: list[Effect] = [EFFECTS[n](**options.get(n, {})) for n in effects]
    return ModelStructure(items)


def run_task(task: Task) -> CandidateResult:
    """Fit and score one candidate. A candidate whose fit fails (a parameter set the
    simulator cannot integrate) is reported as failed, with the reason, and earns no
    credit: one bad candidate must not end the diagnosis."""
    t0 = time.perf_counter()
    try:
        return _run_task(task, t0)
    except Exception as exc:  # noqa: BLE001 - any failure of one candidate is reported as such
        if not task.effects:
            raise
        nan = {z: float("nan") for z in ZONES}
        return CandidateResult(task.effects, {}, {}, dict(nan), dict(nan), identifiable=False,
                               note=f"fit failed: {type(exc).__name__}: {exc}",
                               options={n: dict(task.options.get(n, {})) for n in task.effects},
                               elapsed_s=time.perf_counter() - t0)


def _run_task(task: Task, t0: float) -> CandidateResult:
    structure = structure_of(task.effects, task.options)
    init = None
    if task.init is not None:
        init = {k: v for k, v in task.init.items() if k in structure.names}
        if not structure.linear:
            # Integrated, not closed form: no evolutionary search, only the polish from the
            # baseline with the effect at its default strength.
            init = {**structure.defaults(), **init}
    bounds = {k: v for k, v in task.bounds.items() if k in structure.names}
    if init is not None:
        init = {k: (float(np.clip(v, *bounds[k])) if k in bounds else v) for k, v in init.items()}
    # The baseline is cheap and everything is measured against it: three independent
    # searches, so that a side valley of eq. 11 is not mistaken for a gap.
    # Linearised intervals (with the residual's colour): the profiles' refits would cost
    # more than the candidate's fit, and the verdict reads the white ones.
    runs = 3 if not task.effects else 1
    fr = fit(task.fit_data, structure, init=init, seed=task.seed, zone_offsets=True,
             runs=runs, bounds=bounds, generations=task.generations, profile=False)
    off_floor = task.cold_above is None or any(
        fr.per_zone[z]["rmse_c"] > task.cold_above[z] for z in ZONES)
    if init is not None and structure.linear and task.cold_too and off_floor:
        cold = fit(task.fit_data, structure, seed=task.seed + 1, zone_offsets=True,
                   bounds=bounds, profile=False)
        if cold.sse < fr.sse:
            fr = cold
    fit_pred = fitted_predictions(fr, task.fit_data)
    unseen = unseen_by_fit(fr, bounds) if any(j is None for j in task.tail_of) else ()
    hold_pred = holdout_predictions(fr, task.fit_data, task.holdout, task.tail_of, unseen)
    res = [e.zone_temp - p for e, p in zip(task.fit_data, fit_pred, strict=True)]
    hold_res = [e.zone_temp - p for e, p in zip(task.holdout, hold_pred, strict=True)]
    n_hold = int(sum(np.isfinite(r).sum() for r in hold_res))
    ident, note = identifiable(fr, task.effects)
    if unseen:
        note = "; ".join(x for x in (note, f"{', '.join(unseen)} unseen by the fitted data: "
                                     "estimated on the held-out data") if x)
    return CandidateResult(
        effects=task.effects, params=dict(fr.params),
        ci95={k: (float(v[0]), float(v[1])) for k, v in fr.ci95.items()},
        rmse_fit_c=rmse_per_zone(task.fit_data, fit_pred),
        rmse_holdout_c=rmse_per_zone(task.holdout, hold_pred),
        identifiable=ident, note=note, fit_pred=fit_pred, holdout_pred=hold_pred,
        options={n: dict(task.options.get(n, {})) for n in task.effects},
        sse_fit=fr.sse, n_obs=fr.n_obs,
        n_params=len(structure.names) + 6 * len(task.fit_data),
        rho1=lag1(res), rho1_holdout=lag1(hold_res), n_holdout=n_hold,
        held_out_fitted=unseen, elapsed_s=time.perf_counter() - t0, warnings=list(fr.warnings))


def unseen_by_fit(fr: FitResult, bounds: dict[str, tuple[float, float]]) -> tuple[str, ...]:
    """The paper's parameters the fitted data do not see at all. An extension can take away
    what the baseline saw: with the heating- and preheating-zone burners heating their own
    zones, the soaking-burner gain f rests on the soaking-zone burners alone, and a record
    in which they never step leaves it anywhere. An effect's own parameter the data do not
    determine already costs the effect its credit."""
    unc = fr.uncertainty
    if unc is None:
        return ()
    box = {p.name: bounds.get(p.name, (p.lo, p.hi)) for p in fr.structure.params}
    out = unc.unseen(np.array([box[n][0] for n in unc.names]),
                     np.array([box[n][1] for n in unc.names]))
    return tuple(n for n in ModelStructure().names if n in out)


def fitted_predictions(fr: FitResult, data: list[Experiment]) -> list[np.ndarray]:
    """The fitted model as the thermocouples read it, its zone offsets included."""
    return [fr.predict(j) for j in range(len(data))]


def holdout_predictions(fr: FitResult, data: list[Experiment], holdout: list[Experiment],
                        tail_of: list[int | None], unseen: tuple[str, ...] = ()
                        ) -> list[np.ndarray]:
    """Held-out predictions with the parameters fixed. A whole held-out experiment gets
    its own initial state and offsets from its data, and the parameters in `unseen` (by
    the fitted data) are estimated on the whole held-out experiments together; a
    tail cut from a fitted experiment continues the fitted run (same start, same
    thermocouples): nothing is estimated on it."""
    out: list[np.ndarray | None] = [None] * len(holdout)
    whole = [i for i, j in enumerate(tail_of) if j is None]
    if whole:
        refined = fr.refine([holdout[i] for i in whole], free=unseen)
        for k, i in enumerate(whole):
            out[i] = refined.predict(k)
    for i, j in enumerate(tail_of):
        if j is None:
            continue
        joined = join(data[j], holdout[i])
        out[i] = fr.predict(joined, fr.x0[j], fr.offsets(j))[len(data[j]):]
    return [p for p in out if p is not None]


def join(head: Experiment, tail: Experiment) -> Experiment:
    return Experiment(head.name, np.concatenate([head.t_min, tail.t_min]),
                      np.concatenate([head.tc, tail.tc]),
                      np.concatenate([head.burners, tail.burners]),
                      np.concatenate([head.t_air, tail.t_air]), head.start_time, head.source)


def rmse_per_zone(data: list[Experiment], preds: list[np.ndarray]) -> dict[str, float]:
    if not data:
        return {z: float("nan") for z in ZONES}
    r = np.concatenate([e.zone_temp - p for e, p in zip(data, preds, strict=True)])
    out = {}
    for w, z in enumerate(ZONES):
        v = r[:, w][np.isfinite(r[:, w])]
        out[z] = float(np.sqrt(np.mean(v * v))) if v.size else float("nan")
    return out


def identifiable(fr: FitResult, effects: tuple[str, ...]) -> tuple[bool, str]:
    """Whether every effect has a strength parameter that the data determine away from the
    value at which it vanishes; else the reason, in words."""
    notes = []
    for name in effects:
        effect = next(e for e in fr.structure.effects if e.name == name)
        box = {p.name: p for p in effect.params}
        ok_any, why = False, []
        for pname, null in NULL[name].items():
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
            notes.append(f"{name}: the data do not determine it ({'; '.join(why)})")
    return not notes, "; ".join(notes)


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
    fl2 = float(np.mean([floor[z] ** 2 for z in ZONES]))
    excess = rb * rb - fl2
    c.gap_closed_pct = float(100.0 * (rb * rb - rc * rc) / excess) if excess > 0 else 0.0
    n = c.n_obs
    if n and c.sse_fit > 0 and base.sse_fit > 0:
        neff = c.n_eff()
        c.delta_bic = float(neff * np.log(c.sse_fit / base.sse_fit)
                            + (c.n_params - base.n_params) * np.log(neff))
    else:
        c.delta_bic = 0.0
    # Held-out evidence: the Gaussian log-likelihood ratio on data the fit has not seen,
    # counted in effective samples; with the fit's BIC it ranks candidates whose held-out
    # errors are within noise of each other (a lag and a dead time both near the floor).
    # A parameter estimated on the held-out data is charged as BIC charges one.
    rho = c.rho1_holdout
    n_ho = c.n_holdout * (1 - rho) / (1 + rho)
    c.evidence = c.delta_bic + (n_ho * np.log(rc * rc / (rb * rb)) if rb > 0 and rc > 0 else 0.0)
    if n_ho > 1:
        c.evidence += (len(c.held_out_fitted) - len(base.held_out_fitted)) * np.log(n_ho)


def check_effects(names) -> tuple[str, ...]:
    names = tuple(names)
    bad = [n for n in names if n not in EFFECTS]
    if bad:
        raise FurnaceError(f"unknown effect(s) {', '.join(bad)}: expected names from "
                           f"{', '.join(EFFECTS)}")
    return names
