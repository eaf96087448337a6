"""Do the 95% intervals hold the truth as often as they say, with the offsets and initial
states held to what is physical? Known truth: the paper's experiment-1 schedule with
Table V parameters, thermocouple bias of sd 0.5 °C per thermocouple and noise of sd 1.5 °C
(white, low-pass, low-pass with white on top), fitted as tests/test_coverage.py fits them
(zone offsets on, started 5% off the truth). Prints, per noise, how many of the draws'
intervals hold each parameter's truth, how many hold each zone offset's truth (the mean
bias of the zone's thermocouples, which the plant drew), and how many fits flagged an
offset or a start on its bound. A markdown table for docs/identification.md.

    .venv/bin/python bench/bench_coverage.py [--draws 100] [--quick]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from furnace_model.identification.fit import fit
from furnace_model.simulation.parameters import PAPER_TABLE_V
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))  # the thermocouples and start the coverage test uses
from test_coverage import NOISE, START  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--draws", type=int, default=100)
    ap.add_argument("--quick", action="store_true", help="10 draws a row")
    args = ap.parse_args()
    draws = 10 if args.quick else args.draws
    names = list(PAPER_TABLE_V)
    print(f"| noise | draws | {' | '.join(names)} | offset soak | offset heat | offset preheat "
          "| fits flagged |")
    print("|---" * (len(names) + 6) + "|")
    for noise, spec in NOISE.items():
        sc = replace(load_scenario(ROOT / "config/scenarios/paper_exp1.yaml"), sensors=spec)
        held = {n: 0 for n in names}
        offsets = np.zeros(3, dtype=int)
        flagged = 0
        t0 = time.perf_counter()
        for k in range(draws):
            plant = Plant.from_scenario(sc, seed=5000 + k)
            exp = plant.run_scenario(sc).to_experiment()
            res = fit([exp], init=START, zone_offsets=True)
            for n in names:
                lo, hi = res.ci95[n]
                held[n] += lo <= PAPER_TABLE_V[n] <= hi
            truth = exp.furnace.zone_means(plant.bias[None])[0]
            for w, zone in enumerate(exp.furnace.zones):
                ci = res.zone_offsets_ci95_c[0][zone]
                offsets[w] += ci is not None and ci[0] <= truth[w] <= ci[1]
            flagged += bool(res.flags)
            print(f"\r{noise}: {k + 1}/{draws} {time.perf_counter() - t0:.0f} s", end="",
                  file=sys.stderr, flush=True)
        print(file=sys.stderr)
        print(f"| {noise} | {draws} | " + " | ".join(str(held[n]) for n in names) + " | "
              + " | ".join(str(v) for v in offsets) + f" | {flagged} |", flush=True)


if __name__ == "__main__":
    main()
