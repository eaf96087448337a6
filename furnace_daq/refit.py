"""Online identification as a pure pipeline: windows cut on the data clock, one fit per
window, the /model/parameters message and any /model/events (drift).

Why a chain. With `method: ga_polish` (the default) window k is searched around the result of
window k-1: the genetic search seeded with it, in a box of that window's uncertainty, then
the polish (`fit` with `WarmStart.reach`; the first window is `fit`'s offline fast search).
The seed is one of the search's first population and elitism keeps it, and its own polish is
compared with the search's, so a window never ends worse than the polish alone from the
previous model would (`method: polish`, which costs a little less). With `method: ga` every
window is the paper's genetic search from scratch with a fixed seed: it depends on its own
data alone, costs 10-30 times as much, and ends where the GA stalls rather than at the optimum
(docs/performance.md); the chain still carries the drift references. The live daemon and
`furnace-daq replay` each hold one `RefitChain` and push the same windows through it in the
same order: the same log gives the same timeline. No I/O here; the worker process
(refitworker) runs `run_fit`, the daemon and replay move messages.

Why the same log gives the same search. A window's result may depend on the data, the windows
before it and the settings, never on the host: replay runs on another machine, at another
load. So `ga_polish`'s random generator is seeded from the window's end on the data clock
(whole seconds: `window_seed`), and its number of generations is fixed by the settings
(`RefitConfig.ga_size`: `budget_s` and the window's samples at a nominal cost, capped),
not by how many the host manages in its time; the result records both (`search`). The time
budget stays a wall-clock guard: the search stops at half of it and the polish has the rest,
and a fit cut short by it is `failed` (`run_fit`), the model in force kept, as for every
method. A search that stopped at the budget and published what it had would give a faster
replay host a different model.

Windows. A refit is due at every multiple of `period_s` of the PLC clock (publish time,
aligned to the Unix epoch); its window is the `window_s` of data before that instant,
resampled to `step_s` exactly as `logs export` does (furnace_model.log.resample.Resampler).

Drift. Each parameter has a reference: its value and 95% interval in the first model fitted,
or at its last drift event. A window's value moves away from the reference when (1) it lies
outside the reference interval, (2) the distance on the log scale exceeds twice the two
intervals' half-widths combined in quadrature (overlapping noisy windows scatter within that:
WINDOW_INTERVAL_FACTOR), and (3) the
relative change is at least `drift_min_change` (3 %: smaller changes are not worth an alarm
even when the data resolve them). `drift_windows` successive fitted windows moving away in the
same direction raise one drift event, and the new value becomes the reference. Only a
parameter the data determine (95% interval within +-5%, see docs/identification.md) is
judged: at 1-minute sampling b, c, d and e are not, and their intervals, linearised around
a long curved valley, are not to be trusted for an alarm. A reference that was itself not
determined is replaced by the next value.

Recent drift. A window much longer than the period moves only as the share of the window
after a change grows (with 24 h every 15 min, f of a fuel switch needs hours to move beyond
its interval). So each fitted window also judges its newest `RECENT_PERIODS` periods alone:
f re-estimated on them with the window model's a..e held (and the temperatures at the span's
start; see `recent_f`), against f's reference: outside its interval, beyond the two
uncertainties combined and by at least twice `drift_min_change` (RECENT_MIN_CHANGE_FACTOR).
`drift_windows` such refits in a row moving the same way raise one event (`basis: recent`)
and move f's reference to the recent value. A span in which no burner fires is not judged (f
is seen only with heat input), nor is one longer than the window. Only the paper's structure
has this one heat per burner; another furnace's network is judged on its windows alone.

Any furnace. The windows are of the furnace the daemon's config describes, and the model is
its thermal network: /model/parameters carries the network's parameters (a..f for the
paper's furnace, `k_`/`loss_`/`gain_` names for another, furnace_model.simulation.network), and drift
is judged on each of them the same way.

After a drift event no window that still holds data from before the end of the event's
window is judged (nor counts), by either test: with windows much longer than the period, a change inside
the window gives a day of compromise fits (one parameter set for two furnaces) whose values
swing, and an alarm for each swing would bury the one that matters. The next judgement
compares a window wholly after the event with the references the event set.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import pandas as pd

from furnace_model.experiment import Experiment
from furnace_model.glitches import without_glitches
from furnace_model.identification.fit import WarmStart, fit
from furnace_model.identification.noisefloor import GAP_RATIO, GAP_Z, limits, record_floor
from furnace_model.identification.result import FitResult
from furnace_model.log.messages import (
    Ambient,
    FurnaceMessage,
    ModelEvent,
    ModelEventKind,
    ModelParameters,
    Thermocouples,
    as_message,
)
from furnace_model.log.read import iso_time
from furnace_model.log.resample import Binned, Resampler
from furnace_model.log.schema import param_names
from furnace_model.simulation.furnace import Furnace
from furnace_model.simulation.network import parameters
from furnace_model.simulation.structure import ModelStructure
from furnace_model.stuckreadings import without_stuck

from .daqconfig import RefitConfig

FITTING_SEED = 0
"""Seed of `polish`'s first (cold) fit and of every `ga` search: fixed, so that
their logs replay exactly."""
SEEDED_REACH = 10.0
"""`ga_polish` searches a box of this many of the previous window's standard deviations
around its model: the scatter from one window to the next is about one."""
WINDOW_INTERVAL_FACTOR = 2.0
"""The window test asks for this multiple of the two half-widths combined: the intervals come
from residuals that are not independent, and over a steady week with the default windows a
moved 5.5% and back against a combined 95% half-width of 4.4%."""
RECENT_PERIODS = 2
"""The recent span judged for drift besides the window: the newest refit periods."""
RECENT_MIN_CHANGE_FACTOR = 2.0
"""The recent test asks for this multiple of `drift_min_change`: half an hour of data gives
an f that scatters by 3-7% about the truth over two steady days (plant seeds 1-5), where a
fuel switch moves it by 20%."""


@dataclass
class Window:
    """One refit window: [start_ns, end_ns) on the data clock and the data it holds."""

    start_ns: int
    end_ns: int
    experiment: Experiment | None
    expected_bins: int
    complete_bins: int
    burner_steps: int
    set_aside: tuple[str, ...] = ()
    """Thermocouples left out of the zone means (`RefitChain.without_set_aside`)."""
    explained_until: int | None = None
    """The end of the last window a verdict that set one aside explained (ns): the model
    with the drift fitted the data until then."""
    outage: tuple[int, int] | None = None
    """(last reading before, first after) of the outage whose rows before were left out."""
    left_out: tuple[str, ...] = ()
    """What the readings left out of the window's experiment were: runs of one reading
    repeated far longer than its column's repeat (`furnace_model.stuckreadings`: a frozen
    transmitter) and lone glitched ones (`furnace_model.glitches`: a reading far from the
    two beside it, which agree)."""

    @property
    def gap_fraction(self) -> float:
        return 1.0 - self.complete_bins / self.expected_bins if self.expected_bins else 1.0


def cut_window(resampler: Resampler, start_ns: int, end_ns: int, step_ns: int,
               t_air_default: float, name: str = "window", outage_ns: int | None = None
               ) -> Window:
    """The window's resampled rows as an experiment of the resampler's furnace (None when no
    row has a burner state): the rows `logs export` writes for the same span, burner-change
    rows included. With `outage_ns`, only the rows after the window's last span that long
    without a reading: the burners' states in it were not read, and a fit across it would
    hold the last ones while the plant's control moved them."""
    rows = resampler.table(start_ns, end_ns)
    expected = int(round((end_ns - start_ns) / step_ns))
    if rows.t.size == 0:
        return Window(start_ns, end_ns, None, expected, 0, 0)
    complete = int((np.all(np.isfinite(resampler.furnace.zone_means(rows.tc)), axis=1)
                    & rows.reading).sum())
    outage = None
    read = rows.t[rows.reading]
    if outage_ns is not None and read.size > 1:
        k = np.flatnonzero(np.diff(read) > outage_ns)
        if k.size:
            outage = (int(read[k[-1]]), int(read[k[-1] + 1]))
            keep = rows.t >= outage[1]
            rows = Binned(*(f[keep] for f in rows[:-1]),
                          {n: v[keep] for n, v in rows.signals.items()})
    # As logs export -> load: a missing ambient holds the last reading, the default before any.
    air = pd.Series(rows.t_air).ffill().fillna(t_air_default).to_numpy()
    t0 = int(rows.t[0])
    exp, stuck = without_stuck(Experiment(
        name, (rows.t - t0) / 60e9, rows.tc, rows.burners, air,
        pd.Timestamp(t0, unit="ns", tz="UTC"), name, furnace=resampler.furnace,
        disturbances=rows.disturbances))
    exp, glitched = without_glitches(exp)
    return Window(start_ns, end_ns, exp, expected, complete, exp.burner_steps, outage=outage,
                  left_out=tuple(stuck + glitched))


def _after_outage(window: Window, verb: str) -> str:
    """Which of the window's rows were used (`verb`: what they were used for), and why."""
    lo, hi = window.outage  # type: ignore[misc]
    return (f"only the rows after the outage from {iso_time(lo)} to {iso_time(hi)} {verb} "
            f"(no reading for {(hi - lo) / 60e9:.0f} min: the burners' states in it are "
            "unknown)")


def window_seed(window: Window) -> int:
    """The seed of `ga_polish`'s search on this window: its end on the data clock in whole
    seconds, the same live and in replay, and a different stream for every window."""
    return window.end_ns // 1_000_000_000


@dataclass(frozen=True)
class FitJob:
    """What the worker process needs for one fit: picklable, no state of the chain."""

    experiment: Experiment
    init: dict[str, float] | None
    budget_s: float
    recent_from_min: float | None = None
    """Start of the recent span (minutes on the experiment's time) whose f is estimated."""
    method: str = "polish"
    population: int = 20
    generations: int = 2000
    """The genetic search's size (methods ga and ga_polish: `RefitConfig.ga_size`)."""
    warm: WarmStart | None = None
    """The previous window's offsets and intervals, with `init` its parameters; with
    `ga_polish` also the reach of the search around them."""
    seed: int = FITTING_SEED
    """The search's random seed: `window_seed` for ga_polish."""


def run_fit(job: FitJob) -> dict:
    """One window's fit as a plain dict (the worker sends it back through a pipe). A fit that
    runs out of its time budget has status `failed`: a truncated search depends on the
    host's speed, and a result that depends on the host is not one to keep.

    `ga_polish` and `polish` fit with zone offsets from `init` (`ga_polish` searching
    around it first, as `job.warm` says; both the fast search when there is none); `ga` is
    the paper's search on the paper's criterion, which has no offsets (the GA holds them at
    zero), so none are fitted or reported. The model is the experiment's furnace's network
    (the paper's eq. 11 for its furnace)."""
    t0 = time.perf_counter()
    furnace = job.experiment.furnace
    structure = ModelStructure(furnace=furnace)
    if job.method == "ga":
        res = fit([job.experiment], structure, method="ga", population=job.population,
                  generations=job.generations, seed=job.seed, time_budget_s=job.budget_s)
    else:
        around = job.warm is not None and job.warm.reach is not None
        res = fit([job.experiment], structure, init=job.init, seed=job.seed,
                  zone_offsets=True, time_budget_s=job.budget_s, warm=job.warm,
                  population=job.population if around else None,
                  generations=job.generations if around else None)
    over = any(w.startswith("time budget") for w in res.warnings)
    search = {"method": job.method, "warm_start": job.init is not None}
    if job.method == "ga":
        search.update(population=job.population, generations=int(res.runs[0]["generations"]))
    elif job.method == "ga_polish":
        search.update(population=int(res.runs[0]["population"]),
                      generations=int(res.runs[0]["generations"]), seed=job.seed)
    return {
        "status": "failed" if over else "ok",
        "detail": "; ".join(res.warnings),
        "search": search,
        "params": dict(res.params),
        "ci95": {k: [float(v[0]), float(v[1])] for k, v in res.ci95.items()},
        "rmse_c": {z: float(res.per_zone[z]["rmse_c"]) for z in furnace.zones},
        "combinations": res.combinations,
        "determined_combinations": list(res.determined_combinations),
        "undetermined": list(res.undetermined),
        "zone_offsets_c": (res.zone_offsets_c or [None])[0],
        "flags": [f.to_json() for f in res.flags],
        "sigma_c": float(res.sigma_c),
        "recent": None if over or job.recent_from_min is None or not furnace.paper_structure
        else recent_f(res, job.experiment, job.recent_from_min),
        **misfit_limits(job.experiment),
        "elapsed_s": time.perf_counter() - t0,
    }


def misfit_limits(exp: Experiment) -> dict[str, dict[str, float | None]]:
    """The window's noise floor per zone and the fit RMSE above which the model misses it:
    the floor widened by its uncertainty, as the diagnosis judges a gap (`GAP_RATIO`,
    `GAP_Z`), so that the daemon's trigger and the diagnosis it starts agree on what a gap
    is. None for a zone without a floor."""
    floor = record_floor(exp)
    limit = limits([floor], GAP_RATIO, GAP_Z)

    def finite(d: dict[str, float]) -> dict[str, float | None]:
        return {z: float(v) if math.isfinite(v) else None for z, v in d.items()}
    return {"noise_floor_c": finite(floor.floor_c), "misfit_limit_c": finite(limit)}


def recent_f(res: FitResult, exp: Experiment, from_min: float) -> dict | None:
    """f on the recent span alone, the window model's a..e held: what the newest data say
    about the heat per burner, long before a day-long window follows (a window's f moves with
    the share of the window after a change). The zone temperatures at the span's start are
    estimated with it, starting from the window model's: right after a change that model's
    state is off (it ran the old f), and held fixed it pushed a fuel switch's f to -35%
    instead of -20%. The window's thermocouple offsets are held (a short span cannot tell
    them from the start), and its noise level scales f's standard error (a short span's own
    residual says little about the thermocouples). None when no burner fires in the span: f
    is seen only with heat input."""
    span = exp.between(from_min, math.inf)
    if len(span) < 8 or not np.any(span.burners > 0):
        return None
    start = res.response(0).state_at(span.t_min[0])[0]
    recent = res.refine([span], free=("f",), x0=[start], offsets=[res.offsets(0)],
                        sigma=float(res.sigma_c))
    f, se = recent.params["f"], recent.std["f"]
    if not (math.isfinite(f) and math.isfinite(se)):
        return None
    return {"f": f, "se": se, "n_samples": int(np.isfinite(span.zone_temp).any(axis=1).sum())}


STATE_VERSION = 1
MODEL_KEYS = ("ci95", "rmse_c", "window_start", "window_end", "determined_combinations",
              "combinations")
"""What the message of a window that keeps the model copies from it."""


def _carries_model(model: ModelParameters, names: tuple[str, ...],
                   positive: frozenset[str]) -> bool:
    """Whether `model` is a fitted /model/parameters message: a window may keep it."""
    values = [model.params.get(p) for p in names]
    return (model.fitted
            and all(isinstance(v, int | float) and math.isfinite(v) and (v > 0 or p not in positive)
                    for p, v in zip(names, values, strict=True))
            and all(getattr(model, k) not in (None, "") for k in MODEL_KEYS))


@dataclass
class _Reference:
    value: float
    ci95: tuple[float, float]
    window_end: str
    determined: bool = True
    streak: int = 0
    direction: int = 0


@dataclass
class RefitChain:
    """The sequence of models: the current one, what each parameter is compared with for
    drift, and the messages every window produces. See the module docstring."""

    config: RefitConfig
    t_air_default: float = 30.0
    furnace: Furnace = field(kw_only=True)
    model: ModelParameters | None = None
    """The model in force: the last window fitted with status ok (its message)."""
    references: dict[str, _Reference] = field(default_factory=dict)
    quiet_until: str | None = None
    """Window end of the last drift event: later windows that overlap it are not judged."""
    recent_streak: int = 0
    recent_direction: int = 0
    set_aside: dict[str, tuple[int, int]] = field(default_factory=dict)
    """Thermocouples an online diagnosis found drifting, each with the data-clock instants
    (ns) from which windows leave it out and until which the verdict explained the data
    (`set_aside_from`)."""

    @property
    def names(self) -> tuple[str, ...]:
        """The parameters of the furnace's network, as /model/parameters carries them."""
        return param_names(self.furnace)

    @property
    def positive(self) -> frozenset[str]:
        """The parameters that are positive by nature (rates, searched on a log scale); a
        disturbance's gain takes either sign."""
        return frozenset(p.name for p in parameters(self.furnace) if p.log)

    def state(self) -> dict:
        """What a restarted daemon needs to go on where this chain stopped: the model in force
        and the drift references, as plain JSON."""
        model = None if self.model is None else self.model.to_json()
        return {"version": STATE_VERSION, "model": model,
                "references": {p: {**asdict(r), "ci95": list(r.ci95)}
                               for p, r in self.references.items()},
                "quiet_until": self.quiet_until, "recent_streak": self.recent_streak,
                "recent_direction": self.recent_direction,
                "set_aside": {s: {"from": f, "explained_until": u}
                              for s, (f, u) in self.set_aside.items()}}

    def restore(self, state: object) -> None:
        """Take over a saved `state()`. Raises ValueError, naming what is wrong, and leaves
        the chain as it was, for anything that is not one."""
        try:
            if not isinstance(state, dict) or state.get("version") != STATE_VERSION:
                raise ValueError(f"not a chain state of version {STATE_VERSION}")
            raw = state["model"]
            model = None if not isinstance(raw, dict) else \
                ModelParameters.from_json(raw)
            if raw is not None and (model is None
                                    or not _carries_model(model, self.names, self.positive)):
                raise ValueError("its model is not a fitted /model/parameters message")
            refs = {p: _Reference(float(r["value"]), (float(r["ci95"][0]), float(r["ci95"][1])),
                                  str(r["window_end"]), bool(r["determined"]), int(r["streak"]),
                                  int(r["direction"]))
                    for p, r in state["references"].items() if p in self.names}
            quiet = state["quiet_until"]
            streak, direction = int(state["recent_streak"]), int(state["recent_direction"])
            aside = {str(k): (int(v["from"]), int(v["explained_until"]))
                     for k, v in (state.get("set_aside") or {}).items()
                     if k in self.furnace.sensors and k not in self._trusted}
        except (KeyError, TypeError, IndexError, AttributeError) as exc:
            raise ValueError(f"malformed chain state ({type(exc).__name__}: {exc})") from None
        self.model, self.references = model, refs
        self.quiet_until = None if quiet is None else str(quiet)
        self.recent_streak, self.recent_direction = streak, direction
        self.set_aside = aside

    def set_aside_from(self, sensor: str, from_ns: int, explained_until_ns: int) -> bool:
        """Leave a drifting thermocouple out of the windows that end at or after `from_ns`:
        a reading that moves away from the furnace would otherwise be fitted as a furnace
        that changed, every window, and the model would never fit again. Its zone keeps its
        other thermocouples; a zone's last one is never set aside (the zone would go
        unmeasured). False when it is not set aside."""
        furnace = self.furnace
        if sensor not in furnace.sensors or sensor in self.set_aside or sensor in self._trusted:
            return False
        zone = furnace.sensor_zone[furnace.sensors.index(sensor)]
        kept = [s for s, z in zip(furnace.sensors, furnace.sensor_zone, strict=True)
                if z == zone and s != sensor and s not in self.set_aside]
        if not kept:
            return False
        self.set_aside[sensor] = (from_ns, explained_until_ns)
        return True

    @property
    def _trusted(self) -> tuple[str, ...]:
        """Thermocouples the config says never to set aside."""
        return () if self.config.diagnosis is None else self.config.diagnosis.trusted

    def without_set_aside(self, window: Window) -> Window:
        """The window with the thermocouples set aside by its end left out (NaN readings:
        the zone's mean is its other thermocouples')."""
        out = {s: u for s, (t, u) in self.set_aside.items() if window.end_ns >= t}
        if not out or window.experiment is None:
            return window
        exp = window.experiment
        tc = exp.tc.copy()
        tc[:, [self.furnace.sensors.index(s) for s in out]] = np.nan
        return replace(window, experiment=replace(exp, tc=tc), set_aside=tuple(out),
                       explained_until=max(out.values()))

    def check(self, window: Window) -> str | None:
        """Why the window cannot identify the model, or None when it can be fitted."""
        reason = self._unfit(window)
        if reason is None or window.outage is None:
            return reason
        return f"{reason}; {_after_outage(window, 'count')}"

    def _unfit(self, window: Window) -> str | None:
        cfg = self.config
        if window.experiment is None or len(window.experiment) < 10:
            n = 0 if window.experiment is None else len(window.experiment)
            return f"too short: {n} samples of {cfg.step_s:g} s with a burner state in the window"
        if window.gap_fraction > cfg.max_gap_fraction:
            return (f"{100 * window.gap_fraction:.1f}% of the window's {window.expected_bins} "
                    f"samples are missing or lack a zone (limit "
                    f"{100 * cfg.max_gap_fraction:g}%)")
        if window.burner_steps < cfg.min_burner_steps:
            return (f"{window.burner_steps} burner change(s) in the window (at least "
                    f"{cfg.min_burner_steps} needed)")
        return None

    def job(self, window: Window) -> FitJob:
        assert window.experiment is not None
        exp = window.experiment
        cfg = self.config
        init = None if self.model is None or cfg.method == "ga" \
            else {p: self.model.params[p] for p in self.names}
        recent_ns = window.end_ns - int(round(RECENT_PERIODS * cfg.period_s * 1e9))
        t0 = exp.start_time.value if exp.start_time is not None else window.start_ns
        recent = (recent_ns - t0) / 60e9 if recent_ns > max(window.start_ns, t0) else None
        warm = None
        if init is not None and self.model is not None:
            warm = WarmStart([self.model.zone_offsets_c],
                             {p: tuple(v) for p, v in (self.model.ci95 or {}).items()},
                             SEEDED_REACH if cfg.method == "ga_polish" else None)
        seed = window_seed(window) if cfg.method == "ga_polish" else FITTING_SEED
        return FitJob(exp, init, cfg.budget_s, recent, cfg.method, *cfg.ga_size(), warm, seed)

    def process(self, window: Window, fitter: Callable[[FitJob], dict] = run_fit
                ) -> tuple[ModelParameters, list[ModelEvent]]:
        """Check, fit in this process, accept: replay without a worker, and the tests."""
        reason = self.check(window)
        if reason is not None:
            return self.kept(window, "insufficient_excitation", reason), []
        try:
            outcome = fitter(self.job(window))
        except Exception as exc:  # noqa: BLE001 - any failure of a fit is a failed refit
            return self.kept(window, "failed", f"fit raised {type(exc).__name__}: {exc}"), []
        return self.accept(window, outcome)

    # -- messages --------------------------------------------------------------------------

    def _base(self, window: Window, status: str, detail: str) -> ModelParameters:
        exp = window.experiment
        if window.outage and status == "ok":
            detail = "; ".join(x for x in (_after_outage(window, "fitted"), detail) if x)
        if window.left_out and status == "ok":
            detail = "; ".join(x for x in (*window.left_out, detail) if x)
        return ModelParameters(status, detail, iso_time(window.start_ns), iso_time(window.end_ns),
                               0 if exp is None else len(exp), round(window.gap_fraction, 6),
                               window.burner_steps)

    def kept(self, window: Window, status: str, detail: str) -> ModelParameters:
        """The message of a window that did not change the model: the model in force (or
        nulls before the first), with the reason."""
        msg = self._base(window, status, detail)
        m = self.model
        msg.ci95 = {} if m is None else m.ci95
        msg.rmse_c = {} if m is None else m.rmse_c
        if m is not None:  # before the first model a..f are absent (the schema has no null)
            msg.params = {p: m.params[p] for p in self.names}
            msg.model_window_start = m.window_start
            msg.model_window_end = m.window_end
            msg.determined_combinations = m.determined_combinations
            msg.combinations = m.combinations
        return msg

    def accept(self, window: Window, outcome: dict
               ) -> tuple[ModelParameters, list[ModelEvent]]:
        """The worker's outcome for `window` -> (the /model/parameters message, events)."""
        if outcome.get("status") != "ok" or not _finite(outcome, self.names, self.positive):
            detail = outcome.get("detail") or "the fit returned non-finite values"
            msg = self.kept(window, "failed", detail)
            msg.elapsed_s, msg.search = outcome.get("elapsed_s"), outcome.get("search")
            return msg, []
        msg = self._base(window, "ok", outcome["detail"])
        msg.params = {p: outcome["params"][p] for p in self.names}
        msg.ci95, msg.rmse_c = outcome["ci95"], outcome["rmse_c"]
        msg.combinations = outcome["combinations"]
        msg.determined_combinations = outcome["determined_combinations"]
        msg.undetermined, msg.zone_offsets_c = outcome["undetermined"], outcome["zone_offsets_c"]
        msg.flags, msg.sigma_c = outcome["flags"], outcome["sigma_c"]
        msg.elapsed_s, msg.search = outcome["elapsed_s"], outcome["search"]
        msg.model_window_start = msg.window_start
        msg.model_window_end = msg.window_end
        recent = outcome.get("recent")
        msg.recent_f = recent
        msg.noise_floor_c = outcome.get("noise_floor_c")
        msg.misfit_limit_c = outcome.get("misfit_limit_c")
        events = self._drift(msg) or self._drift_recent(msg, recent)
        self.model = msg
        return msg, events

    def _drift(self, msg: ModelParameters) -> list[ModelEvent]:
        cfg = self.config
        events: list[ModelEvent] = []
        if self.quiet_until is not None and msg.window_start < self.quiet_until:
            return events  # still holds data from before the last event: see module doc
        for p in self.names:
            new, (lo, hi) = float(msg.params[p]), msg.ci95[p]
            determined = p not in msg.undetermined
            ref = self.references.get(p)
            if ref is None or not ref.determined:
                self.references[p] = _Reference(new, (lo, hi), msg.window_end, determined)
                continue
            direction = _moved(ref, new, (lo, hi), cfg.drift_min_change,
                               p in self.positive) if determined else 0
            if direction == 0 or direction != ref.direction:
                ref.streak = 0
            ref.direction = direction
            if direction == 0:
                continue
            ref.streak += 1
            if ref.streak < cfg.drift_windows:
                continue
            change = new / ref.value - 1.0 if ref.value else math.copysign(math.inf, new)
            events.append(ModelEvent(
                ModelEventKind.DRIFT, parameter=p,
                detail=(f"{p} {'rose' if new > ref.value else 'fell'} {100 * abs(change):.1f}% "
                           f"from {ref.value:.6g} [{ref.ci95[0]:.6g}, {ref.ci95[1]:.6g}] "
                           f"(window to {ref.window_end}) to {new:.6g} [{lo:.6g}, {hi:.6g}] "
                        f"over {ref.streak} windows"),
                old=ref.value, old_ci95=list(ref.ci95), old_window_end=ref.window_end,
                new=new, new_ci95=[lo, hi], relative_change=change,
                windows=ref.streak, window_start=msg.window_start,
                window_end=msg.window_end, parameters={p: new}))
            self.references[p] = _Reference(new, (lo, hi), msg.window_end, determined)
        if events:
            self._after_event(msg)
        return events

    def _after_event(self, msg: ModelParameters) -> None:
        self.quiet_until = msg.window_end
        self.recent_streak, self.recent_direction = 0, 0
        for ref in self.references.values():
            ref.streak, ref.direction = 0, 0

    def _drift_recent(self, msg: ModelParameters, recent: dict | None) -> list[ModelEvent]:
        """The recent span's f against the reference (see the module docstring). Spans
        without firing burners neither count nor break a run."""
        ref = self.references.get("f")
        if recent is None or ref is None or not ref.determined:
            return []
        if self.quiet_until is not None and msg.window_start < self.quiet_until:
            return []  # the window model is still a compromise across the change
        direction = _recent_moved(ref, recent,
                                  RECENT_MIN_CHANGE_FACTOR * self.config.drift_min_change)
        if direction == 0 or direction != self.recent_direction:
            self.recent_streak = 0
        self.recent_direction = direction
        if direction == 0:
            return []
        self.recent_streak += 1
        if self.recent_streak < self.config.drift_windows:
            return []
        new, se = float(recent["f"]), float(recent["se"])
        ci = (new - 1.96 * se, new + 1.96 * se)
        change = new / ref.value - 1.0
        start = self._recent_start(msg)
        event = ModelEvent(
            ModelEventKind.DRIFT, parameter="f", basis="recent",
            detail=(f"f {'rose' if change > 0 else 'fell'} {100 * abs(change):.1f}% from "
                       f"{ref.value:.6g} [{ref.ci95[0]:.6g}, {ref.ci95[1]:.6g}] (window to "
                       f"{ref.window_end}) to {new:.6g} [{ci[0]:.6g}, {ci[1]:.6g}] on the data "
                    f"from {start}, {self.recent_streak} refits in a row"),
            old=ref.value, old_ci95=list(ref.ci95), old_window_end=ref.window_end,
            new=new, new_ci95=list(ci), relative_change=change,
            windows=self.recent_streak, recent_start=start,
            window_start=msg.window_start, window_end=msg.window_end,
            parameters={"f": new})
        self.references["f"] = _Reference(new, ci, msg.window_end, True)
        self._after_event(msg)
        return [event]

    def _recent_start(self, msg: ModelParameters) -> str:
        end = pd.Timestamp(msg.window_end).value
        return iso_time(end - int(round(RECENT_PERIODS * self.config.period_s * 1e9)))


def _recent_moved(ref: _Reference, recent: dict, min_change: float) -> int:
    """+1 / -1 when the recent span's f lies outside the reference interval, differs from it by
    at least `min_change` and by more than twice the two 95% uncertainties combined (as for
    windows: the span's residuals are not independent either)."""
    new, se = float(recent["f"]), float(recent["se"])
    if not (new > 0 and math.isfinite(se)):
        return 0
    if ref.ci95[0] <= new <= ref.ci95[1] or abs(new / ref.value - 1.0) < min_change:
        return 0
    half_ref = 0.5 * (math.log(ref.ci95[1]) - math.log(ref.ci95[0]))
    distance = math.log(new) - math.log(ref.value)
    if abs(distance) <= WINDOW_INTERVAL_FACTOR * math.hypot(half_ref, 1.96 * se / new):
        return 0
    return 1 if distance > 0 else -1


def _moved(ref: _Reference, new: float, ci: tuple[float, float], min_change: float,
           positive: bool = True) -> int:
    """+1 / -1 when `new` has moved significantly up / down from the reference, else 0. A
    positive parameter is judged on the log scale it is searched on, a signed one (a
    disturbance's gain) on the linear scale."""
    if ref.ci95[0] <= new <= ref.ci95[1] or abs(new - ref.value) < min_change * abs(ref.value):
        return 0
    scale = math.log if positive else float
    half_ref = 0.5 * (scale(ref.ci95[1]) - scale(ref.ci95[0]))
    half_new = 0.5 * (scale(ci[1]) - scale(ci[0]))
    distance = scale(new) - scale(ref.value)
    if abs(distance) <= WINDOW_INTERVAL_FACTOR * math.hypot(half_ref, half_new):
        return 0
    return 1 if distance > 0 else -1


def _finite(outcome: dict, names: tuple[str, ...], positive: frozenset[str]) -> bool:
    """Every parameter and interval end a number, the positive ones above zero."""
    values = [(p, outcome["params"][p]) for p in names]
    values += [(p, v) for p in names for v in outcome["ci95"][p]]
    return all(isinstance(v, float | int) and math.isfinite(v) and (v > 0 or p not in positive)
               for p, v in values)


def moves_data_clock(msg: FurnaceMessage) -> bool:
    """Whether a message's publish time is the data clock: a reading's. A failed poll is
    stamped with the host's time (the PLC gave no clock), and burner states may come from
    CAN on the host's clock; a clock that jumped to either and back would cut, or pace,
    months of empty windows."""
    return isinstance(msg, Ambient) or isinstance(msg, Thermocouples) and msg.error is None


@dataclass
class WindowCutter:
    """Feeds messages into a resampler and says when a refit is due on the data clock.

    `feed` returns the windows that became due before the message (normally none, one at a
    period boundary). Messages must come in data-clock order, as the daemon logs them; a
    message that arrives late (publish time behind the last due instant) still enters the
    bins but no window already cut sees it."""

    config: RefitConfig
    t_air_default: float = 30.0
    furnace: Furnace = field(kw_only=True)
    resampler: Resampler = field(init=False)
    next_due_ns: int | None = None
    _last_ns: int | None = None

    def __post_init__(self) -> None:
        self.step_ns = int(round(self.config.step_s * 1e9))
        self.period_ns = int(round(self.config.period_s * 1e9))
        self.window_ns = int(round(self.config.window_s * 1e9))
        self.resampler = Resampler(self.step_ns, 0, self.furnace)

    def feed(self, topic: str, msg: FurnaceMessage | dict, pub_ns: int) -> list[Window]:
        """Only readings move the data clock (`moves_data_clock`); the other messages still
        enter the bins. A decoded dict is read as its topic's class."""
        msg = as_message(topic, msg, self.furnace)
        if not moves_data_clock(msg):
            self.resampler.add(topic, msg, pub_ns)
            return []
        out: list[Window] = []
        due = self.next_due_ns
        if self._last_ns is not None and pub_ns < self._last_ns - self.window_ns:
            # The data clock went back by more than a window (a PLC restarted with its clock
            # at zero and a fixed epoch): what was binned belongs to another time line.
            self.resampler = Resampler(self.step_ns, 0, self.furnace)
            self._last_ns = None
            due = None
        if due is None:
            self.next_due_ns = (pub_ns // self.period_ns + 1) * self.period_ns
        elif pub_ns >= due:
            while due <= pub_ns:
                if self._last_ns is not None and due - self.window_ns > self._last_ns:
                    # A silence longer than a window: the windows until now hold nothing.
                    due = (pub_ns // self.period_ns + 1) * self.period_ns
                    break
                out.append(cut_window(self.resampler, due - self.window_ns, due, self.step_ns,
                                      self.t_air_default, outage_ns=self.config.outage_ns))
                due += self.period_ns
            self.next_due_ns = due
            self.resampler.forget(due - self.window_ns)
        self.resampler.add(topic, msg, pub_ns)
        if self._last_ns is None or pub_ns > self._last_ns:
            self._last_ns = pub_ns
        return out
