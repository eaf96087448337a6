"""Diagnosis speed: `diagnose` of two heat-ups of about 3500 minutes at 1-minute samples
across all nine candidates, wall time per case. Prints a markdown table for
docs/performance.md.

    .venv/bin/python bench/bench_diagnose.py [--quick] [--repeat 3]

The headline case is the worked example of docs/diagnosis.md: the paper's two heat-ups
(3310 and 3800 minutes) on a furnace with zone burners, given together so that the
diagnosis picks the holdout. The others come from furnace_model.diagnosis.cases.draw_case (the
plant simulator with one effect, random strengths and schedules): a control (no gap: only
the baseline is fitted), a case the baseline absorbs badly (zone burners: every candidate
fitted, warm and cold), a lag, and a nonlinear effect (radiation: exponent 4, then its
exponent fitted).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np

from furnace_model.diagnosis import diagnose
from furnace_model.diagnosis.cases import draw_case
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

CASES = ("paper pair", None, "zone_burners", "sensor_lag", "radiation")
SCENARIOS = Path(__file__).resolve().parent.parent / "config" / "scenarios"


def paper_pair() -> list:
    out = []
    for seed, name in ((1, "paper_exp1_zone_burners"), (2, "paper_exp2_zone_burners")):
        sc = load_scenario(SCENARIOS / f"{name}.yaml")
        out.append(Plant.from_scenario(sc, seed=seed).run_scenario(sc).to_experiment(name))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="one run per case")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    repeat = 1 if args.quick else args.repeat
    print(f"cores available: {os.cpu_count()}\n")
    print("| case | samples (fit + held out) | verdict | candidates | median wall time (s) | runs |")
    print("|---|---|---|---|---|---|")
    for name in CASES:
        times = []
        for r in range(repeat):
            if name == "paper pair":
                data, hold = paper_pair(), None
            else:
                case = draw_case(name, np.random.default_rng(7000 + r), furnace=PAPER)
                data, hold = case.fit, case.holdout
            t0 = time.perf_counter()
            d = diagnose(data, hold)
            times.append(time.perf_counter() - t0)
        n = " + ".join(str(len(e)) for e in d.fit_data + d.holdout)
        print(f"| {name or 'control'} | {n} | {d.verdict.status} "
              f"{'+'.join(d.verdict.effects)} | {len(d.candidates)} | "
              f"{statistics.median(times):.1f} | {repeat} |", flush=True)


if __name__ == "__main__":
    main()
