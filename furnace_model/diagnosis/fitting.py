"""Candidate extensions of the paper's model: each fitted on the fit data, warm-started from
the baseline, and predicted on held-out data with its parameters fixed."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from ..effects import EFFECTS, Effect
from ..experiment import Experiment
from ..identification.carried import carried_error, carried_onto_tail
from ..identification.equationerror import equation_error_starts
from ..identification.fit import WarmStart, fit
from ..identification.model import Refinement
from ..identification.noisefloor import limits, pooled_floor, record_floor
from ..identification.residuals import lag1
from ..identification.result import FitResult
from ..identification.uncertainty import within
from ..simulation.furnace import Furnace
from ..simulation.structure import Inputs, ModelStructure
from .candidate import CandidateResult
from .credit import CARRIED_Z, identifiable

BASELINE_RUNS = 3
"""The baseline is cheap and everything is measured against it: independent searches, so
that a side valley of eq. 11 is not mistaken for a gap."""
SAME_END = 1e-6
"""Two searches whose criteria lie within this share of each other ended in one minimum:
the polish stops when a step gains less than a tenth of it, so two that meet agree far
closer (docs/performance.md, "The baseline's third search")."""

AT_FLOOR_Z = 1.0
"""Standard errors of the RMSE-to-floor ratio (`noisefloor.limits`) within which a fit
follows its records to their noise in every zone, and further starts are not polished: what
they could still take off is the noise's own scatter, not the model's error."""


@dataclass
class Task:
    """One candidate to fit: picklable, so a process pool can take it. Fits are bounded by
    their iteration counts, not by the clock, so that a diagnosis does not depend on how
    busy the machine is; only a time limit the user asks for (`deadline`) cuts them."""

    effects: tuple[str, ...]
    options: dict[str, dict]
    fit_data: list[Experiment]
    holdout: list[Experiment]
    tail_of: list[int | None]  # per holdout: index of the fit experiment it continues
    init: dict[str, float] | None
    seed: int
    cold_too: bool = False
    """Also search from scratch in the task (linear structures), the lower fit kept: a
    logged signal's gain started from a baseline bent far to do without it (as strong zone
    burners bend a to 1 and d to 11) can stay in that side valley."""
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    """Search boxes narrower than the effect's own: a time within the record, not 0-1e6 min."""
    generations: int | None = None
    """Generations of a search from scratch (init None); None: the fit's default."""
    baseline_sse: float | None = None
    """The baseline's fit criterion, with `init` the baseline's parameters: the candidate is
    the baseline at its effects' nulls, so a fit of it that ends above this is polished
    again from there (`_from_null`)."""
    baseline_end: WarmStart | None = None
    """Where the baseline's fit ended on each fitted record (its offsets and initial
    states): `_from_null` starts there, at the baseline's own criterion."""
    runs: int | None = None
    """Independent searches of a search from scratch; None: BASELINE_RUNS for the baseline,
    one for a candidate."""
    settled: tuple[str, ...] = ()
    """Effects whose parameters `init` holds from a fit of these records with them in (a
    combination's kept effects; all of them in a refit of the kept set): their further
    starts (`_restarted`) are not tried again, since that fit placed them."""
    deadline: float | None = None
    """time.monotonic() by which the diagnosis must answer (its --time-limit): a fit still
    running then stops, and the candidate is named as not tried."""
    told: tuple[str, ...] = ()
    """The told parameters `profile_told` profiles (none: all of `told_names`)."""
    start_on: list[Experiment] | None = None
    """Records whose baseline fit, with what they determine, replaces `init` (the rest
    searched; `Trial.start_on`): fitted in the task, so in the pool beside the others."""

    @property
    def furnace(self) -> Furnace:
        return self.fit_data[0].furnace


def structure_of(effects: tuple[str, ...], options: dict[str, dict],
                 furnace: Furnace) -> ModelStructure:
    items: list[Effect] = [EFFECTS[n](**options.get(n, {}), furnace=furnace) for n in effects]
    return ModelStructure(items, furnace=furnace)


def baseline_tasks(fit_data: list[Experiment], holdout: list[Experiment],
                   tail_of: list[int | None], seed: int) -> list[Task]:
    """The baseline's searches as one task each, for a pool to run side by side: the
    lowest criterion among their results is the baseline `run_task` fits in one task with
    BASELINE_RUNS runs (run r of a fit uses seed + r); the diagnosis runs the first two,
    and the others only where those two end apart (`baseline_settled`). One task where no
    seed moves the search: on a network of many zones the baseline is polished from the
    equations' least squares (`identification.fit.seeded`)."""
    runs = BASELINE_RUNS if fit_data[0].furnace.paper_structure else 1
    return [Task((), {}, fit_data, holdout, tail_of, None, seed + r, runs=1)
            for r in range(runs)]


def baseline_settled(first: list[CandidateResult]) -> bool:
    """Whether the baseline's first searches leave nothing for the others: two from
    different seeds that ended in one minimum (`SAME_END`) have found the one the others
    find, and each further search costs as much as they did."""
    if len(first) < 2:
        return False
    sse = sorted(c.sse_fit for c in first[:2])
    return bool(np.isfinite(sse[1]) and sse[1] - sse[0] <= SAME_END * sse[0])


def run_task(task: Task) -> CandidateResult:
    """Fit and score one candidate. A candidate whose fit fails (a parameter set the
    simulator cannot integrate) is reported as failed, with the reason, and earns no
    credit: one bad candidate must not end the diagnosis."""
    t0 = time.perf_counter()
    if task.deadline is not None and time.monotonic() >= task.deadline:
        return not_tried(task)
    try:
        return _run_task(task, t0)
    except Exception as exc:  # noqa: BLE001 - any failure of one candidate is reported as such
        if not task.effects:
            raise
        nan = {z: float("nan") for z in task.furnace.zones}
        return CandidateResult(task.effects, {}, {}, dict(nan), dict(nan), identifiable=False,
                               note=f"fit failed: {type(exc).__name__}: {exc}",
                               options={n: dict(task.options.get(n, {})) for n in task.effects},
                               elapsed_s=time.perf_counter() - t0)


def not_tried(task: Task) -> CandidateResult:
    """A candidate the time limit left unfitted (the baseline has no limit: everything is
    measured against it)."""
    nan = {z: float("nan") for z in task.furnace.zones}
    return CandidateResult(task.effects, {}, {}, dict(nan), dict(nan), identifiable=False,
                           note="not tried within the time limit", cut=True,
                           options={n: dict(task.options.get(n, {})) for n in task.effects})


def told_names(c: CandidateResult) -> list[str]:
    """The parameters of c's effects that its verdict gives with intervals (`Effect.told`)."""
    return [p for n in c.effects for p in EFFECTS[n].told if p in c.params]


def end_task(c: CandidateResult, fit_data: list[Experiment], holdout: list[Experiment],
             tail_of: list[int | None], seed: int,
             bounds: dict[str, tuple[float, float]], told: tuple[str, ...] = ()) -> Task:
    """c's model refitted from where its fit ended, for a profile from its optimum
    (`profile_told`, `profile_strength`; its own end in `baseline_end`: the warm start a
    fit of the model nested in it would take); `told`: the parameters `profile_told`
    profiles, one task each for a pool (each profile is a search of its own from the same
    end), none: all."""
    return Task(c.effects, c.options, fit_data, holdout, tail_of, dict(c.params),
                seed, bounds={k: v for k, v in bounds.items() if k in c.params},
                baseline_end=c.ended, told=told)


def profile_told(task: Task, kept: CandidateResult) -> CandidateResult:
    """kept with the intervals of its told parameters (`told_names`) profiled on the fitted
    records (`told_interval`): the candidates' fits give linearised intervals, which rank
    them well enough, but the verdict's are read by someone who replaces a thermocouple
    from them, and a drift's onset trades with its rate along a valley far from quadratic
    (docs/diagnosis.md, "The verdict's intervals"). The parameters stay the kept fit's,
    unless a profile's refit ended lower than it (`FitResult.moves`: a drift's onset has
    side valleys that follow the records to their noise as well as the lowest, and an
    interval drawn around one of them can miss the truth): then the candidate as fitted in
    that lower valley, its intervals drawn there (`moved`, with a lower `sse_fit`).
    Cut by the time limit: kept as it was, marked `cut`. Only `task.told` when it names any."""
    t0 = time.perf_counter()
    names = list(task.told) or told_names(kept)
    if not names or (task.deadline is not None and time.monotonic() >= task.deadline):
        return dataclasses.replace(kept, cut=bool(names))
    structure = structure_of(task.effects, task.options, task.furnace)
    fr = fit(task.fit_data, structure, init=task.init, zone_offsets=True, bounds=task.bounds,
             profile=names, warm=task.baseline_end, time_budget_s=_budget(task))
    if fr.stop_reason == "time_budget" or (task.deadline is not None
                                           and time.monotonic() >= task.deadline):
        return dataclasses.replace(kept, cut=True)
    if fr.moves and fr.sse < kept.sse_fit:
        kept = scored(fr, task, structure, task.bounds, t0)
        lin = fr.linearised_ci95()
        kept.ci95.update({n: lin[n] for n in names if n in lin})
    ci = dict(kept.ci95)
    for n in fr.profiled:
        ci[n] = told_interval(kept.ci95[n], fr.ci95[n], kept.params[n])
    return dataclasses.replace(kept, ci95=ci)


def moved(kept: CandidateResult, parts: list[CandidateResult]) -> CandidateResult | None:
    """The lowest of `profile_told`'s results that left kept's valley for a lower one (None:
    none did)."""
    lower = [c for c in parts if not c.cut and c.sse_fit < kept.sse_fit]
    return min(lower, key=lambda c: c.sse_fit) if lower else None


def strengths_inside(effects: tuple[str, ...], options: dict[str, dict],
                     params: dict[str, float], furnace: Furnace,
                     bounds: dict[str, tuple[float, float]]) -> list[str]:
    """The effects' strength parameters (`Tried.nulls`) whose values in `params` lie inside
    their search boxes: one on an edge has an interval that reaches it, however profiled."""
    structure = structure_of(effects, options, furnace)
    out = []
    for effect in structure.effects:
        box = {p.name: bounds.get(p.name, (p.lo, p.hi)) for p in effect.params}
        for name in effect.tried.nulls(effect):
            if name in box and name in params:
                lo, hi = box[name]
                margin = 1e-6 * (hi - lo)
                if lo + margin < params[name] < hi - margin:
                    out.append(name)
    return out


def profile_strength(task: Task) -> CandidateResult:
    """Whether the data determine the strength of the task's model (`identifiable`), judged
    on its strength parameters' white intervals profiled from where its fit ended
    (`fit`'s `white_profile`; the task from `end_task`): a linearisation spreads every
    parameter along a direction the criterion leaves nearly flat, so that a strength the
    criterion pins to a few percent looks like anything from a trace to a flood (a wall
    behind a room's air that settles within the hour between its rows: docs/diagnosis.md,
    step 5). Only the judgement is returned (`identifiable`, `note`, and the intervals
    profiled as `ci95`); cut by the time limit: marked `cut`."""
    names = strengths_inside(task.effects, task.options, task.init or {}, task.furnace,
                             task.bounds)
    structure = structure_of(task.effects, task.options, task.furnace)
    nan = {z: float("nan") for z in task.furnace.zones}
    judged = CandidateResult(task.effects, {}, {}, dict(nan), dict(nan), identifiable=False,
                             cut=True)
    if not names or _late(task):
        return judged
    fr = fit(task.fit_data, structure, init=task.init, zone_offsets=True, bounds=task.bounds,
             profile=False, warm=task.baseline_end, time_budget_s=_budget(task),
             white_profile=names)
    if fr.stop_reason == "time_budget" or _late(task):
        return judged
    ident, note = identifiable(fr, task.effects)
    return dataclasses.replace(judged, identifiable=ident, note=note, cut=False,
                               ci95={n: fr.ci95_white[n] for n in names})


def with_told(kept: CandidateResult, told: list[str], parts: list[CandidateResult]
              ) -> tuple[CandidateResult, str | None]:
    """kept with the intervals of the `told` parameters whose profiles ran (`parts`, one
    `profile_told` each, in the order of `told`), and what to name among the untried where
    the time limit cut some (None: it cut none); a cut one keeps its linearised interval."""
    cut = [n for n, part in zip(told, parts, strict=True) if part.cut]
    ci = dict(kept.ci95)
    ci.update({n: part.ci95[n] for n, part in zip(told, parts, strict=True) if not part.cut})
    which = "" if len(cut) == len(told) else f" ({', '.join(cut)})"
    words = (f"the profiled intervals of {kept.label}{which} (linearised ones given)"
             if cut else None)
    return (kept if len(cut) == len(told) else dataclasses.replace(kept, ci95=ci)), words


def told_interval(linearised: tuple[float, float], profiled: tuple[float, float],
                  value: float) -> tuple[float, float]:
    """Each end the further of the two. The profile follows the criterion where the
    quadratic does not hold (the onset's side of the valley it shares with the rate), but
    where the criterion rises faster than the quadratic it narrows that end, and with a
    hinge neither is exact: on a few hours of drift the profile alone holds the rate less
    often than the linearised interval, and the linearised holds the onset far less often
    (docs/diagnosis.md)."""
    return within((min(linearised[0], profiled[0]), max(linearised[1], profiled[1])), value)


def determined(records: list[Experiment], seed: int) -> dict[str, float]:
    """The baseline fitted on `records`, with the parameters they determine."""
    fr = fit(records, ModelStructure(furnace=records[0].furnace), seed=seed, zone_offsets=True,
             profile=False)
    return {k: v for k, v in fr.params.items() if k not in fr.undetermined}


def _budget(task: Task) -> float | None:
    return None if task.deadline is None else max(task.deadline - time.monotonic(), 0.0)


def _run_task(task: Task, t0: float) -> CandidateResult:
    if task.start_on:
        start = determined(task.start_on, task.seed)
        task = dataclasses.replace(task, start_on=None, **(
            {"init": start, "baseline_sse": None, "baseline_end": None} if start else {}))
    structure = structure_of(task.effects, task.options, task.furnace)
    init, bounds = _start_of(task, structure)
    # Linearised intervals (with the residual's colour): the profiles' refits would cost
    # more than the candidate's fit, and the verdict reads the white ones.
    runs = task.runs or (BASELINE_RUNS if not task.effects else 1)
    fr = fit(task.fit_data, structure, init=init, seed=task.seed, zone_offsets=True,
             runs=runs, bounds=bounds, generations=task.generations, profile=False,
             time_budget_s=_budget(task))
    # A step the time limit leaves out makes the candidate not tried, never a lesser fit:
    # a candidate that is named fitted ends as it would without a limit (limit.TimeLimit).
    if init is not None and fr.stop_reason != "time_budget":
        fr = _restarted(fr, task, structure, init, bounds)
    if init is not None and task.baseline_sse is not None and fr.sse > task.baseline_sse \
            and fr.stop_reason != "time_budget":
        fr = _from_null(fr, task, structure, init, bounds)
    if init is not None and structure.linear and task.cold_too \
            and fr.stop_reason != "time_budget":
        if _late(task):
            return not_tried(task)
        cold = fit(task.fit_data, structure, seed=task.seed + 1, zone_offsets=True,
                   bounds=bounds, profile=False, time_budget_s=_budget(task))
        if cold.stop_reason == "time_budget":
            return not_tried(task)
        if cold.sse < fr.sse:
            fr = cold
    if fr.stop_reason == "time_budget":
        return not_tried(task)
    return scored(fr, task, structure, bounds, t0)


def scored(fr: FitResult, task: Task, structure: ModelStructure,
           bounds: dict[str, tuple[float, float]], t0: float) -> CandidateResult:
    """The task's candidate as `fr` fitted it: predicted on the held-out data, scored."""
    zones = task.furnace.zones
    fit_pred = fitted_predictions(fr, task.fit_data)
    unseen = unseen_by_fit(fr, bounds)
    hold_pred, refined = holdout_predictions(fr, task.fit_data, task.holdout, task.tail_of,
                                             unseen)
    carried = fr.carried_offsets()
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
        rmse_fit_c=rmse_per_zone(task.fit_data, fit_pred, zones),
        rmse_holdout_c=rmse_per_zone(task.holdout, hold_pred, zones),
        identifiable=ident, note=note, fit_pred=fit_pred, holdout_pred=hold_pred,
        options={n: EFFECTS[n].tried.named(dict(task.options.get(n, {})), fr.params,
                                           task.fit_data) for n in task.effects},
        sse_fit=fr.sse, n_obs=fr.n_obs,
        n_params=len(structure.names) + 2 * len(zones) * len(task.fit_data),
        rho1=lag1(res), rho1_holdout=lag1(hold_res), n_holdout=n_hold,
        held_out_fitted=unseen, carried_c=_carried(fr, task, refined, unseen),
        elapsed_s=time.perf_counter() - t0, warnings=list(fr.warnings),
        offsets_c=None if carried is None else dict(zip(zones, map(float, carried), strict=True)),
        ended=WarmStart(offsets=fr.zone_offsets_c, x0=[x.tolist() for x in fr.x0]),
        offsets_undetermined=undetermined_offsets(fr),
        holdout_offsets_c=None if refined is None else refined.zone_offsets_c,
        rmse_holdout_carried_c=(None if task.effects else
                                _with_carried_offsets(fr, task, hold_pred, unseen)),
        flags=[f.words() for f in [*fr.flags, *(refined.flags if refined else [])]])


def undetermined_offsets(fr: FitResult) -> tuple[str, ...]:
    """The zones whose offset some fitted record leaves undetermined: an interval wider
    than the box a thermocouple's bias allows. A furnace held at its setpoints cannot tell
    a shift of its readings from a shift of its level, which its rates take up."""
    if not fr.zone_offsets_c or not fr.bounds_c:
        return ()
    out = []
    for z in fr.zone_offsets_c[0]:
        for j in range(len(fr.zone_offsets_c)):
            ci = (fr.zone_offsets_ci95_c or [{}] * (j + 1))[j].get(z)
            lo, hi = fr.bounds_c[j]["offset"][z]
            if ci is not None and ci[1] - ci[0] > hi - lo:
                out.append(z)
                break
    return tuple(out)


def _late(task: Task) -> bool:
    return task.deadline is not None and time.monotonic() >= task.deadline


def _with_carried_offsets(fr: FitResult, task: Task, hold_pred: list[np.ndarray],
                          unseen: tuple[str, ...]) -> dict[str, float]:
    """The held-out RMSE per zone with the offsets the fit carries held on every whole
    held-out record (its initial state still its own): a model that misses the held-out
    data cannot hide behind offsets there. A tail continues the fitted run as it is."""
    carried = fr.carried_offsets()
    whole = [i for i, j in enumerate(task.tail_of) if j is None]
    preds = list(hold_pred)
    if whole and carried is not None:
        held = fr.refine([task.holdout[i] for i in whole], free=unseen,
                         offsets=[carried] * len(whole))
        for k, i in enumerate(whole):
            preds[i] = held.predict(k)
    return rmse_per_zone(task.holdout, preds, task.furnace.zones)


def _restarted(fr: FitResult, task: Task, structure: ModelStructure, init: dict[str, float],
               bounds: dict[str, tuple[float, float]]) -> FitResult:
    """The fit polished again from the effects' further starts (`Tried.starts`), the best
    kept, unless it already follows the records to their noise (`AT_FLOOR_Z`). On a network,
    a thermocouple's error from a start is also taken off the readings and the network
    started where the equations' least squares fit what is left: a large drift (tens of
    degrees on one of a pair) bends the baseline so far that from its rates the drift's fit
    finds only side valleys. The starts are one fit (`fit`'s `further`): each scouted ten
    steps, then polished on in the scouts' order until one follows the records to their
    noise. A start polished to its end costs an integrated model minutes, and the one that
    reaches the floor is mostly among the first scouts; where none does, they are polished
    on while they still find lower ends (`fit`'s `STALLED_STARTS`), the lowest kept."""
    floor = limits([record_floor(e) for e in task.fit_data], 1.0, AT_FLOOR_Z)

    def at_floor(per_zone: dict[str, dict[str, float]]) -> bool:
        return all(per_zone[z]["rmse_c"] <= floor[z] for z in floor if z in per_zone)
    if at_floor(fr.per_zone):
        return fr
    own, again = _starts(structure, init, bounds, task.settled)
    starts = own + [{**v, **net} for v in again
                    for net in _networks_for(structure, v, task.fit_data)]
    if not starts:
        return fr
    if _late(task):
        return dataclasses.replace(fr, stop_reason="time_budget")
    other = fit(task.fit_data, structure, init=starts[0], further=starts[1:], enough=at_floor,
                seed=task.seed, zone_offsets=True, bounds=bounds, profile=False,
                time_budget_s=_budget(task))
    if other.stop_reason == "time_budget":  # a search left unfinished: not tried
        return dataclasses.replace(fr, stop_reason="time_budget")
    return other if other.sse < fr.sse else fr


def _start_of(task: Task, structure: ModelStructure
              ) -> tuple[dict[str, float] | None, dict[str, tuple[float, float]]]:
    """Where the task's polish starts (None: a search from scratch), and its search box."""
    bounds = {k: v for k, v in task.bounds.items() if k in structure.names}
    if task.init is None:
        return None, bounds
    init = {k: v for k, v in task.init.items() if k in structure.names}
    if not structure.linear:
        # Integrated, not closed form: no evolutionary search, only the polish from the
        # baseline with the effect at its default strength.
        init = {**structure.defaults(), **init}
    return {k: (float(np.clip(v, *bounds[k])) if k in bounds else v)
            for k, v in init.items()}, bounds


def _starts(structure: ModelStructure, init: dict[str, float],
            bounds: dict[str, tuple[float, float]], settled: tuple[str, ...] = ()
            ) -> tuple[list[dict[str, float]], list[dict[str, float]]]:
    """`_restarted`'s starts: the effects' own, and those also started with the network the
    equations' least squares give (none on eq. 11's furnace). None for the `settled`
    effects, nor their networks: the kept effects' fit placed them and left their network
    unbent by them."""
    given = {**structure.defaults(), **init}
    restarts, placed = [], [given]
    new = [e for e in structure.effects if e.name not in settled]
    for e in new:
        for s in e.tried.starts(e, init, bounds):
            restarts.append({**given, **s})
            if set(s) <= set(e.tried.nulls(e)):  # a strength alone (a drift's sign): still placed
                placed.append(restarts[-1])
    if structure.furnace.paper_structure or not new:
        return restarts, []
    bending = ModelStructure(new, furnace=structure.furnace)
    if bending.has_sensor_offsets:
        # not for a spread of onsets: an error not placed would be taken off at random
        return restarts, placed
    # a change of the inputs at any instant is a start: the polish moves it
    return restarts, [given, *restarts] if bending.moves_inputs else []


def relative_cost(task: Task) -> float:
    """About what a task costs, in fits of a linear model, for a pool to start the longest
    first (one started last and alone sets when the stage ends): a fit of an integrated
    model costs about three, and each restart a tenth of a first fit, which has the
    evolutionary search."""
    structure = structure_of(task.effects, task.options, task.furnace)
    init, bounds = _start_of(task, structure)
    restarts = 0 if init is None else sum(map(len, _starts(structure, init, bounds,
                                                           task.settled)))
    return (1.0 if structure.linear else 3.0) * (1.0 + 0.1 * restarts)


def _from_null(fr: FitResult, task: Task, structure: ModelStructure, init: dict[str, float],
               bounds: dict[str, tuple[float, float]]) -> FitResult:
    """The candidate polished from its effects' nulls (the baseline itself, its offsets and
    initial states where the baseline's fit ended: `Task.baseline_end`), where its fit ended
    above the baseline: started at a strength far from the data's (radiation's half share on
    a furnace with none), the polish can stop at its iteration limit in a valley worse than
    no effect at all, and such a candidate would be scored for where its search stopped,
    not for what the effect can do. From the baseline's parameters alone, its offsets and
    initial states started again from the readings, the polish can end in such a valley
    too. Not for an effect whose null is only that its
    parameter be determined (NaN): the baseline is not nested in it."""
    null: dict[str, float] = {}
    for e in structure.effects:
        values = e.tried.nulls(e)
        if not values or not all(np.isfinite(v) for v in values.values()):
            return fr
        null.update(values)
    if _late(task):
        return dataclasses.replace(fr, stop_reason="time_budget")
    other = fit(task.fit_data, structure, init={**init, **null}, seed=task.seed,
                zone_offsets=True, bounds=bounds, profile=False, time_budget_s=_budget(task),
                warm=task.baseline_end)
    if other.stop_reason == "time_budget":
        return dataclasses.replace(fr, stop_reason="time_budget")
    return other if other.sse < fr.sse else fr


def _networks_for(structure: ModelStructure, values: dict[str, float],
                  records: list[Experiment]) -> list[dict[str, float]]:
    """The network's rates the equations' least squares put on `records` with the sensor
    error of `values` taken off their readings and their inputs as its effects make them
    (a fuel switch, a delay): the rates of a baseline bent to absorb the effect hold the
    candidate's polish in a side valley even from the effect's true values. Where the
    integrated equations put a rate on a bound of its box (a zone that settles within a
    sample loses its rates' scale there, a valley the polish may not leave), each further
    distinct start a fit from scratch has (`equation_error_starts`) as well."""
    nz = structure.furnace.n_zones
    theta = structure.theta(values)
    clean = []
    for e in records:
        t = np.asarray(e.t_min, dtype=float)
        u = structure.drive(theta, Inputs.of(e)).levels_at(t)[0]
        clean.append(dataclasses.replace(
            e, tc=e.tc - structure.sensor_offsets(values, t)[0], burners=u[:, :nz],
            disturbances=u[:, nz + 1:]))
    network = ModelStructure(furnace=structure.furnace)
    first, *others = equation_error_starts(network, clean)
    box = {p.name: p for p in network.params}
    on_bound = any(not box[n].lo < v < box[n].hi for n, v in first.items())
    return [first, *others] if on_bound else [first]


def _carried(fr: FitResult, task: Task, refined: Refinement | None,
             unseen: tuple[str, ...]) -> dict[str, float]:
    """What the fit's uncertainty carries onto the held-out records, at the gap's level of
    evidence: onto whole records with their own start and offsets re-estimated
    (`carried.carried_error`), onto a tail of a fitted record with the fitted start and
    offsets it continues from (`carried.carried_onto_tail`; `split` cuts at most one), but
    for the `unseen` parameters, which the held-out data set."""
    floors = pooled_floor([record_floor(e) for e in task.fit_data])
    counts = {z: sum(int(np.isfinite(e.zone_temp[:, w]).sum()) for e in task.fit_data)
              for w, z in enumerate(task.furnace.zones)}
    noise = float(np.sqrt(sum(counts[z] * floors[z] ** 2 for z in counts if np.isfinite(floors[z]))
                          / max(sum(counts[z] for z in counts if np.isfinite(floors[z])), 1)))
    if refined is None:
        tails = [(i, j) for i, j in enumerate(task.tail_of) if j is not None]
        if not tails:
            return dict.fromkeys(task.furnace.zones, 0.0)
        i, j = tails[0]
        return carried_onto_tail(fr, join(task.fit_data[j], task.holdout[i]),
                                 len(task.fit_data[j]), fr.x0[j], fr.offsets(j), noise,
                                 CARRIED_Z, refitted=unseen)
    whole = [task.holdout[i] for i, j in enumerate(task.tail_of) if j is None]
    offsets = [np.array([o[z] for z in task.furnace.zones]) if o else np.zeros(len(counts))
               for o in (refined.zone_offsets_c or [None] * len(whole))]
    return carried_error(fr, whole, refined.x0, offsets, noise, CARRIED_Z)


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
    return tuple(n for n in ModelStructure(furnace=fr.structure.furnace).names if n in out)


def fitted_predictions(fr: FitResult, data: list[Experiment]) -> list[np.ndarray]:
    """The fitted model as the thermocouples read it, its zone offsets included."""
    return [fr.predict(j) for j in range(len(data))]


def holdout_predictions(fr: FitResult, data: list[Experiment], holdout: list[Experiment],
                        tail_of: list[int | None], unseen: tuple[str, ...] = ()
                        ) -> tuple[list[np.ndarray], Refinement | None]:
    """Held-out predictions with the parameters fixed, and what was estimated on the whole
    held-out experiments (None without one). A whole held-out experiment gets its own
    initial state and offsets from its data, and the parameters in `unseen` (by the fitted
    data) are estimated on the whole held-out experiments together; a tail cut from a
    fitted experiment continues the fitted run (same start, same thermocouples); where
    parameters are `unseen`, they are estimated on the run with its tail, the start again
    with them and the offsets held (a window whose fitted hours never charge a slab cannot
    say what charging does in the hours after)."""
    out: list[np.ndarray | None] = [None] * len(holdout)
    whole = [i for i, j in enumerate(tail_of) if j is None]
    refined = None
    if whole:
        refined = fr.refine([holdout[i] for i in whole], free=unseen)
        for k, i in enumerate(whole):
            out[i] = refined.predict(k)
    for i, j in enumerate(tail_of):
        if j is None:
            continue
        joined = join(data[j], holdout[i])
        if unseen:
            on_tail = fr.refine([joined], free=unseen, x0=[fr.x0[j]], offsets=[fr.offsets(j)])
            out[i] = on_tail.predict(0)[len(data[j]):]
        else:
            out[i] = fr.predict(joined, fr.x0[j], fr.offsets(j))[len(data[j]):]
    return [p for p in out if p is not None], refined


def join(head: Experiment, tail: Experiment) -> Experiment:
    return Experiment(head.name, np.concatenate([head.t_min, tail.t_min]),
                      np.concatenate([head.tc, tail.tc]),
                      np.concatenate([head.burners, tail.burners]),
                      np.concatenate([head.t_air, tail.t_air]), head.start_time, head.source,
                      furnace=head.furnace,
                      disturbances=np.concatenate([head.disturbances, tail.disturbances]),
                      signals={k: np.concatenate([v, tail.signals[k]])
                               for k, v in head.signals.items() if k in tail.signals})


def rmse_per_zone(data: list[Experiment], preds: list[np.ndarray],
                  zones: tuple[str, ...] | None = None) -> dict[str, float]:
    """`zones`: the furnace's (its records' when not given)."""
    if zones is None and not data:
        raise ValueError("no records to read the furnace's zones from: give `zones`")
    zones = zones or data[0].furnace.zones
    if not data:
        return {z: float("nan") for z in zones}
    r = np.concatenate([e.zone_temp - p for e, p in zip(data, preds, strict=True)])
    out = {}
    for w, z in enumerate(zones):
        v = r[:, w][np.isfinite(r[:, w])]
        out[z] = float(np.sqrt(np.mean(v * v))) if v.size else float("nan")
    return out
