"""The online refit's three methods side by side: `refit.method: ga_polish` (the default: the
GA seeded with the previous window's model, then the polish), `ga` (the paper's GA from
scratch on every window, population 20, 2000 generations) and `polish` (the polish alone
from the previous model). CPU time per fitted window, how far each window's model is from
the plant's truth (a..f, and b/c and d/e, which 1-minute data determine where b, c, d and e
alone are not: docs/identification.md), and the drift events raised on a plant that does
not drift.

Each case is a plant run at 1-minute samples cut into windows on the data clock and fitted
window by window in this process by the refit chain (RefitChain.process, as replay without a
worker; the fit runs on one thread, so the process's CPU time is the fit's):
- the shipped window: 24 h of `week_steps` per refit (the built-in `window_s`), a refit every
  3 h over two days (every 15 min as shipped would give the same kind of fits, 8 times as
  many of them);
- the demo's: `paper_exp1` (55 h) with `make demo`'s refit of the last 36 h every 6 h;
- production in closed loop: `paper_production` (a PI loop per zone staging whole burners,
  slabs charged all day), its first two days as the shipped window. The burners follow the
  readings' noise there, and a window held at its setpoints carries less than a heat-up; the
  furnace is a network of its own, so the errors are shown per parameter of that network.
  (The modulated furnace's closed loop has pulse-fired zones, which `run_messages` cannot
  write without the simulated PLC.)
- a production day with two faults: tests/data/production_faults_day.yaml (soak_1 drifting
  from 7 h, each burner 25% weaker from 12.5 h) with the online story test's 6-h windows
  every hour. No diagnosis runs here, so soak_1 is never set aside, and every window that
  holds a fault misses its noise floor: what a refit costs while the model does not fit.

    .venv/bin/python bench/bench_refit.py [--quick] [--cases TEXT] [--methods M ...]
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace
from pathlib import Path

from furnace_daq.daqconfig import REFIT_METHODS, RefitConfig
from furnace_daq.plantlog import run_messages
from furnace_daq.refit import RefitChain, WindowCutter
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "config" / "scenarios"
HOUR = 3600.0
DAYS_2 = 2 * 1440.0
CASES = {
    "shipped window: week_steps, 24-h window every 3 h": (SCENARIOS / "week_steps.yaml", DAYS_2,
                                                          3 * HOUR, 24 * HOUR),
    "demo: paper_exp1, 36-h window every 6 h": (SCENARIOS / "paper_exp1.yaml", None, 6 * HOUR,
                                                36 * HOUR),
    "production record: paper_production, 24-h window every 3 h": (
        SCENARIOS / "paper_production.yaml", DAYS_2, 3 * HOUR, 24 * HOUR),
    "two faults: production_faults_day, 6-h window every hour": (
        ROOT / "tests" / "data" / "production_faults_day.yaml", None, HOUR, 6 * HOUR),
}


PAPER_COLUMNS = {**{p: (lambda m, p=p: m[p]) for p in "abcdef"},
                 "b/c": lambda m: m["b"] / m["c"], "d/e": lambda m: m["d"] / m["e"]}
"""The errors shown on the paper's furnace: its parameters, and the ratios 1-minute data
determine."""


def columns(truth: dict) -> dict:
    """The errors shown for a plant of this truth: the paper's columns, or on a furnace of
    its own network every parameter by its name."""
    if all(p in truth for p in "abcdef"):
        return PAPER_COLUMNS
    return {p: (lambda m, p=p: m[p]) for p in truth}


def header(names) -> str:
    head = ("| case | method | ok / fitted | median CPU | max CPU | " + " | ".join(names)
            + " | max RMSE | drift events |")
    return head + "\n" + "|---" * (head.count("|") - 1) + "|"


def refits(path: Path, duration_min: float | None, config: RefitConfig,
           seed: int) -> tuple[list[tuple[dict, float]], list[dict], dict]:
    """([(message, CPU s)] per window, events, the plant's truth)."""
    s = load_scenario(path)
    if duration_min is not None:
        s.duration_min = min(s.duration_min, duration_min)
    run = Plant.from_scenario(s, seed=seed).run_scenario(s)
    cutter = WindowCutter(config, s.t_air_c, furnace=s.furnace)
    chain = RefitChain(config, s.t_air_c, furnace=s.furnace)
    params: list[tuple[dict, float]] = []
    events: list[dict] = []
    for topic, msg, t in run_messages(run):
        for window in cutter.feed(topic, msg, t):
            cpu = time.process_time()
            message, raised = chain.process(window)
            params.append((message.to_json(), time.process_time() - cpu))
            events += [e.to_json() for e in raised]
    return params, events, s.values()


def row(case: str, method: str, params: list[tuple[dict, float]], events: list[dict],
        truth: dict) -> str:
    fitted = [(m, cpu) for m, cpu in params if m["status"] != "insufficient_excitation"]
    ok = [m for m, _ in fitted if m["status"] == "ok"]
    times = [cpu for _, cpu in fitted]
    errors = []
    for value in columns(truth).values():
        try:
            errors.append(f"{100 * max(abs(value(m) / value(truth) - 1) for m in ok):.1f}%")
        except (KeyError, ValueError, ZeroDivisionError):  # not this model's, or no ok window
            errors.append("-")
    rmse = max(max(m["rmse_c"].values()) for m in ok) if ok else float("nan")
    drift = sum(e["kind"] == "drift" for e in events)
    cpu = f"{statistics.median(times):.2f} s | {max(times):.2f} s" if times else "- | -"
    return (f"| {case} | {method} | {len(ok)} / {len(fitted)} | {cpu} | "
            + " | ".join(errors) + f" | {rmse:.2f} °C | {drift} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="the shipped window only")
    ap.add_argument("--cases", default="", help="only the cases whose name holds this text")
    ap.add_argument("--methods", nargs="+", choices=REFIT_METHODS, default=list(REFIT_METHODS))
    ap.add_argument("--seed", type=int, default=1, help="plant noise seed")
    args = ap.parse_args()
    print("Online refit, per fitted window: CPU time of the fit, largest error against the "
          "plant's truth over the ok windows, largest per-zone RMSE, drift events (the plant "
          "does not drift, but in the two-fault case)\n")
    shown = None
    cases = [(c, v) for c, v in CASES.items() if args.cases in c]
    for case, (path, duration, period, window) in cases[:1] if args.quick else cases:
        if not path.exists():
            print(f"| {case} | (no {path}: skipped) |")
            continue
        base = RefitConfig(period_s=period, window_s=window, step_s=60.0)
        for method in args.methods:
            params, events, truth = refits(path, duration, replace(base, method=method),
                                           args.seed)
            if list(columns(truth)) != shown:
                shown = list(columns(truth))
                print("\n" + header(shown))
            print(row(case, method, params, events, truth), flush=True)


if __name__ == "__main__":
    main()
