"""Diagnosis speed: `diagnose` of two heat-ups of about 3500 minutes at 1-minute samples
across all nine candidates, wall time per case. Prints a markdown table for
docs/performance.md.

    .venv/bin/python bench/bench_diagnose.py [--quick] [--repeat 3]

Cases come from furnace_model.selfcheck.draw_case (the plant simulator with one effect,
random strengths and schedules): a control (no gap: only the baseline is fitted), a case
the baseline absorbs badly (zone burners: every candidate fitted, warm and cold) and one
with a nonlinear effect (radiation).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from furnace_model.diagnosis import diagnose
from furnace_model.selfcheck import draw_case

CASES = (None, "zone_burners", "sensor_lag", "radiation")


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
            case = draw_case(name, np.random.default_rng(7000 + r))
            t0 = time.perf_counter()
            d = diagnose(case.fit, case.holdout)
            times.append(time.perf_counter() - t0)
        n = len(case.fit[0]) + len(case.holdout[0])
        print(f"| {name or 'control'} | {n} | {d.verdict.status} "
              f"{'+'.join(d.verdict.effects)} | {len(d.candidates)} | "
              f"{statistics.median(times):.1f} | {repeat} |", flush=True)


if __name__ == "__main__":
    main()
