"""The fleet jobs on 1 and on 2 worker processes, side by side, what cutting a history into
segments does to its refit timeline, and a projection to a large fleet from the measured
costs.

A fleet of simulated furnaces (config/scenarios/fuel_switch.yaml with the switch at day 2,
06:00, and week_steps.yaml; 1-min samples, written as the daemon logs them): `fleet refit`
uncut on a LocalCluster of 1 and of 2 workers, then cut into day-long segments on 2; `fleet
diagnose` of day 1 against day 2 per furnace with every candidate on 1 and on 2 workers; the
runs one after the other, so that neighbouring runs see about the same load (--repeat
alternates the whole sequence). Wall time per run, and the CPU time the tasks spent
(process time in the workers), which the load of other jobs does not inflate: the cost per
refit window and per diagnosis that docs/performance.md projects from.

    .venv/bin/python bench/bench_fleet.py [--days D] [--furnaces N] [--repeat R] [--quick]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import pandas as pd
import yaml

from furnace_daq.fleet.description import load_fleet
from furnace_daq.fleet.engine import open_client
from furnace_daq.fleet.jobs.diagnose import run_diagnose
from furnace_daq.fleet.jobs.refit import run_refit
from furnace_daq.mcaplog import LogWriter
from furnace_daq.plantlog import write_run
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
REFIT = {"period_s": 7200, "window_s": 86400, "step_s": 60}
"""24-h windows as shipped, refitted every 2 h (the shipped 15 min multiplies the windows
and the cost by 8, not what a cut does to them)."""


def make_fleet(root: Path, days: float, furnaces: int) -> Path:
    kinds = ["fuel_switch", "week_steps"]
    entries = []
    for i in range(furnaces):
        kind = kinds[i % 2]
        name = f"f{i + 1}-{kind}"
        doc = yaml.safe_load((ROOT / "config" / "scenarios" / f"{kind}.yaml").read_text())
        doc["duration_min"] = days * 1440 - 1
        if "fuel_change" in doc["effects"]:
            doc["effects"]["fuel_change"]["t_fuel"] = 1800  # day 2, 06:00
        doc["burners"]["steps"] = [s for s in doc["burners"]["steps"]
                                   if s["at_min"] <= doc["duration_min"]]
        path = root / f"{name}.yaml"
        path.write_text(yaml.safe_dump(doc))
        s = load_scenario(path)
        if not (root / name).exists():
            run = Plant.from_scenario(s, seed=i + 1).run_scenario(s)
            with LogWriter(root / name, rotate_s=86400.0, flush_interval_s=3600.0) as log:
                write_run(run, log, s.start_time)
        # campaigns: day 1 fitted, day 2 held out
        start = s.start_time
        camp = [{"name": "first", "from": start.isoformat(),
                 "to": (start + pd.Timedelta(days=1)).isoformat()},
                {"name": "second", "from": (start + pd.Timedelta(days=1)).isoformat(),
                 "to": (start + pd.Timedelta(days=2)).isoformat()}]
        entries.append({"name": name, "logs": [name], "campaigns": camp})
    fleet = root / "fleet.yaml"
    fleet.write_text(yaml.safe_dump({"furnaces": entries, "refit": REFIT}, sort_keys=False))
    return fleet


def timed(job, workers: int, fleet, out: Path, **kw) -> tuple[float, object]:
    out.mkdir(parents=True, exist_ok=True)
    with open_client(workers=workers) as client:
        t0 = time.perf_counter()
        result = job(client, fleet, out, quiet=True, **kw)
        return time.perf_counter() - t0, result


def cut_effect(cut: pd.DataFrame, uncut: pd.DataFrame, period_s: float) -> list[str]:
    """Per window after each cut: the largest relative difference of a and f (the
    parameters the data determine) between the cut and the uncut run."""
    key = ["furnace", "window_end"]
    m = cut.merge(uncut, on=key, suffixes=("_cut", ""))
    assert len(m) == len(uncut) == len(cut)
    starts = cut.groupby(["furnace", "segment"])["window_end"].min().reset_index()
    starts = starts[starts["segment"] > 0]
    lines = ["| windows after the cut | windows | max abs diff a (%) | max abs diff f (%) | "
             "median abs diff f (%) |", "|---|---|---|---|---|"]
    m = m.merge(starts.rename(columns={"window_end": "first_end", "segment": "segment_cut"}),
                on=["furnace", "segment_cut"], how="left")
    m = m[m["fitted"] & m["fitted_cut"] & m["first_end"].notna()]
    m["k"] = ((m["window_end"] - m["first_end"]).dt.total_seconds() / period_s).round() + 1
    for lo, hi in ((1, 1), (2, 2), (3, 6), (7, 12), (13, 24)):
        g = m[(m["k"] >= lo) & (m["k"] <= hi)]
        if g.empty:
            continue
        da = (g["a_cut"] / g["a"] - 1).abs() * 100
        df = (g["f_cut"] / g["f"] - 1).abs() * 100
        lines.append(f"| {lo if lo == hi else f'{lo}-{hi}'} | {len(g)} | {da.max():.3f} | "
                     f"{df.max():.3f} | {df.median():.4f} |")
    return lines


def shipped_cost(root: Path, days: float = 2.0) -> str:
    """CPU per fitted window at the shipped refit settings (24-h windows every 15 min), one
    furnace (week_steps.yaml cut to `days`), the segment task run in this process."""
    from furnace_daq.daqconfig import RefitConfig
    from furnace_daq.fleet.tasks import Segment, list_files, refit_segment

    doc = yaml.safe_load((ROOT / "config" / "scenarios" / "week_steps.yaml").read_text())
    doc["duration_min"] = days * 1440 - 1
    doc["burners"]["steps"] = [s for s in doc["burners"]["steps"]
                               if s["at_min"] <= doc["duration_min"]]
    (root / "shipped.yaml").write_text(yaml.safe_dump(doc))
    s = load_scenario(root / "shipped.yaml")
    logs = root / "shipped"
    if not logs.exists():
        run = Plant.from_scenario(s, seed=5).run_scenario(s)
        with LogWriter(logs, rotate_s=86400.0, flush_interval_s=3600.0) as log:
            write_run(run, log, s.start_time)
    files = tuple(map(str, list_files([logs])))
    t0 = time.perf_counter()
    r = refit_segment(Segment("shipped", 0, files, RefitConfig(), 30.0, None, None,
                                      description=PAPER))
    fitted = [x for x in r["rows"] if x["fitted"]]
    return (f"shipped settings, {days:g} days: {len(r['rows'])} windows, {len(fitted)} fitted, "
            f"{r['cpu_s']:.1f} s CPU ({time.perf_counter() - t0:.1f} s wall): "
            f"{r['cpu_s'] / len(fitted):.3f} s CPU per fitted window")


def task_cpus(result) -> list[float]:
    """Process time each of the job's tasks spent: a refit segment's result carries it, a
    diagnosis carries it in its row."""
    return [v.get("cpu_s", 0.0) + sum(r.get("cpu_s", 0.0) for r in v["rows"]
                                      if "cpu_s" in r and "status" in r and "furnace" in r
                                      and "fit_campaign" in r)
            for _, v in result.results]


def cpu(result) -> float:
    return sum(task_cpus(result))


def best_ratio(tasks: list[float], workers: int = 2) -> float:
    """The wall time on `workers` over that on one, at best, for tasks of these costs: the
    largest task, or the work shared out evenly, whichever is longer (a lower bound that no
    scheduler beats, whatever the engine)."""
    total = sum(tasks)
    return max(max(tasks), total / workers) / total if total else 1.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--days", type=float, default=2.0)
    ap.add_argument("--furnaces", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "bench_fleet")
    ap.add_argument("--quick", action="store_true", help="no diagnosis")
    args = ap.parse_args()
    days = args.days
    root = args.cache / f"{days:g}d-{args.furnaces}"
    root.mkdir(parents=True, exist_ok=True)
    fleet = load_fleet(make_fleet(root, days, args.furnaces))
    walls: dict[str, list[float]] = {}
    cpus: dict[str, list[float]] = {}
    tasks: dict[str, list[float]] = {}
    tables: dict[str, pd.DataFrame] = {}
    diag_rows = None
    runs = [("refit uncut", 1, run_refit, {}), ("refit uncut", 2, run_refit, {}),
            ("refit cut 1 d", 2, run_refit, {"segment_days": 1.0})]
    if not args.quick:
        runs += [("diagnose", 1, run_diagnose, {}), ("diagnose", 2, run_diagnose, {})]
    for r in range(args.repeat):
        for name, workers, job, kw in runs:
            out = root / f"out-{r}-{workers}-{name.replace(' ', '')}"
            for old in out.glob("store/**/*.json"):
                old.unlink()
            wall, result = timed(job, workers, fleet, out, **kw)
            assert not result.failures, result.failures
            walls.setdefault(f"{name}, {workers} worker(s)", []).append(wall)
            cpus.setdefault(f"{name}, {workers} worker(s)", []).append(cpu(result))
            tasks[name] = task_cpus(result)
            if job is run_refit:
                tables[name] = pd.read_parquet(out / "refit.parquet")
            else:
                diag_rows = pd.read_parquet(out / "verdicts.parquet")
            print(f"{name}, {workers} worker(s): {wall:.1f} s wall, {cpu(result):.1f} s CPU "
                  "in the tasks", flush=True)
    uncut = tables["refit uncut"]
    fitted = int(uncut["fitted"].sum())
    cpu_window = statistics.median(cpus["refit uncut, 2 worker(s)"]) / fitted
    print(f"\nfleet: {args.furnaces} furnaces x {days:g} days at 1-min samples, "
          f"{len(uncut)} refit windows ({fitted} fitted; 24 h every "
          f"{REFIT['period_s'] / 3600:g} h); cut into day-long segments: "
          f"{tables['refit cut 1 d']['segment'].nunique()} per furnace\n")
    print("| job | workers | median wall time (s) | CPU in the tasks (s) | runs |")
    print("|---|---|---|---|---|")
    for k, v in walls.items():
        name, workers = k.rsplit(", ", 1)
        print(f"| {name} | {workers.split()[0]} | {statistics.median(v):.1f} | "
              f"{statistics.median(cpus[k]):.1f} | {len(v)} |")
    for job in ("refit uncut", "diagnose"):
        one, two = walls.get(f"{job}, 1 worker(s)"), walls.get(f"{job}, 2 worker(s)")
        if one and two:
            print(f"\n{job}: wall time on 2 workers / on 1 worker = "
                  f"{statistics.median(two) / statistics.median(one):.2f}; at best "
                  f"{best_ratio(tasks[job]):.2f} for its tasks of "
                  + ", ".join(f"{c:.1f}" for c in sorted(tasks[job], reverse=True))
                  + " s of CPU")
    print(f"\nCPU per fitted refit window: {cpu_window:.3f} s")
    if diag_rows is not None:
        print("diagnoses: " + "; ".join(f"{r.furnace} {r.fit_campaign}->{r.holdout_campaign} "
                                        f"{r.status} [{r.effects}] {r.cpu_s:.1f} s CPU"
                                        for r in diag_rows.itertuples()))
        print(f"CPU per diagnosis (median): {diag_rows['cpu_s'].median():.1f} s")
    ev = {k: pd.read_parquet(root / f"out-0-2-{k}" / "drift_events.parquet")
          for k in ("refituncut", "refitcut1d")}
    for k, e in ev.items():
        print(f"drift events {k}: " + ("; ".join(f"{x.furnace} {x.parameter} {x.window_end}"
                                                 for x in e.itertuples()) or "none"))
    if not args.quick:
        print("\n" + shipped_cost(root))
    print("\nThe cut's effect, windows counted from the first one after each cut "
          "(fitted in both runs):\n")
    print("\n".join(cut_effect(tables["refit cut 1 d"], uncut, REFIT["period_s"])))


if __name__ == "__main__":
    main()
