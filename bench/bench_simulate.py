"""Batched exact simulation: 1000 parameter sets over the paper's 3800-minute second
experiment at 1-minute samples, in one call. Prints a markdown table for docs/performance.md.
With --segments: the two ways of walking many constant-input segments side by side, and the
one the simulator picks.

    .venv/bin/python bench/bench_simulate.py [--sets 1000] [--repeat 15] [--segments]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from furnace_model.effects import DeadTime, SensorLag, ZoneBurners
from furnace_model.simulation import lti
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


def segments_table(repeat: int) -> None:
    """`lti._segments` forced each way (the walk over segments with its tables, or every
    sample's exponential directly) on random stable modes, step times and samples a minute
    apart."""
    rng = np.random.default_rng(0)
    rule = (lti._DIRECT_CELLS, lti._WALK_SEGMENT_CELLS, lti._WALK_MODE_CELLS)
    print(f"`lti._segments`, median of {repeat}\n")
    print("| sets | modes | samples | segments | walk | direct | picked |")
    print("|---|---|---|---|---|---|---|")
    for P, n, N, K in [(1, 3, 4000, 50), (10, 1, 15000, 700), (10, 3, 15000, 200),
                       (10, 9, 4000, 700), (100, 3, 4000, 200), (100, 1, 4000, 50),
                       (1000, 3, 4000, 10), (1000, 1, 4000, 700)]:
        lam = -10 ** rng.uniform(-3, -0.5, (P, n))
        args = (lam, rng.standard_normal((P, 3, n)), rng.standard_normal((P, n)),
                rng.standard_normal((P, n)),
                np.sort(rng.choice(np.arange(1, N), K, replace=False)).astype(float),
                rng.standard_normal((P, K, n)), 0.0, np.arange(float(N)))
        times = {}
        for way, forced in (("walk", (0, 0, 0)), ("direct", (0, 10 ** 18, 0))):
            lti._DIRECT_CELLS, lti._WALK_SEGMENT_CELLS, lti._WALK_MODE_CELLS = forced
            times[way] = median_time(lambda a=args: lti._segments(*a), repeat)
        lti._DIRECT_CELLS, lti._WALK_SEGMENT_CELLS, lti._WALK_MODE_CELLS = rule
        picked = "direct" if (P * n * N <= rule[0]
                              or P * n * N < (K + 1) * (rule[1] + rule[2] * P * n)) else "walk"
        print(f"| {P} | {n} | {N} | {K + 1} | {times['walk'] * 1e3:.2f} ms "
              f"| {times['direct'] * 1e3:.2f} ms | {picked} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sets", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--segments", action="store_true",
                    help="the walk over segments against the direct way, and the pick")
    args = ap.parse_args()
    if args.segments:
        segments_table(args.repeat)
        return
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
