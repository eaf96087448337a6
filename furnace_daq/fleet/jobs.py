"""The fleet's batch jobs: plan the tasks, skip those already stored, fan the rest out on the
Dask client, gather the rows, write the tables.

A task that fails (a log that is no log, a worker killed more often than the scheduler
retries, a fit that raises) becomes one row of the job's failures table with its furnace,
its task and the reason; every other task completes. Dask itself moves a task off a worker
that dies to another worker, so a killed worker costs time, not results.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from furnace_model.simulation.furnace import Furnace

from .description import Fleet, FleetFurnace
from .progress import Progress
from .report import write_report
from .store import Store, task_key
from .tasks import (
    Draw,
    Pair,
    Segment,
    diagnose_pair,
    files_between,
    refit_segment,
    scan_furnace,
    selfcheck_draw,
)

ROLLING = {"day": "D", "week": "W-SUN", "month": "M"}
"""--rolling PERIOD: each calendar period (UTC; weeks Monday to Sunday) against the next."""


@dataclass
class TaskSpec:
    job: str
    furnace: str
    label: str
    fn: Callable[[object], dict]
    arg: object
    key: str


@dataclass
class Failure:
    furnace: str
    job: str
    task: str
    reason: str


@dataclass
class JobResult:
    results: list[tuple[TaskSpec, dict]] = field(default_factory=list)
    failures: list[Failure] = field(default_factory=list)
    cached: int = 0
    computed: int = 0
    notes: list[str] = field(default_factory=list)

    def failures_frame(self) -> pd.DataFrame:
        return pd.DataFrame([f.__dict__ for f in self.failures],
                            columns=["furnace", "job", "task", "reason"])


def _reason(exc: BaseException) -> str:
    name = type(exc).__name__
    if name == "KilledWorker":
        return f"every worker that ran it died (Dask gives up after its allowed failures): {exc}"
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return f"{name}: {text}" if name not in ("DataError", "ConfigError", "PluginError") \
        else text


def run_tasks(client, specs: list[TaskSpec], store: Store | None, progress: Progress,
              result: JobResult) -> None:
    """Run what the store does not hold; stored results count as done at once."""
    from distributed import as_completed

    todo = []
    for spec in specs:
        hit = store.get(spec.job, spec.furnace, spec.key) if store is not None else None
        if hit is not None:
            result.results.append((spec, hit))
            result.cached += 1
        else:
            todo.append(spec)
    progress.cached = progress.done = result.cached
    progress.show()
    if not todo:
        return
    futures = {}
    for spec in todo:
        fut = client.submit(spec.fn, spec.arg, pure=False,
                            key=f"{spec.job}-{spec.furnace}-{spec.label}-{spec.key[:12]}")
        futures[fut] = spec
    for fut in as_completed(list(futures)):
        spec = futures.pop(fut)
        try:
            value = fut.result()
        except Exception as exc:  # noqa: BLE001 - any task failure is a reported row
            result.failures.append(Failure(spec.furnace, spec.job, spec.label, _reason(exc)))
            progress.failure(spec.furnace, spec.label, result.failures[-1].reason)
            progress.finished(ok=False)
            continue
        finally:
            fut.release()
        result.computed += 1
        if store is not None:
            store.put(spec.job, spec.furnace, spec.key, value)
        result.results.append((spec, value))
        progress.finished()


def scan(client, fleet: Fleet, job: str, result: JobResult) -> dict[str, dict]:
    """Every furnace's files and spans (tasks on the cluster: the files may be visible only
    there); a furnace whose scan fails is a failure of the job and is left out."""
    specs = [TaskSpec(job, f.name, "scan", _scan_task,
                      (f.name, tuple(map(str, f.logs)), f.description), "")
             for f in fleet.furnaces]
    progress = Progress(f"{job} (scan)", len(specs), quiet=True)  # failures still print
    got = JobResult()
    run_tasks(client, specs, None, progress, got)
    progress.close()
    result.failures += got.failures
    for spec, value in got.results:
        for reason in value.get("bad", []):
            result.failures.append(Failure(spec.furnace, job, "scan", reason))
            progress.failure(spec.furnace, "scan", reason + " (file left out)")
    return {spec.furnace: value for spec, value in got.results}


def _scan_task(arg: tuple) -> dict:
    return scan_furnace(*arg)


# -- refit ----------------------------------------------------------------------------------

def segment_bounds(start_ns: int, end_ns: int, period_s: float, segment_days: float | None
                   ) -> list[tuple[int | None, int | None]]:
    """(after, until] bounds of the windows' ends: one open segment when not cut; else cuts
    every `segment_days` from the first midnight after the start, on the refit period's grid
    (a cut at a refit instant: no window is in two segments or in none)."""
    if not segment_days:
        return [(None, None)]
    step = int(round(segment_days * 86400e9))
    period = int(round(period_s * 1e9))
    day = 86400 * 10**9
    cut = (start_ns // day + 1) * day + step - day
    cuts = []
    while cut < end_ns:
        aligned = cut // period * period
        if not cuts or aligned > cuts[-1]:
            cuts.append(aligned)
        cut += step
    edges: list[int | None] = [None, *cuts, None]
    return list(zip(edges[:-1], edges[1:], strict=True))


def plan_refit(fleet: Fleet, scans: dict[str, dict], segment_days: float | None,
               effects_from: tuple[str, ...] = ()) -> list[TaskSpec]:
    cfg = fleet.refit
    window_ns = int(round(cfg.window_s * 1e9))
    specs = []
    for f in fleet.furnaces:
        if f.name not in scans:
            continue
        files = scans[f.name]["files"]
        start = min(x["start_ns"] for x in files)
        end = max(x["end_ns"] for x in files)
        for i, (after, until) in enumerate(segment_bounds(start, end, cfg.period_s,
                                                          segment_days)):
            chosen = files_between(files, None if after is None else after - window_ns, until)
            seg = Segment(f.name, i, tuple(chosen), cfg, f.ambient_default_c, after, until,
                          effects_from, description=f.description)
            ident = [x["identity"] for x in files if x["path"] in chosen]
            key = task_key("refit", f.name, ident,
                           {"refit": cfg, "t_air": f.ambient_default_c, "after": after,
                            "until": until, "furnace": f.description.describe()})
            specs.append(TaskSpec("refit", f.name, f"segment {i}", refit_segment, seg, key))
    return specs


def run_refit(client, fleet: Fleet, out_dir: Path, *, segment_days: float | None = None,
              effects_from: tuple[str, ...] = (), quiet: bool = False) -> JobResult:
    """Refit every furnace; writes refit.parquet, drift_events.parquet, refit_failures.parquet
    and the fleet report under `out_dir`."""
    result = JobResult()
    scans = scan(client, fleet, "refit", result)
    specs = plan_refit(fleet, scans, segment_days, effects_from)
    progress = Progress("refit", len(specs), quiet=quiet)
    run_tasks(client, specs, Store(out_dir), progress, result)
    progress.close()
    rows = [r for _, v in result.results for r in v["rows"]]
    events = [e for _, v in result.results for e in v["events"]]
    write_table(refit_frame(rows), out_dir / "refit.parquet")
    write_table(events_frame(events), out_dir / "drift_events.parquet")
    write_table(result.failures_frame(), out_dir / "refit_failures.parquet")
    write_report(out_dir)
    return result


def refit_frame(rows: list[dict]) -> pd.DataFrame:
    frame = pd.DataFrame(rows)
    if frame.empty:
        return frame
    for col in ("window_start", "window_end"):
        frame[col] = pd.to_datetime(frame[col], utc=True)
    return frame.sort_values(["furnace", "window_end"], kind="stable").reset_index(drop=True)


def events_frame(events: list[dict]) -> pd.DataFrame:
    cols = ["furnace", "segment", "kind", "parameter", "basis", "window_start", "window_end",
            "old", "new", "relative_change", "detail"]
    frame = pd.DataFrame(events, columns=cols)
    for col in ("window_start", "window_end"):
        frame[col] = pd.to_datetime(frame[col], utc=True)
    return frame.sort_values(["furnace", "window_end"], kind="stable").reset_index(drop=True)


def write_table(frame: pd.DataFrame, path: Path) -> None:
    tmp = path.with_suffix(".parquet.tmp")
    frame.to_parquet(tmp, index=False)
    tmp.replace(path)


# -- diagnose -------------------------------------------------------------------------------

def campaign_pairs(f: FleetFurnace, scan_: dict, pairs: list[tuple[str, str]] | None,
                   rolling: str | None) -> tuple[list[tuple[tuple[str, int, int],
                                                            tuple[str, int, int]]], list[str]]:
    """The (fit, holdout) campaigns of one furnace, and notes on pairs it cannot have."""
    notes: list[str] = []
    if rolling is not None:
        start = min(x["start_ns"] for x in scan_["files"])
        end = max(x["end_ns"] for x in scan_["files"])
        periods = pd.period_range(pd.Timestamp(start, tz="UTC").tz_localize(None),
                                  pd.Timestamp(end, tz="UTC").tz_localize(None),
                                  freq=ROLLING[rolling])
        spans = [(_period_name(p, rolling), int(p.start_time.value),
                  int((p + 1).start_time.value)) for p in periods]
        return list(zip(spans[:-1], spans[1:], strict=True)), notes
    camps = {c.name: (c.name, c.start_ns, c.end_ns) for c in f.campaigns}
    if pairs:
        out = []
        for a, b in pairs:
            missing = [n for n in (a, b) if n not in camps]
            if missing:
                notes.append(f"{f.name}: no campaign {', '.join(missing)}; pair {a}:{b} "
                             "left out")
                continue
            out.append((camps[a], camps[b]))
        return out, notes
    ordered = sorted(camps.values(), key=lambda c: c[1])
    if len(ordered) < 2:
        notes.append(f"{f.name}: fewer than two campaigns; nothing to diagnose")
    return list(zip(ordered[:-1], ordered[1:], strict=False)), notes


def _period_name(p: pd.Period, rolling: str) -> str:
    if rolling == "month":
        return p.strftime("%Y-%m")
    if rolling == "week":
        return p.start_time.strftime("%G-W%V")
    return p.strftime("%Y-%m-%d")


def plan_diagnose(fleet: Fleet, scans: dict[str, dict], pairs: list[tuple[str, str]] | None,
                  rolling: str | None, effects_from: tuple[str, ...] = ()
                  ) -> tuple[list[TaskSpec], list[str]]:
    s = fleet.diagnose
    specs, notes = [], []
    for f in fleet.furnaces:
        if f.name not in scans:
            continue
        files = scans[f.name]["files"]
        chosen, why = campaign_pairs(f, scans[f.name], pairs, rolling)
        notes += why
        for fit, hold in chosen:
            fit_files = tuple(files_between(files, fit[1], fit[2]))
            hold_files = tuple(files_between(files, hold[1], hold[2]))
            pair = Pair(f.name, fit, hold, fit_files, hold_files, f.ambient_default_c,
                        s.effects, s.period_s, s.seed, effects_from, description=f.description)
            ident = [x["identity"] for x in files if x["path"] in set(fit_files + hold_files)]
            key = task_key("diagnose", f.name, ident,
                           {"fit": fit, "holdout": hold, "settings": s,
                            "t_air": f.ambient_default_c, "furnace": f.description.describe(),
                            "effects_from": [_file_id(p) for p in effects_from]})
            specs.append(TaskSpec("diagnose", f.name, f"{fit[0]}:{hold[0]}", diagnose_pair,
                                  pair, key))
    return specs, notes


def _file_id(path: str) -> list:
    p = Path(path)
    try:
        st = p.stat()
    except OSError:
        return [str(p), None, None]
    return [str(p.resolve()), st.st_size, st.st_mtime_ns]


VERDICT_COLUMNS = ["furnace", "fit_campaign", "holdout_campaign", "status", "effects",
                   "shrink_pct"]


def run_diagnose(client, fleet: Fleet, out_dir: Path, *,
                 pairs: list[tuple[str, str]] | None = None, rolling: str | None = None,
                 effects_from: tuple[str, ...] = (), quiet: bool = False) -> JobResult:
    """Diagnose every furnace's campaign pairs; writes verdicts.parquet and
    diagnose_failures.parquet, each diagnosis's JSON under diagnoses/, and the report."""
    result = JobResult()
    scans = scan(client, fleet, "diagnose", result)
    specs, result.notes = plan_diagnose(fleet, scans, pairs, rolling, effects_from)
    progress = Progress("diagnose", len(specs), quiet=quiet)
    run_tasks(client, specs, Store(out_dir), progress, result)
    progress.close()
    rows = [r for _, v in result.results for r in v["rows"]]
    frame = pd.DataFrame(rows)
    if frame.empty:
        frame = pd.DataFrame(columns=VERDICT_COLUMNS)
    frame = frame.sort_values(["furnace", "fit_campaign", "holdout_campaign"], kind="stable")
    write_table(frame.reset_index(drop=True), out_dir / "verdicts.parquet")
    write_table(result.failures_frame(), out_dir / "diagnose_failures.parquet")
    import json

    folder = out_dir / "diagnoses"
    folder.mkdir(exist_ok=True)
    for spec, v in result.results:
        name = f"{spec.furnace}__{spec.label.replace(':', '__')}.json"
        (folder / name).write_text(json.dumps(v["diagnosis"], indent=1, default=_nan_none)
                                   + "\n")
    write_report(out_dir)
    return result


def _nan_none(x):
    return None if isinstance(x, float) and math.isnan(x) else str(x)


# -- selfcheck ------------------------------------------------------------------------------

def run_selfcheck(client, labels: list[str], draws: int, out_dir: Path, *, seed: int = 0,
                  first: int = 0, form: str = "candidate",
                  candidates: tuple[str, ...] | None = None, noise: str = "white",
                  effects_from: tuple[str, ...] = (), quiet: bool = False,
                  furnace: Furnace) -> tuple[list, JobResult]:
    """Every (label, draw) of the selfcheck as a task; the Outcomes in the order
    `furnace-model selfcheck` reports them."""
    from furnace_model.diagnosis.selfcheck import Outcome

    specs = []
    for label in labels:
        for k in range(first, first + draws):
            d = Draw(label, k, seed, form, candidates, noise, effects_from, furnace=furnace)
            key = task_key("selfcheck", label, [_file_id(p) for p in effects_from], d)
            specs.append(TaskSpec("selfcheck", label, f"draw {k}", selfcheck_draw, d, key))
    result = JobResult()
    progress = Progress("selfcheck", len(specs), quiet=quiet)
    run_tasks(client, specs, Store(out_dir), progress, result)
    progress.close()
    order = {(s.furnace, s.label): i for i, s in enumerate(specs)}
    got = sorted(result.results, key=lambda sv: order[(sv[0].furnace, sv[0].label)])
    outcomes = []
    for _, v in got:
        doc = dict(v["rows"][0])
        for k in ("shrink_pct", "gap_closed_pct", "elapsed_s"):
            if doc.get(k) is None:
                doc[k] = math.nan
        outcomes.append(Outcome(**doc))
    return outcomes, result
