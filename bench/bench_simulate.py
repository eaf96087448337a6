"""Batched exact simulation: 1000 parameter sets over the paper's 3800-minute second
experiment at 1-minute samples, in one call. Prints a markdown table for docs/performance.md.

    .venv/bin/python bench/bench_simulate.py [--sets 1000] [--repeat 15]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from furnace_model.effects import DeadTime, SensorLag, ZoneBurners
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.parameters import PAPER_TABLE_V
from furnace_model.simulation.scenario import load_scenario
from furnace_model.simulation.structure import ModelStructure

ROOT = Path(__file__).resolve().parent.parent


def median_time(fn, repeat: int) -> float:
    fn()  # warm up: first-touch page faults of the result array
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sets", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=15)
    args = ap.parse_args()
    scn = load_scenario(ROOT / "config/scenarios/paper_exp2.yaml")
    t = scn.sample_times()
    rng = np.random.default_rng(0)
    rows = []
    for structure, label in [
        (ModelStructure(furnace=PAPER), "paper model (eq. 11)"),
        (ModelStructure([ZoneBurners(furnace=PAPER), SensorLag(furnace=PAPER)],
                        furnace=PAPER), "+ zone_burners + sensor_lag (9 states)"),
        (ModelStructure([DeadTime(furnace=PAPER)],
                        furnace=PAPER), "+ dead_time (per-set step times)"),
    ]:
        values = {p.name: p.default * np.exp(rng.normal(0, 0.2, args.sets)) if p.log
                  else np.full(args.sets, p.default) for p in structure.params}
        values.update({k: v * np.exp(rng.normal(0, 0.2, args.sets))
                       for k, v in PAPER_TABLE_V.items()})
        sec = median_time(lambda s=structure, v=values: s.simulate(v, scn.inputs(), t,
                                                                   scn.initial_c), args.repeat)
        rows.append((label, sec))
    one = ModelStructure(furnace=PAPER)
    single = median_time(lambda: one.simulate(PAPER_TABLE_V, scn.inputs(), t, scn.initial_c),
                         args.repeat)
    print(f"{args.sets} parameter sets x {t.size} samples (paper_exp2, 1-minute sampling), "
          f"median of {args.repeat}\n")
    print("| structure | one call, all sets | per set |")
    print("|---|---|---|")
    for label, sec in rows:
        print(f"| {label} | {sec * 1e3:.1f} ms | {sec / args.sets * 1e6:.1f} us |")
    print(f"| paper model, one set | {single * 1e3:.2f} ms | |")


if __name__ == "__main__":
    main()
