"""The online refit's two methods side by side: `refit.method: polish` (the default: each
window polished from the previous window's model) and `refit.method: ga` (the paper's GA
from scratch on every window, population 20, 2000 generations). Time per refit in the
worker process, and how far each window's model is from the plant's truth.

Two cases, fed through the real pipeline (RefitRunner and its worker process, as replay
does) from plant runs at 1-minute samples:
- the demo's: `paper_exp1` (55 h) with `make demo`'s refit of the last 36 h every 6 h;
- the shipped window: 24 h of `week_steps` per refit (the built-in `window_s`), a refit
  every 3 h over two days (every 15 min as shipped would give the same fits, 8 times as
  many of them).

    .venv/bin/python bench/bench_refit.py [--quick]
"""

from __future__ import annotations

import argparse
import statistics
from dataclasses import replace
from pathlib import Path

from furnace_daq.daqconfig import RefitConfig
from furnace_daq.plantlog import run_messages
from furnace_daq.refitworker import RefitRunner
from furnace_model.log.schema import MODEL_EVENTS, MODEL_PARAMETERS
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "config" / "scenarios"
HOUR = 3600.0
CASES = {
    "demo: paper_exp1, 36-h window every 6 h": ("paper_exp1", None, 6 * HOUR, 36 * HOUR),
    "shipped window: week_steps, 24-h window every 3 h": ("week_steps", 2 * 1440.0, 3 * HOUR,
                                                          24 * HOUR),
}


def combinations(p: dict) -> dict[str, float]:
    """What 1-minute data determine (docs/identification.md)."""
    return {"a": p["a"], "f": p["f"], "b/c": p["b"] / p["c"], "d/e": p["d"] / p["e"]}


def refits(name: str, duration_min: float | None, config: RefitConfig,
           seed: int) -> tuple[list[dict], list[dict], dict]:
    s = load_scenario(SCENARIOS / f"{name}.yaml")
    if duration_min is not None:
        s.duration_min = duration_min
    run = Plant.from_scenario(s, seed=seed).run_scenario(s)
    params: list[dict] = []
    events: list[dict] = []

    def emit(topic: str, msg, _pub_ns: int) -> None:
        (params if topic == MODEL_PARAMETERS else events).append(msg.to_json())
        assert topic in (MODEL_PARAMETERS, MODEL_EVENTS)

    runner = RefitRunner(config, emit, max_queue=None, furnace=PAPER)
    runner.start()
    try:
        for topic, msg, t in run_messages(run):
            runner.feed(topic, msg, t)
            while len(runner.queue) > 2:
                runner.pump(1.0)
        if not runner.drain(3600.0):
            raise SystemExit("refits did not finish within an hour")
    finally:
        runner.close()
    return params, events, s.params


def row(case: str, method: str, params: list[dict], events: list[dict], truth: dict) -> str:
    fitted = [m for m in params if m["status"] != "insufficient_excitation"]
    ok = [m for m in fitted if m["status"] == "ok"]
    times = [m["elapsed_s"] for m in fitted]
    want = combinations(truth)
    errors = {k: max(abs(combinations(m)[k] / v - 1) for m in ok) for k, v in want.items()}
    rmse = max(max(m["rmse_c"].values()) for m in ok)
    drift = sum(e["kind"] == "drift" for e in events)
    return (f"| {case} | {method} | {len(ok)} / {len(fitted)} | "
            f"{statistics.median(times):.2f} s | {max(times):.2f} s | "
            + " | ".join(f"{100 * errors[k]:.1f}%" for k in want)
            + f" | {rmse:.2f} °C | {drift} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="the demo's case only")
    ap.add_argument("--seed", type=int, default=1, help="plant noise seed")
    args = ap.parse_args()
    print("Online refit, per fitted window: time in the worker, largest error against the "
          "plant's truth over the ok windows, largest per-zone RMSE, drift events (the plant "
          "does not drift)\n")
    print("| case | method | ok / fitted | median time | max time | a | f | b/c | d/e "
          "| max RMSE | drift events |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    cases = list(CASES.items())[:1] if args.quick else CASES.items()
    for case, (name, duration, period, window) in cases:
        base = RefitConfig(period_s=period, window_s=window, step_s=60.0)
        for method in ("polish", "ga"):
            params, events, truth = refits(name, duration, replace(base, method=method),
                                           args.seed)
            print(row(case, method, params, events, truth), flush=True)


if __name__ == "__main__":
    main()
