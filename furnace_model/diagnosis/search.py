"""The search for the effects that explain the model's error: the baseline, each effect
alone (warm, and from scratch where the baseline bent), its further laws, then effects
added one at a time; the verdict is judged on what it keeps."""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable, Iterable, Sequence

import numpy as np

from ..blas import on_one_thread
from ..effects import EFFECTS, Clues
from ..errors import FurnaceError
from ..experiment import Experiment
from ..identification.noisefloor import (
    GAP_RATIO,
    GAP_Z,
    RecordFloor,
    limits,
    pooled_floor,
    record_floor,
)
from ..identification.residuals import residual_tests, sensor_faults
from .candidate import CandidateResult
from .credit import (
    MIN_GAP_CLOSED,
    NEAR_RATIO,
    NEAR_Z,
    closes,
    credited,
    near_floor,
    rank,
    score_against,
    strength_rejudged,
)
from .fitting import (
    Task,
    baseline_settled,
    baseline_tasks,
    end_task,
    moved,
    profile_strength,
    profile_told,
    strengths_inside,
    structure_of,
    told_names,
    with_told,
)
from .holdout import split, uncovered
from .laws import between_laws, further_laws, laws_named
from .limit import TimeLimit
from .locate import Located, locate
from .pool import run_all
from .result import Diagnosis
from .signals import prefer_signal, signal_candidates, unused_signals
from .verdict import judge

MAX_EFFECTS = 3
TOLD_ROUNDS = 2
"""Rounds of the told parameters' profiles: a round whose refits find a lower valley than
the kept fit's moves it there (`fitting.moved`), and the next profiles it from there; the
last round's lower valley is kept with the intervals its own fit drew."""
SSE_GAIN = 1e-3
"""The share by which a refit of the kept effects must lower their fitted squared error (or
their held-out error, refitted from a combination that closes the gap) to replace them:
more than an optimiser's tolerance, far less than a real side valley's step. A refit that
ends where the kept set did is not a second row of the table."""
STEP_TRIES = 8
"""Further effects tried at each step of the combination search, the best singles first: a
second effect may show nothing alone while a larger one dominates the error."""
COLD_GENERATIONS = 15
"""Generations of the search from scratch for a nonlinear candidate (32 sets each)."""
PASS = 0.075
"""The share of the progress each pass of searches from scratch and further laws (the
linear candidates', then the nonlinear ones') takes, between the candidates and the
combinations."""


def check_effects(names) -> tuple[str, ...]:
    names = tuple(names)
    bad = [n for n in names if n not in EFFECTS]
    if bad:
        raise FurnaceError(f"unknown effect(s) {', '.join(bad)}: expected names from "
                           f"{', '.join(EFFECTS)}")
    return names


@on_one_thread
def diagnose(data: list[Experiment], holdout: list[Experiment] | None = None, *,
             effects: Sequence[str] | None = None, seed: int = 0,
             progress: Callable[[str, float], None] | None = None,
             time_limit_s: float | None = None, cut: Iterable[str] | None = None
             ) -> Diagnosis:
    """Fit the baseline, locate its error, try every effect as an extension, and judge.

    `time_limit_s`: answer within about this long (the baseline always completes: every
    verdict is measured against it). What the limit leaves unfitted is named in
    `Diagnosis.untried`, and the verdict is judged on what was fitted. `cut`, in place of a
    time: the fits a limited run cut (its `Diagnosis.cut`), to repeat that run on any host
    (limit.TimeLimit)."""
    t_start = time.perf_counter()
    limit = TimeLimit(None if cut is not None else time_limit_s, cut)
    untried: list[str] = []

    def tried(results: list[CandidateResult]) -> list[CandidateResult]:
        untried.extend(c.label for c in results if c.cut and c.label not in untried)
        return [c for c in results if not c.cut]
    say = _onwards(progress)
    names = check_effects(EFFECTS if effects is None else effects)
    fit_data, hold, tail_of, how = split(data, holdout)
    furnace = fit_data[0].furnace
    zones = furnace.zones
    names = tuple(n for n in names if _applies(n, furnace, effects is not None))
    say("baseline", 0.0)
    searches = baseline_tasks(fit_data, hold, tail_of, seed)
    first, rest = searches[:2], searches[2:]
    share = len(first) / len(searches)
    base_runs = run_all(first, lambda f: say("baseline", 0.1 * share * f))
    if rest and not baseline_settled(base_runs):  # only where the first two end apart
        base_runs += run_all(rest, lambda f: say("baseline", 0.1 * (share + (1 - share) * f)))
    base = min(base_runs, key=lambda c: c.sse_fit)
    every = fit_data + hold
    floors = [record_floor(e) for e in every]
    fit_floors, hold_floors = floors[:len(fit_data)], floors[len(fit_data):]
    floor = pooled_floor(hold_floors)  # what the held-out RMSE, pooled alike, compares with
    fit_limit = limits(fit_floors, GAP_RATIO, GAP_Z)
    gap_limit = limits(hold_floors, GAP_RATIO, GAP_Z)
    near = limits(hold_floors, NEAR_RATIO, NEAR_Z)
    tc_noise = [{z: f.zones[z].tc_sd_c for z in zones} for f in floors]
    base_res = [e.zone_temp - p for e, p in zip(every, base.fit_pred + base.holdout_pred,
                                                strict=True)]
    faults = sensor_faults(every, base.fit_pred + base.holdout_pred, tc_noise)
    where = locate(every, base_res, floors, faults)
    tests = residual_tests(hold, [e.zone_temp - p for e, p in
                                  zip(hold, base.holdout_pred, strict=True)])
    # A gap stands clear of the noise and of what the baseline's own parameter uncertainty
    # carries onto the held-out records (`carried`).
    gap = tuple(z for z in zones if base.rmse_holdout_c[z] > base.allowed(gap_limit)[z])
    noise = {"record_floors": floors, "noise_floor_fit_c": pooled_floor(fit_floors),
             "gap_limit_c": base.allowed(gap_limit), "sensor_noise_c": _pooled_tc(floors)}

    clues = Clues(fit_data, every, predictions=base.fit_pred + base.holdout_pred,
                  furnace=furnace)
    if not gap:
        # Nothing to explain: no extension can beat the noise on held-out data.
        verdict = judge(base, None, [], floor, near, gap, where, furnace=furnace)
        say("done", 1.0)
        return Diagnosis(fit_data, hold, how, base, floor, where, tests, [], verdict,
                         time.perf_counter() - t_start, gap, **noise, time_limit_s=time_limit_s,
                         cut=limit.cut)

    def explains(results: list[CandidateResult]) -> bool:
        """Whether one of `results` alone explains the gap (credit, and at the floor)."""
        return any(credited(c) and near_floor(c, near) for c in results)

    def is_linear(c: CandidateResult) -> bool:
        return structure_of(c.effects, c.options, furnace).linear
    clues.bent = bent = any(base.rmse_fit_c[z] > fit_limit[z] for z in zones)
    say("candidates", 0.1)
    trials = {n: EFFECTS[n].tried.trial(clues) for n in names}
    options = {n: t.options for n, t in trials.items()}
    starts = {n: t.start for n, t in trials.items()}
    bounds = {k: v for n in names for k, v in EFFECTS[n].tried.search_bounds(fit_data).items()}
    tasks = [Task((n,), {n: options.get(n, {})}, fit_data, hold, tail_of,
                  {**base.params, **starts[n]}, seed, bounds=bounds, baseline_sse=base.sse_fit,
                  baseline_end=base.ended, start_on=trials[n].start_on)
             for n in names]
    fitted = tried(run_all(tasks, lambda f: say("candidates", 0.1 + 0.5 * f),
                           counted(len(tasks), lambda w: say(w, 0.1)), limit))
    for c in fitted:
        score_against(c, base, floor)

    def off_floor(c: CandidateResult) -> bool:
        return any(c.rmse_fit_c[z] > fit_limit[z] for z in zones)

    def from_scratch(results: list[CandidateResult], off: list[int], linear: bool,
                     stage: str, at: float) -> None:
        """results[i] for i in `off` searched again from scratch, each kept where that
        search ends lower."""
        if off:
            say(stage, at)
        cold = run_all([Task(results[i].effects, results[i].options, fit_data, hold, tail_of,
                             None, seed + 1, bounds=bounds,
                             generations=None if linear else COLD_GENERATIONS)
                        for i in off], lambda f: say(stage, at + PASS / 3 * f),
                       counted(len(off), lambda w: say(f"{w}, from scratch", at)), limit)
        for i, c in zip(off, cold, strict=True):
            if c.cut:
                untried.append(f"{c.label} searched from scratch")
                continue
            score_against(c, base, floor)
            if np.isfinite(c.sse_fit) and c.sse_fit < results[i].sse_fit:
                c.note = "; ".join(x for x in (c.note, "searched from scratch") if x)
                results[i] = c

    # A candidate that stays off the floor of a bent baseline may sit in its side valley
    # (seen: strong zone burners, a = 1 and d = 11; strong radiation, a held at its bound):
    # it is searched from scratch too, a nonlinear one with a short evolutionary search
    # (each generation is a batch), but only while no candidate alone explains the gap: on
    # a bent baseline most candidates help a little, and searching them all again costs
    # much of the diagnosis (a nonlinear one more than the rest of it) for a verdict it
    # does not change.
    # Then the effects' further laws, on a bent baseline also from scratch, but only while
    # no candidate alone explains the gap, the laws' own warm fits included (a
    # preheating-zone wall whose warm law stays off the floor lets a drift be added in its
    # place; a wall or lag of one zone whose warm law reaches the floor leaves nothing for
    # the other zones' searches to find). Once a candidate alone explains the
    # gap, a nonlinear one that does not gets no further laws at all: each is a search of
    # the integrated model.
    # The linear candidates first, searches and laws, and the rule read again after them:
    # one that reaches the floor from scratch or in another law (a lag in the zone it is
    # in, of a furnace of many) spares the nonlinear searches.
    for at, linear in ((0.6, True), (0.6 + PASS, False)):
        if bent:
            stuck = not explains(fitted)
            from_scratch(fitted, [i for i, c in enumerate(fitted)
                                  if is_linear(c) == linear and stuck and off_floor(c)],
                         linear, "from scratch", at)
        solved = explains(fitted)
        laws = [Task((c.effects[0],), {c.effects[0]: opts}, fit_data, hold, tail_of, c.params,
                     seed, bounds=bounds)
                for c, opts in further_laws([c for c in fitted if is_linear(c) == linear],
                                            furnace)
                if not solved or explains([c]) or linear]
        begun = at + PASS / 3
        if laws:
            say("laws", begun)
        more = tried(run_all(laws, lambda f, begun=begun: say("laws", begun + PASS / 3 * f),
                             counted(len(laws), lambda w, begun=begun: say(w, begun)), limit))
        for c in more:
            score_against(c, base, floor)
        if bent and linear and not solved and not explains(more):
            from_scratch(more, [i for i, c in enumerate(more) if off_floor(c)], True,
                         "laws from scratch", at + 2 * PASS / 3)
        fitted += more
    singles = []
    for n in names:
        same = sorted((c for c in fitted if c.effects == (n,)), key=rank)
        if not same:  # left unfitted by the time limit
            continue
        if len(same) > 1:
            options[n] = same[0].options[n]  # combinations are simulated in one law
            mix = between_laws(same, fit_data, hold) if EFFECTS[n].tried.blends else None
            if mix is not None:
                score_against(mix, base, floor)
            if mix is not None and rank(mix) < rank(same[0]):
                same.insert(0, mix)
            else:
                same[0].note = "; ".join(x for x in (same[0].note, "law chosen among "
                                                     + laws_named(same, furnace)) if x)
        singles.append(same[0])
    # A single held from credit by its strength's linearised intervals alone is judged
    # again on their profiles (fitting.profile_strength). Only these: a profile is a refit
    # per trial value, and for any other candidate the judgement would change nothing.
    doubtful = [c for c in singles
                if not c.identifiable and credited(dataclasses.replace(c, identifiable=True))
                and strengths_inside(c.effects, c.options, c.params, furnace, bounds)]
    if doubtful:
        say("strengths", 0.75)
    judged = run_all([end_task(c, fit_data, hold, tail_of, seed, bounds) for c in doubtful],
                     lambda _f: None, limit=limit, work=profile_strength)
    for c, j in zip(doubtful, judged, strict=True):
        if j.cut:
            untried.append(f"the profiled strength of {c.label}")
        else:
            strength_rejudged(c, j)
    singles.sort(key=rank)
    combos, kept, steps = stepwise(singles, base, floor, gap_limit, fit_data, hold, tail_of,
                                   seed, options, bounds, starts, gap,
                                   lambda f: say("combinations", 0.75 + 0.2 * f),
                                   limit, untried, lambda w: say(w, 0.75))
    signals = unused_signals(fit_data + hold)
    if signals:
        say("signals", 0.95)
    followed = tried(signal_candidates(signals, base, fit_data, hold, tail_of, seed, floor,
                                       counted(len(signals), lambda w: say(w, 0.95)),
                                       limit)
                     if signals else [])
    candidates = sorted(singles + combos + followed, key=rank)
    told = told_names(kept) if kept is not None else []
    for _round in range(TOLD_ROUNDS if told else 0):
        # one profile per parameter, side by side: each is a search of its own
        parts = run_all([end_task(kept, fit_data, hold, tail_of, seed, bounds, (n,))
                         for n in told], lambda _f: None, limit=limit,
                        work=functools.partial(profile_told, kept=kept))
        lower = moved(kept, parts)
        if lower is not None:  # the kept fit lay in a side valley: it moves, and is told there
            score_against(lower, base, floor)
            if kept.identifiable and not lower.identifiable:  # judged as the kept one was
                judged = run_all([end_task(lower, fit_data, hold, tail_of, seed, bounds)],
                                 lambda _f: None, limit=limit, work=profile_strength)[0]
                if not judged.cut:
                    strength_rejudged(lower, judged)
            candidates = [lower if c is kept else c for c in candidates]
            kept = lower
            continue
        profiled, words = with_told(kept, told, parts)
        if words is not None:
            untried.append(words)
        candidates = [profiled if c is kept else c for c in candidates]
        kept = profiled
        break

    def remaining(c: CandidateResult) -> list[Located] | None:
        """Where c's held-out residual lies, as the baseline's is located; None without
        its predictions."""
        if len(c.holdout_pred) != len(hold):
            return None
        faults = sensor_faults(hold, c.holdout_pred, tc_noise[len(fit_data):])
        return locate(hold, [e.zone_temp - p for e, p in zip(hold, c.holdout_pred, strict=True)],
                      hold_floors, faults)

    verdict = judge(base, kept, candidates, floor, near, gap, where, uncovered(fit_data, hold),
                    furnace=furnace, steps=steps, locate_remaining=remaining)
    verdict = prefer_signal(verdict, followed, kept, base, floor, near, gap, where, furnace,
                            remaining)
    say("done", 1.0)
    return Diagnosis(fit_data, hold, how, base, floor, where, tests, candidates, verdict,
                     time.perf_counter() - t_start, gap, **noise, kept=kept,
                     time_limit_s=time_limit_s, untried=untried, cut=limit.cut)


def _onwards(progress: Callable[[str, float], None] | None) -> Callable[[str, float], None]:
    """`progress` told the share done as it never goes back: a stage's lines carry where
    the stage began, and a pool reports its share after the line of the fit it heard."""
    reached = [0.0]

    def say(stage: str, fraction: float) -> None:
        reached[0] = max(reached[0], fraction)
        if progress is not None:
            progress(stage, reached[0])
    return say


def fitted_words(c: CandidateResult) -> str:
    """A candidate's progress line: what was fitted and how long it took."""
    return f"{c.label} fitted in {c.elapsed_s:.0f} s"


def counted(total: int, say: Callable[[str], None]) -> Callable[[CandidateResult], None]:
    """Each result of a batch of `total` as a progress line, with how many are done and the
    time the others will take at the pace so far."""
    from ..progress import duration

    t0, done = time.monotonic(), [0]

    def heard(c: CandidateResult) -> None:
        done[0] += 1
        k = done[0]
        left = (time.monotonic() - t0) / k * (total - k)
        say(f"{fitted_words(c) if not c.cut else c.label + ' not tried (time limit)'} "
            f"({k} of {total}" + (f"; about {duration(left)} left for the others)"
                                  if k < total else ")"))
    return heard


def _pooled_tc(floors: list[RecordFloor]) -> dict[str, float]:
    """One thermocouple's noise sd per zone over the records, weighted by their readings."""
    out = {}
    for z in (floors[0].zones if floors else ()):
        pairs = [(f.zones[z].tc_sd_c, f.zones[z].samples) for f in floors
                 if f.zones[z].samples and np.isfinite(f.zones[z].tc_sd_c)]
        out[z] = (float(np.sqrt(np.average([s * s for s, _ in pairs],
                                           weights=[n for _, n in pairs])))
                  if pairs else float("nan"))
    return out


def stepwise(singles: list[CandidateResult], base: CandidateResult, floor: dict[str, float],
             gap_limit: dict[str, float], fit_data, hold, tail_of, seed: int, options: dict, bounds: dict, starts: dict,
             gap: tuple[str, ...],
             progress: Callable[[float], None], limit: TimeLimit | None = None,
             untried: list[str] | None = None, say: Callable[[str], None] | None = None
             ) -> tuple[list[CandidateResult], CandidateResult | None, list[CandidateResult]]:
    """Combinations tried, the set kept, and the kept set after each effect was added (the
    last is the set kept): the best single with credit, then one effect added at a time
    while the kept set leaves a clear gap and a further effect removes most of what is left
    (and is itself determined by the data). Combinations the time limit (`limit`) cut
    are added to `untried` and the search stops there. `say` hears a line per fit."""
    untried = [] if untried is None else untried
    if not gap or not singles or not credited(singles[0]):
        return [], None, []
    kept = singles[0]
    steps = [kept]
    tried: list[CandidateResult] = []

    def refit(kept: CandidateResult, combination: CandidateResult) -> CandidateResult:
        """The kept set fitted again from a combination's optimum."""
        structure = structure_of(kept.effects, options, fit_data[0].furnace)
        again = run_all([Task(kept.effects, {k: v for k, v in options.items()
                                              if k in kept.effects}, fit_data, hold, tail_of,
                              {k: v for k, v in combination.params.items()
                               if k in structure.names}, seed, bounds=bounds,
                              settled=kept.effects)], progress,
                        limit=limit)[0]
        if again.cut:
            untried.append(f"{kept.label} refitted from {combination.label}'s optimum")
            return again
        score_against(again, base, floor)
        again.note = "; ".join(x for x in (again.note, "refitted from a combination's "
                                           "optimum") if x)
        return again

    def no_gap(kept: CandidateResult) -> bool:
        return all(kept.rmse_holdout_c[z] <= kept.allowed(gap_limit)[z] for z in gap_limit)

    for _step in range(MAX_EFFECTS - 1):
        if no_gap(kept):
            break
        others = [c.effects[0] for c in singles if c.effects[0] not in kept.effects][:STEP_TRIES]
        tasks = []
        for n in others:
            effs = (*kept.effects, n)
            opts = {k: v for k, v in options.items() if k in effs}
            tasks.append(Task(effs, opts, fit_data, hold, tail_of,
                              {**kept.params, **starts.get(n, {})}, seed,
                              bounds=bounds, settled=kept.effects))
        if not tried:
            progress(0.0)  # the stage has begun: its first fit may take minutes
        step = run_all(tasks, progress,
                       counted(len(tasks), say) if say is not None else None, limit)
        untried.extend(c.label for c in step if c.cut)
        if any(c.cut for c in step):
            break  # a step judged on some of its combinations would not be the search's
        for c in step:
            score_against(c, base, floor)
        tried += step
        good = [c for c in step if closes(c, kept, floor)]
        if not good:
            # No further effect earns its place, but a combination's fit may have taken the
            # kept effects out of the side valley their own fit stopped in, the added effect
            # doing nothing (a one-zone lag on a network of many zones can stop where it
            # leaves the held-out error of every zone high). The kept set refitted
            # from the combination that fits best replaces it when it fits the fitted data
            # better: the same model at a lower criterion.
            lowest = min((c for c in step if np.isfinite(c.sse_fit)),
                         key=lambda c: c.sse_fit, default=None)
            again = None if lowest is None else refit(kept, lowest)
            if again is not None and again.sse_fit < (1 - SSE_GAIN) * kept.sse_fit \
                    and credited(again):
                tried.append(again)
                kept = steps[-1] = again
                continue
            break
        best = min(good, key=lambda c: c.evidence)
        # The gain may come from the kept effects reaching their own optimum from the
        # combination's start (a fit that stopped in a side valley), not from the added
        # effect: refit the kept set from there, and add the effect only if the refitted set
        # still leaves a clear gap and the effect closes most of it (what lies within the
        # noise is no gap for an effect to close).
        again = refit(kept, best)
        if np.isfinite(again.rmse_holdout_pooled()) and credited(again) and \
                again.rmse_holdout_pooled() < (1 - SSE_GAIN) * kept.rmse_holdout_pooled():
            tried.append(again)
            kept = steps[-1] = again
            if no_gap(kept) or not closes(best, kept, floor):
                break
        kept = best
        steps.append(best)
    # A combination earns credit against the baseline on the strength of the effects it
    # extends; say why one with credit is not the set kept.
    for c in tried:
        if len(c.effects) > 1 and c.effects != kept.effects and credited(c):
            c.note = "; ".join(x for x in (c.note, _not_kept(kept)) if x)
    return tried, kept, steps


def _not_kept(kept: CandidateResult) -> str:
    return (f"not kept: the stepwise search keeps {kept.label} (a further effect is added "
            "only where the kept ones leave a held-out error clear of the noise, and must "
            f"remove at least {MIN_GAP_CLOSED:.0f}% of it above the floor, with its strength "
            "determined and a lower BIC)")


def _applies(name: str, furnace, asked: bool) -> bool:
    """Whether an effect is a candidate on this furnace. One asked for by name that cannot
    apply is refused with the reason; of all the effects, those that cannot apply are left
    out (zone_burners on a furnace whose burners heat their own zones already)."""
    why = EFFECTS[name].refusal(furnace)
    if why and asked:
        raise FurnaceError(f"{name} does not apply to furnace '{furnace.name}': {why}")
    return not why
