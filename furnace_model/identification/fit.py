"""Offline identification of the model's parameters from heat-up records (paper section III).

The criterion is the paper's eq. 12: the sum over zones of the squared difference between
the measured zone temperature and the model's, over every sample with a reading (missing
readings are masked out, not filled). Unknowns are the structure's parameters plus each
experiment's initial zone temperatures: a cold start sits at ambient, a window cut from a
running furnace does not.

Two methods:
- `ga`: the paper's real-coded genetic algorithm, population and generations as its knobs.
- `fast` (default): a short evolutionary search to find the basin, then a Gauss-Newton polish
  (scipy's trust-region least squares) on the exact simulator, with the finite-difference
  Jacobian evaluated as one batched simulation of all perturbed parameter sets.
Both search positive parameters on the log scale. The Jacobian at the optimum gives the
intervals and the determined combinations (furnace_model.identification.uncertainty).

A sliding window's refit starts from the window before (`init`, `WarmStart`): the polish
alone, or, with `WarmStart.reach`, the `fast` method's two stages around that start: the
genetic search seeded with it in a box of the previous window's uncertainty, then the
polish from the start and from the search's best.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..blas import on_one_thread
from ..errors import FurnaceError
from ..experiment import Experiment, outage_words
from ..simulation.structure import ModelStructure
from .criteria import criteria
from .ga import genetic_search
from .model import Model, Refinement, score
from .noisefloor import GAP_RATIO, GAP_Z, limits, record_floor
from .plausible import Flag
from .problem import POLISH_MAX_ITER, Polished, Problem
from .profile import profile_interval
from .result import FitResult
from .uncertainty import WIDE, Z95, Uncertainty, from_jacobian, within

__all__ = ["METHODS", "FitResult", "Model", "Refinement", "WarmStart", "fit", "score"]
"""The fitting surface: the driver and the objects it hands back."""

METHODS = ("fast", "ga")
GA_DEFAULTS = {"fast": (32, 30), "ga": (20, 2000)}
"""(population, generations) per method: the paper ran population 20 for 25 000-100 000
cycles; 2000 generations already take seconds per run here."""
PROFILE_WIDE = 0.25
"""A linearised 95% half-width (search scale: about +-25% for a rate) beyond which the
interval is profiled instead: nearer, the criterion is close enough to quadratic for the
linearised interval to hold the truth as often as it says (docs/identification.md,
coverage)."""
PROFILE_RISE_SHARE = 0.01
"""A profile's refit has converged when a step lowers the criterion by less than this share
of the rise its interval ends at: the rise is wanted to a few percent, and near a minimum
the steps left would take less than the last one did."""
PROFILE_LOWER = 0.1
"""A profile's refit that ends this share of its rise below the fit's criterion has found a
lower valley, which the fit moves to (`PROFILE_MOVES` times at most): less is the scatter
of the refits' convergence."""
PROFILE_MOVES = 2
"""Moves at most: each is a polish and every profile again."""
PROFILE_OUTSIDE = 2.0
"""A profile's trial whose criterion stays above this many times the rise is outside its
interval whatever the refit's last steps would take (`Problem.polish`'s `above`): its
exact height only steers the next trial, by the square root of its rise."""
AT_BOUND_SHARE = 1e-3
"""A parameter this close to an edge of its box (a share of the box's width on the search
scale: 1.2% of a rate's value) is reported on it: the polish stops once a step gains less
than its tolerance, which can leave a parameter whose optimum lies beyond its bound a hair
inside it, a value no different from the bound to the data."""
Enough = Callable[[dict[str, dict[str, float]]], bool]
"""Whether a polished start's per-zone figures end a search of several starts (`fit`'s
`enough`)."""
SAME_END = 0.1
"""Two polished members of the genetic search whose costs differ by less than this share of
the residuals' variance end in one valley, the same fit as far as the data can tell: two
distinct members that lead there say the search does, and a third is polished only where
they disagree (docs/performance.md, "The polish's steps")."""
SCOUT_STEPS = 10
"""Polish steps each of several starts takes before the lowest goes on: enough to leave
a start's own misfit (its offsets and initial states, a zone's scale) behind, and for one in
a valley the polish cannot leave to show it."""
STALLED_STARTS = 4
"""Scouts polished on in a row without lowering the lowest end, after which the rest are
left where none is `enough`: an effect that cannot follow the records to their noise (a
fuel switch on records without one) would otherwise have every start polished to its end,
most to their iteration limit in valleys no lower. A valley the effect truly has holds
many of the starts, and the scouts rank one of them among the first."""
STALL_GAIN = 1e-3
"""What an end must take off the lowest so far to count as lower: less is the scatter of
ends that stopped at their iteration limit in one valley."""
WARM_DAMPING = 1e-7
"""The first Levenberg-Marquardt damping of a sliding window's refit (`WarmStart`): the
previous window's optimum is next to this one's, where undamped Gauss-Newton steps converge
in a few; a larger first damping spends its steps walking the last millionths of the
criterion down the d/e valley to the same optimum."""
SEEDED_SPREAD = 0.1
"""A search around a warm start (`WarmStart.reach`) draws its first population with this sd
as a share of its box, and the GA's mutations are scaled by the same box: at a reach of 10,
two of the previous window's standard deviations, narrowing over the run."""
SEEDED_SD_MISSING = 0.02
"""The standard deviation, as a share of the search box, of a parameter whose previous
interval is unusable (absent, not finite, or the value on a bound of the box): the spread
`init` gets offline."""
SEEDED_SD_FLOOR = 1e-4
"""No parameter's search around a warm start is narrower than this share of its box: a
parameter the data pin to a millionth still gets a neighbourhood to search."""



@on_one_thread
def fit(experiments: list[Experiment], structure: ModelStructure | None = None, *,
        method: str = "fast", runs: int = 1, population: int | None = None,
        generations: int | None = None, seed: int = 0,
        init: dict[str, float] | None = None,
        fixed: dict[str, float] | None = None,
        bounds: dict[str, tuple[float, float]] | None = None,
        progress: Callable[[float], None] | None = None,
        time_budget_s: float | None = None, zone_offsets: bool = False,
        profile: bool | Collection[str] = True, warm: WarmStart | None = None,
        further: Sequence[Mapping[str, float]] = (), enough: Enough | None = None,
        white_profile: Collection[str] = ()) -> FitResult:
    """Fit the structure's parameters to the experiments (jointly; own initial state each);
    without a structure, the baseline of the furnace the records are of.

    Run r uses seed + r; where no seed moves the search (`seeded`), one run is made whatever
    `runs` asks. With `init` the global search is skipped: a warm-started polish,
    which is what a sliding-window refit wants. The best run (lowest SSE) is the result; the
    arithmetic mean of the runs is kept as the paper's 'genetic mean parameter'.
    `zone_offsets` adds a constant offset per zone and experiment: thermocouple biases the
    model cannot otherwise absorb, except by bending its parameters (per experiment, since
    thermocouples are replaced and recalibrated between campaigns). `profile`: the
    intervals of parameters the data leave wide follow the criterion (furnace_model.identification.profile)
    instead of its quadratic approximation, where the fit reaches its records' noise floor
    (`_missed_floor`); a refit per trial value, so callers that only rank fits may leave it
    off. Names instead of True: those parameters are profiled whatever their linearised
    width (a hinge's onset, whose criterion is far from quadratic when it trades with the
    hinge's slope), and no others. A profile whose refits end lower than the fit has found
    a valley the search missed: the fit moves there (`FitResult.moves`).

    `warm` (with `init`): a sliding window's refit, which starts from the window before
    (see `WarmStart`); the same optimum and intervals, to the optimiser's and the profile's
    tolerances, for less work. With its `reach` (method fast), the genetic search of
    `population` and `generations` runs around `init` before the polish.

    `further` (with `init`, each giving every parameter): more starts. Each is polished a
    few steps (`SCOUT_STEPS`) and the lowest goes on alone, so that the starts an ambiguous
    onset needs cost about one polish, not one each. With `enough` (a test of the fit's
    per-zone figures, as `FitResult.per_zone`) the next lowest goes on too, and so on,
    until one passes it, or until several in a row (`STALLED_STARTS`) end no lower than
    the lowest so far: a scout's ten steps do not always rank the ends, and a caller that
    knows what a good end is (the records' noise) gets the starts polished on while they
    still find lower valleys.

    `white_profile`: parameters whose white-noise intervals (`ci95_white`) follow the
    criterion too, whatever the floor: a diagnosis asks of them whether the data determine
    an effect's strength, and where another direction is nearly flat (a room's air that
    settles within the hour its rows are apart: its rates known only as ratios) the
    linearisation spreads every parameter along it, a strength the criterion pins to a few
    percent included.
    """
    t_start = time.perf_counter()
    if method not in METHODS:
        raise FurnaceError(f"unknown method '{method}': use one of {', '.join(METHODS)}")
    if not experiments:
        raise FurnaceError("no data to fit")
    if runs < 1:
        raise FurnaceError("runs must be at least 1")
    structure = structure or ModelStructure(furnace=experiments[0].furnace)
    prob = Problem(experiments, structure, fixed or {}, bounds or {}, zone_offsets)
    if prob.n_obs <= prob.n:
        own = "initial state and zone offsets" if zone_offsets else "initial state"
        raise FurnaceError(f"too few readings to fit: {prob.n_obs} for {prob.n} unknowns "
                           f"({prob.k} parameters and each record's {own}); a fit needs more "
                           "readings than unknowns")
    pop_default, gen_default = GA_DEFAULTS[method]
    population = int(population or pop_default)
    generations = int(generations if generations is not None else gen_default)
    deadline = None if time_budget_s is None else t_start + float(time_budget_s)
    if further and not init:
        raise FurnaceError("further starts need `init`")
    starts: list[np.ndarray] = []
    spread, others = None, [dict(s) for s in further]
    if not init and method == "fast" and not structure.furnace.paper_structure:
        # a network of many zones: the search starts where the equations' least squares put
        # it, and a warm-started polish takes it from there (the parameters of an effect
        # that is not zone-affine from their defaults, searched over half their box). The
        # solves disagree where the records are poor in them (a furnace held at setpoint):
        # each is polished and the best end kept, since a start that misses the records less
        # may still lie in a valley the polish cannot leave.
        from .equationerror import equation_error_starts

        init, *others = [{n: v for n, v in st.items() if n not in (fixed or {})}
                         for st in equation_error_starts(structure, experiments)]
    if init:
        starts = [prob.to_z(np.array([{**structure.defaults(), **st}[n] for n in prob.names]))
                  for st in (init, *others)]
        # Given values are searched near where they are; the others (an effect's parameters
        # on top of a baseline fit) over half their box around their defaults.
        spread = np.array([0.02 if n in init else 0.5 for n in prob.names])

    box = None
    if warm is not None and warm.reach is not None:
        if not init or method != "fast":
            raise FurnaceError("a search around a warm start (WarmStart.reach) needs `init` "
                               "and method fast")
        box = _around(prob, starts[0], warm.intervals or {}, float(warm.reach))
    offsets = None
    if warm is not None and zone_offsets and warm.offsets is not None:
        if len(warm.offsets) != len(experiments):
            raise FurnaceError(f"warm start: offsets of {len(warm.offsets)} experiment(s) "
                               f"given for {len(experiments)}")
        offsets = [np.nan_to_num([float((o or {}).get(zone, 0.0))
                                  for zone in structure.furnace.zones])
                   for o in warm.offsets]
    x0 = None
    if offsets is not None and warm.x0 is not None:
        if len(warm.x0) != len(experiments):
            raise FurnaceError(f"warm start: initial states of {len(warm.x0)} experiment(s) "
                               f"given for {len(experiments)}")
        x0 = [np.asarray(x, dtype=float) for x in warm.x0]

    def begin(zp: np.ndarray) -> np.ndarray:
        return prob.start(zp, offsets, x0)
    if box is None and not seeded(method, starts, spread):
        runs = 1  # every run would repeat the first
    results = []
    for r in range(runs):
        t_run = time.perf_counter()
        rng = np.random.default_rng(seed + r)

        def report(frac, r=r):
            if progress is not None:
                progress(min((r + frac) / runs, 1.0))

        damping = 1e-3 if warm is None else WARM_DAMPING
        if box is not None and prob.k > 0:
            run = _seeded_run(prob, box, population, generations, rng, starts[0], deadline,
                              report, begin, damping)
        else:
            run = _one_run(prob, method, population, generations, rng,
                           starts, spread, deadline, report, begin, damping, enough)
        results.append((run, seed + r, time.perf_counter() - t_run))
    report_done = progress or (lambda _f: None)
    report_done(1.0)

    run_dicts = []
    for run, s, dt in results:
        run_dicts.append({"seed": s, "method": method, "population": population,
                          "generations": run.generations, "params": prob.param_dict(run.z),
                          "per_zone": prob.per_zone(run.z), "sse": prob.sse(run.z),
                          "elapsed_s": round(dt, 4), "stop_reason": run.stop_reason,
                          "iterations": run.iterations})
    best_run = results[int(np.argmin([d["sse"] for d in run_dicts]))][0]
    for move in range(PROFILE_MOVES + 1):
        z = best_run.z
        res = prob.fun(z)
        J = prob.jac(z)
        held = prob.held_by_bounds(Polished(z, res, J, best_run.stop_reason, 0,
                                            best_run.free_cost))
        unc = from_jacobian(prob.unflagged(J, held), res, prob.names, prob.log, z[:prob.k],
                            prob.series(), prob.blocked)
        flags = prob.flags(z, held)
        params = prob.param_dict(z)
        ci = dict(zip(prob.names, unc.ci95(prob.lo_val, prob.hi_val), strict=True))
        ci_white = dict(zip(prob.names, unc.ci95(prob.lo_val, prob.hi_val, white=True),
                            strict=True))
        for name, v in prob.fixed.items():
            ci[name] = ci_white[name] = (float(v), float(v))
        undetermined = unc.undetermined(prob.from_z(z[:prob.k]), prob.lo_val, prob.hi_val)
        profiled: dict[str, tuple[float, float]] = {}
        per_zone = prob.per_zone(z)
        missed = _missed_floor(per_zone, experiments) if profile else {}
        lower: list[tuple[float, np.ndarray]] = []
        if profile and not missed:
            if isinstance(profile, bool):
                chosen = [n for i, n in enumerate(prob.names)
                          if Z95 * np.sqrt(max(unc.cov[i, i], 0.0)) > PROFILE_WIDE]
            else:
                chosen = [n for n in prob.names if n in profile]
            profiled = _profiled(prob, z, float(res @ res), unc, chosen, deadline,
                                 None if warm is None else warm.intervals, lower=lower)
            ci.update(profiled)
        chosen = [n for n in prob.names if n in white_profile]
        if chosen:
            ci_white.update(_profiled(prob, z, float(res @ res), unc, chosen, deadline,
                                      white=True, lower=lower))
        if not lower or move == PROFILE_MOVES:
            break
        # A profile's refit ended lower than the fit: the fit stopped in a side valley (a
        # hinge's onset has many), and every interval drawn around it is off. The fit
        # moves to the lowest and is judged again there.
        p = prob.polish(min(lower, key=lambda c: c[0])[1], deadline)
        if not float(p.r @ p.r) < float(res @ res):
            break
        best_run = _Run(p.z, p.reason, p.iterations, best_run.generations,
                        best_run.truncated or p.reason == "time_budget", p.free_cost)
    named = unc.determined_combinations(undetermined)
    combos = [name for name, _ in named]
    combo_values = {}
    for name, coef in named:
        value, (lo, hi) = unc.combination_value(coef)
        combo_values[name] = {"value": value, "ci95": [lo, hi]}
    at_bound = prob.at_bound(z, AT_BOUND_SHARE)
    ranges = {n: (float(lo), float(hi))
              for n, lo, hi in zip(prob.names, prob.lo_val, prob.hi_val, strict=True)}
    edges = {n: ranges[n][0 if side == "lower" else 1] for n, side in at_bound.items()}
    warnings = _warnings(experiments, unc, undetermined, combos, best_run, time_budget_s,
                         at_bound, edges, missed, zone_offsets) + [f.words() for f in flags]
    static = all(e.burner_steps == 0 for e in experiments)
    corr = np.eye(len(structure.names))
    cov = np.zeros((len(structure.names),) * 2)
    idx = [structure.names.index(n) for n in prob.names]
    corr[np.ix_(idx, idx)] = unc.corr
    cov[np.ix_(idx, idx)] = unc.cov_own_units
    for name in at_bound:  # a linearisation on the edge of the box says nothing about it
        cov[structure.names.index(name), :] = cov[:, structure.names.index(name)] = np.nan
    mean = {n: float(np.mean([d["params"][n] for d in run_dicts])) for n in structure.names}
    # The GA alone keeps each record's initial state at its first readings: not estimated.
    n_estimated = prob.k if method == "ga" else prob.n
    return FitResult(
        structure=structure, params=params,
        x0=[prob.x0_of(z, j).copy() for j in range(len(prob.records))],
        ci95={n: ci[n] for n in structure.names}, corr=corr, undetermined=undetermined,
        determined_combinations=combos, warnings=warnings, per_zone=per_zone,
        sse=float(res @ res), n_obs=prob.n_obs, elapsed_s=time.perf_counter() - t_start,
        runs=run_dicts, method=method,
        status="insufficient_excitation" if static else "ok", genetic_mean=mean,
        sigma_c=unc.sigma, combinations=combo_values,
        zone_offsets_c=([dict(zip(structure.furnace.zones, map(float, prob.offsets_of(z, j)),
                                  strict=True))
                         for j in range(len(experiments))] if zone_offsets else None),
        zone_offsets_ci95_c=_offset_intervals(prob, z, unc, flags) if zone_offsets else None,
        bounds_c=_bounds_c(prob), flags=flags, moves=move,
        uncertainty=unc, ci95_white={n: ci_white[n] for n in structure.names},
        profiled=list(profiled),
        std={n: float(np.sqrt(max(cov[i, i], 0.0))) if np.isfinite(cov[i, i]) else float("nan")
             for i, n in enumerate(structure.names)},
        cov=cov, fixed=sorted(prob.fixed, key=structure.names.index),
        bounds=ranges,
        at_bound=at_bound, stop_reason=best_run.stop_reason, iterations=best_run.iterations,
        generations=best_run.generations,
        criteria=criteria(prob.residual_matrix(z), n_estimated), data=list(experiments))


def _offset_intervals(prob: Problem, z: np.ndarray, unc: Uncertainty,
                      flags: list[Flag]) -> list[dict[str, list[float] | None]]:
    """Per record, each zone offset's 95% interval (None where it sits on its bound: a
    bound is not an estimate)."""
    zones = prob.structure.furnace.zones
    held = {(f.record, f.zone) for f in flags if f.kind == "offset"}
    out = []
    for j, r in enumerate(prob.records):
        at = prob.block * j + prob.nz
        sd = unc.nuisance_sd[at:at + prob.nz] if unc.nuisance_sd.size else np.full(prob.nz, np.nan)
        off = prob.offsets_of(z, j)
        out.append({zone: None if (r.name, zone) in held or not np.isfinite(sd[w]) else
                    [float(off[w] - Z95 * sd[w]), float(off[w] + Z95 * sd[w])]
                    for w, zone in enumerate(zones)})
    return out


def _bounds_c(prob: Problem) -> list[dict[str, dict[str, list[float | None]]]]:
    """Per record, what its own unknowns may physically be: {"offset": {zone: [lo, hi]},
    "initial": {zone: [lo, hi]}} (None: unbounded on that side)."""
    zones = prob.structure.furnace.zones

    def edge(v: float) -> float | None:
        return float(v) if np.isfinite(v) else None

    return [{"offset": {zone: [-float(r.bias[w]), float(r.bias[w])]
                        for w, zone in enumerate(zones)},
             "initial": {zone: [edge(r.x0_lo[w]), edge(r.x0_hi[w])]
                         for w, zone in enumerate(zones)}}
            for r in prob.records]


@dataclass(frozen=True)
class WarmStart:
    """What a sliding window's refit takes from the window before it, besides its parameter
    values (`fit`'s init): windows that overlap nearly wholly have their optimum, and their
    intervals' ends, next to each other's."""

    offsets: Sequence[Mapping[str, float] | None] | None = None
    """Per experiment, {zone: offset in °C}: where the zone offsets start, and the initial
    states at the first readings less them (a thermocouple's bias is in its reading). From
    zero and the readings the polish took eight or nine steps instead of two or three."""
    intervals: Mapping[str, tuple[float, float]] | None = None
    """{name: (low, high)}, own units: where each profile's search starts
    (`furnace_model.identification.profile.profile_interval`'s `start`)."""
    reach: float | None = None
    """With `intervals` (the previous window's 95% intervals): the genetic search runs in
    the box of this many of their standard deviations around `init` (inside the search box),
    seeded with it, before the polish; None: the polish alone. What the data pinned down is
    searched near, what they left loose widely; see `_seeded_run`."""
    x0: Sequence[Sequence[float]] | None = None
    """Per experiment (with `offsets`), the initial zone temperatures where a fit of the same
    records ended: the polish then starts at that fit's whole optimum, which a fit of a
    model nested in this one (an effect at its null) cannot then end above."""


@dataclass
class _Run:
    """One run's end point, why its search stopped, and how far it went."""

    z: np.ndarray
    stop_reason: str
    iterations: int  # accepted polish steps of the result's polish
    generations: int  # GA generations run
    truncated: bool  # some stage (GA or polish) stopped on the time budget
    free_cost: float | None = None  # the polish's: see Polished


def _missed_floor(per_zone: Mapping[str, Mapping[str, float]],
                  experiments: list[Experiment]) -> dict[str, tuple[float, float]]:
    """{zone: (RMSE, limit)} where the fit (its `per_zone` metrics) misses the records'
    noise floor, as a refit's misfit and a diagnosis's gap are judged (noisefloor.limits).
    There no parameter set reproduces the records, so a profile's coverage of the truth does
    not apply, and each of its refits crawls along a criterion shaped by what the model
    leaves out; the linearised interval, with the residual's colour, is given instead."""
    limit = limits([record_floor(e) for e in experiments], GAP_RATIO, GAP_Z)
    return {zone: (float(per_zone[zone]["rmse_c"]), float(limit[zone])) for zone in limit
            if zone in per_zone and per_zone[zone]["rmse_c"] > limit[zone]}


def _profiled(prob: Problem, z: np.ndarray, sse: float, unc: Uncertainty,
              names: list[str], deadline: float | None,
              starts: Mapping[str, tuple[float, float]] | None = None, white: bool = False,
              lower: list[tuple[float, np.ndarray]] | None = None
              ) -> dict[str, tuple[float, float]]:
    """Profile-likelihood intervals of the named (wide) parameters, in their own units; the
    criterion's rise at the ends is the linearised interval's, with the residual's colour
    (`white`: the white-noise interval's, without it).
    `starts` (own units): where each search starts (a neighbouring window's ends).
    `lower` hears each refit that ended `PROFILE_LOWER` below `sse` (its cost and every
    unknown): the fit it profiles is not at its optimum.

    A parameter correlated with one profiled before it starts where that profile's refits
    put it at their ends, scaled by the correlation (`_guided`): the paper's d and e share
    one valley, and the second search then needs one or two refits a side, where one
    stepping out from a linearised half-width, which says nothing near a bound, needs five
    to eight."""
    out = {}
    white_cov = unc.cov_white if unc.cov_white is not None else unc.cov
    cov = white_cov if white else unc.cov
    done: list[tuple[int, tuple[float, float], dict[float, np.ndarray]]] = []
    for name in names:
        i = prob.names.index(name)
        if deadline is not None and time.perf_counter() > deadline:
            break
        colour = 1.0 if white or white_cov[i, i] <= 0 else unc.cov[i, i] / white_cov[i, i]
        rise = Z95 ** 2 * unc.sigma ** 2 * colour
        # Start each refit where the others lie for that value along the valley (d follows
        # e at fixed d/e), not where they were: the chord of the two refitted trials nearest
        # it, or at first the linearisation from the optimum; from there Gauss-Newton steps
        # (little damping) reach the minimum in one to three.
        along = np.delete(cov[:, i] / cov[i, i], i)
        refitted = {float(z[i]): np.delete(z, i)}

        def sse_at(z_i: float, i=i, along=along, refitted=refitted, rise=rise) -> float:
            start = _on_valley(refitted, z_i, along)
            p = prob.holding(i, z_i).polish(start, deadline, 30, PROFILE_RISE_SHARE * rise / sse,
                                            1e-7, free_first=False,
                                            above=sse + PROFILE_OUTSIDE * rise)
            cost = float(p.r @ p.r)
            if p.reason != "above":
                refitted[z_i] = p.z
            if lower is not None and cost < sse - PROFILE_LOWER * rise:
                lower.append((cost, np.insert(p.z, i, z_i)))
            return cost

        start = None
        if starts is not None and name in starts:  # on the search scale; NaN: no guide
            ends = np.asarray(starts[name], dtype=float)
            if prob.log[i]:
                ends = np.log(np.where(ends > 0, ends, np.nan))
            start = (float(ends[0]), float(ends[1]))
        else:
            start = _guided(i, z, cov, done)
        lo, hi = profile_interval(sse_at, float(z[i]), Z95 * float(np.sqrt(cov[i, i])),
                                  sse, rise, float(prob.lo[i]), float(prob.hi[i]), start)
        done.append((i, (lo, hi), refitted))
        if prob.log[i]:
            out[name] = within((float(np.exp(lo)), float(np.exp(hi))), float(np.exp(z[i])))
        else:
            out[name] = within((float(lo), float(hi)), float(z[i]))
    return out


PROFILE_GUIDE_CORR = 0.9
"""The least correlation (linearised) with a parameter profiled before at which its
profile's ends guide another's search: below it the refits' values say little of where
the other's criterion crosses."""


def _on_valley(refitted: Mapping[float, np.ndarray], z_i: float, along: np.ndarray
               ) -> np.ndarray:
    """The other unknowns at z_i of a profiled parameter: along the chord of the two refitted
    trials nearest it, or with one, by the linearisation `along` from it."""
    near, *others = sorted(refitted, key=lambda v: abs(v - z_i))
    start = refitted[near].copy()
    if others:
        return start + (refitted[near] - refitted[others[0]]) * (
            (z_i - near) / (near - others[0]))
    start[:along.size] += along * (z_i - near)
    return start


def _guided(j: int, z: np.ndarray, cov: np.ndarray,
            done: Sequence[tuple[int, tuple[float, float], Mapping[float, np.ndarray]]]
            ) -> tuple[float, float] | None:
    """Where parameter j's profile should start its searches (search scale), from the most
    correlated profile already done: j's value on that profile's valley at each of its ends,
    divided by the correlation (for a quadratic criterion exactly j's own ends). None where
    no profile done is correlated enough (PROFILE_GUIDE_CORR)."""
    best, guide = PROFILE_GUIDE_CORR, None
    for i, ends, refitted in done:
        if cov[i, i] <= 0 or cov[j, j] <= 0:
            continue
        rho = cov[i, j] / np.sqrt(cov[i, i] * cov[j, j])
        if abs(rho) >= best and len(refitted) > 1:
            best, guide = abs(rho), (i, ends, refitted, rho)
    if guide is None:
        return None
    i, ends, refitted, rho = guide
    k = j - (j > i)  # j's place among the unknowns other than i
    along = np.delete(cov[:, i] / cov[i, i], i)
    at = [float(z[j] + (_on_valley(refitted, end, along)[k] - z[j]) / rho) for end in ends]
    return (min(at), max(at))


def _around(prob: Problem, start: np.ndarray, intervals: Mapping[str, tuple[float, float]],
            reach: float) -> tuple[np.ndarray, np.ndarray]:
    """The box (search scale) of `reach` standard deviations around `start`, each from its
    95% interval (own units), inside the search box."""
    width = prob.hi - prob.lo
    sd = SEEDED_SD_MISSING * width
    on_bound = prob.at_bound(start)
    for i, name in enumerate(prob.names):
        ends = np.asarray(intervals.get(name, (np.nan, np.nan)), dtype=float)
        if prob.log[i]:
            ends = np.log(np.where(ends > 0, ends, np.nan))
        half = 0.5 * float(ends[1] - ends[0]) / Z95
        if np.isfinite(half) and half > 0 and name not in on_bound:
            sd[i] = half
    sd = np.maximum(sd, SEEDED_SD_FLOOR * width)
    z = np.clip(start, prob.lo, prob.hi)
    return np.maximum(prob.lo, z - reach * sd), np.minimum(prob.hi, z + reach * sd)


def _seeded_run(prob: Problem, box: tuple[np.ndarray, np.ndarray], population: int,
                generations: int, rng: np.random.Generator, start: np.ndarray,
                deadline: float | None, report: Callable[[float], None],
                begin: Callable[[np.ndarray], np.ndarray], damping: float) -> _Run:
    """A warm start's search: the GA in `box` (see `_around`) on the criterion the polish
    minimises (the records' own unknowns held where the start puts them), the start one of
    its first population; then the polish from the start and, where the search found
    better, from its best, the better kept. Elitism keeps the start until a member scores
    better, and the start's own polish is among those compared, so the result is never
    worse than the warm polish alone. A best that scores below the start by less than the
    residual variance is the same fit as far as the data can tell (in the flat d/e valley
    the search always finds such a point): it is not polished. The search gets half the
    time left at most, the polish the rest."""
    lo, hi = box
    start = np.clip(start, lo, hi)
    own = begin(start)[prob.k:]
    at_start = float(prob.sse_params(start[None], own)[0])
    variance = at_start / max(prob.n_obs - prob.n, 1)
    ga_deadline = None if deadline is None else \
        time.perf_counter() + 0.5 * (deadline - time.perf_counter())
    found = genetic_search(lambda zp: prob.sse_params(zp, own), lo, hi, population=population,
                           generations=generations, rng=rng, start=start,
                           spread=SEEDED_SPREAD, progress=lambda f: report(0.8 * f),
                           deadline=ga_deadline)
    ga_cut = found.generations < generations  # only the deadline ends it early
    picked = [start, found.best] if found.best_f < at_start - variance else [start]
    polished = prob.polish_many([begin(z) for z in picked], deadline, damping=damping)
    report(1.0)
    best = _lowest(polished)
    cut = ga_cut or any(p.reason == "time_budget" for p in polished)
    return _Run(best.z, best.reason, best.iterations, found.generations, cut, best.free_cost)


def seeded(method: str, starts: list[np.ndarray], spread: np.ndarray | None) -> bool:
    """Whether a run's seed moves its search: a genetic search draws from it, while a polish
    from values given for every parameter (a warm start; on a network of many zones, the
    equations' least squares a baseline from scratch starts from) does not, so runs beyond
    the first would repeat it."""
    return method != "fast" or not starts or spread is None or not np.all(spread < 0.1)


def _one_run(prob: Problem, method: str, population: int, generations: int,
             rng: np.random.Generator, starts: list[np.ndarray], spread: np.ndarray | None,
             deadline: float | None, report: Callable[[float], None],
             begin: Callable[[np.ndarray], np.ndarray], damping: float = 1e-3,
             enough: Enough | None = None) -> _Run:
    """One run from `starts` (none: the GA over the whole box; several given whole: each
    scouted, then polished on in the scouts' order until one is `enough` or they stall
    (`STALLED_STARTS`), the lowest kept;
    several not given whole: each polished, the first is the GA's centre)."""
    if prob.k == 0:
        p = prob.polish(prob.start(np.zeros(0)), deadline)
        return _Run(p.z, p.reason, p.iterations, 0, p.reason == "time_budget", p.free_cost)
    if method == "fast" and starts and np.all(spread < 0.1):
        # every value given: polish (several starts: a few steps each, then the best on)
        if len(starts) == 1:
            p = prob.polish(begin(starts[0]), deadline, damping=damping)
        else:
            scouts = sorted(prob.polish_many([begin(z) for z in starts], deadline,
                                             SCOUT_STEPS, damping=damping), key=_cost)
            ends: list[Polished] = []
            lowest, stalled = np.inf, 0
            for scout in scouts:
                ends.append(prob.polish(scout.z, deadline)
                            if scout.reason == "iteration_limit" else scout)
                if enough is None or enough(prob.per_zone(ends[-1].z)):
                    break
                cost = _cost(ends[-1])
                stalled = 0 if cost < lowest * (1.0 - STALL_GAIN) else stalled + 1
                lowest = min(lowest, cost)
                if stalled == STALLED_STARTS:
                    break
            p = _lowest(ends)
        report(1.0)
        return _Run(p.z, p.reason, p.iterations, 0, p.reason == "time_budget", p.free_cost)
    start = starts[0] if starts else None
    ga_deadline = deadline
    if deadline is not None and method == "fast":
        ga_deadline = time.perf_counter() + 0.5 * (deadline - time.perf_counter())
    share = 0.8 if method == "fast" else 1.0
    found = genetic_search(prob.sse_params, prob.lo, prob.hi, population=population,
                           generations=generations, rng=rng, start=start,
                           spread=spread if start is not None else 1.0,
                           progress=lambda f: report(share * f), deadline=ga_deadline)
    ga_cut = found.generations < generations  # only the deadline ends it early
    if method == "ga":
        return _Run(prob.start(found.best), "time_budget" if ga_cut else "ga_generations", 0,
                    found.generations, ga_cut)
    # Polish the best few distinct members: the GA's best may sit in a side valley. The
    # starts are always among them: the extended model may be the baseline with its effect off.
    # Once two members end in one valley, the rest are left: the search leads there.
    # A step costs a Jacobian per member, which no batch shares: where a start was given (an
    # effect on top of a fitted baseline, the members around it) or the model is
    # integrated (its Jacobian by differences, a simulation per parameter), each member is
    # scouted and only the lowest polished to the end. A search from scratch polishes its
    # members whole: spread over the box, their scouts would not rank their valleys.
    steps = POLISH_MAX_ITER if prob.structure.linear and not starts else SCOUT_STEPS
    picked: list[np.ndarray] = []
    first = [np.clip(z, prob.lo, prob.hi) for z in starts]
    for cand in [*first, *found.population]:
        if len(picked) == 3 + len(first):
            break
        if not any(np.max(np.abs(cand - p)) < 0.3 for p in picked):
            picked.append(cand)
    # the starts and the first two members are polished whatever their ends: together
    together = len(first) + 2 if steps == POLISH_MAX_ITER else len(picked)
    polished = prob.polish_many([begin(z) for z in picked[:together]], deadline, steps)
    for cand in picked[together:]:
        if _one_valley(prob, polished[len(first):]):
            break
        polished.append(prob.polish(begin(cand), deadline, steps))
    report(1.0)
    best = _lowest(polished)
    more: list[Polished] = []
    if best.reason == "iteration_limit" and steps < POLISH_MAX_ITER:
        lowest = best
        best = prob.polish(best.z, deadline)
        if best.reason == "iteration_limit" and prob.structure.linear:
            # a long valley the polish crawls along: the lowest scout's end need not be the
            # lowest end, so the others are polished on too, as a search polishes its members
            more = prob.polish_many([p.z for p in polished if p is not lowest
                                     and p.reason == "iteration_limit"], deadline)
            best = _lowest([best, *more])
    cut = ga_cut or any(p.reason == "time_budget" for p in [*polished, *more, best])
    return _Run(best.z, best.reason, best.iterations, found.generations, cut, best.free_cost)


def _one_valley(prob: Problem, ends: list[Polished]) -> bool:
    """Whether the last end's cost is another's to within a tenth of the residuals'
    variance (SAME_END): the same fit as far as the data can tell."""
    if len(ends) < 2:
        return False
    costs = [_cost(p) for p in ends]
    variance = min(costs) / max(prob.n_obs - prob.n, 1)
    return any(abs(costs[-1] - c) < SAME_END * variance for c in costs[:-1])


def _cost(p: Polished) -> float:
    return float(np.nan_to_num(float(p.r @ p.r), nan=np.inf))


def _lowest(polished: list[Polished]) -> Polished:
    return min(polished, key=_cost)


def _warnings(experiments, unc: Uncertainty, undetermined: list[str], combos: list[str],
              run: _Run, budget, at_bound: dict[str, str],
              edges: dict[str, float], missed: dict[str, tuple[float, float]],
              offsets: bool = False) -> list[str]:
    out = []
    for e in experiments:
        if e.burner_steps == 0:
            out.append(f"{e.name}: no burner change in the data: too little excitation to "
                       "identify the model; do not trust these values")
        out += outage_words(e)
    for name, side in at_bound.items():
        out.append(f"{name} ended on the {side} bound of its search range ({edges[name]:g}): "
                   "the best fit within the range lies on its edge, so the value is the "
                   "bound, not an estimate, and no sd or interval applies to it")
    if undetermined:
        pairs = [c for c in combos if c not in unc.names]
        out.append(f"the data do not determine {', '.join(undetermined)} (95% interval wider "
                   f"than +-{100 * WIDE:.0f}%)"
                   + (f"; they do determine {', '.join(pairs)}" if pairs else ""))
    if missed:
        out.append("intervals linearised, not profiled: the model misses the noise floor in "
                   + ", ".join(f"{zone} (RMSE {r:.2g} against {lim:.2g} °C)"
                               for zone, (r, lim) in missed.items())
                   # an offset that takes up what the model leaves out is no sensor's bias
                   + ("; there a zone offset may carry part of the model's error, not only a "
                      "thermocouple's bias: run diagnose" if offsets else ""))
    for a, b, r in unc.strong_correlations():
        out.append(f"{a} and {b} are strongly correlated (r = {r:+.3f}): the data fix a "
                   "combination of them better than either")
    if run.truncated:
        out.append(f"time budget of {budget:g} s ran out: the search stopped early")
    elif run.stop_reason == "iteration_limit":
        out.append(f"the least-squares polish did not converge in {POLISH_MAX_ITER} iterations")
    elif run.stop_reason == "not_finite":
        out.append("the model could not be simulated where the polish started: these values "
                   "are that start, not a fit")
    return out
