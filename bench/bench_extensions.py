"""Simulation of the extended structures the diagnosis fits: per-parameter step times
(dead time, fuel change: a step instant that differs between parameter sets) and radiation
(nonlinear, integrated). One call simulates P parameter sets over the paper's second
experiment (3800 minutes at 1-minute samples); the diagnosis makes such calls with P = 1
(a polish step), about 11 (a Jacobian) and 32 (a GA generation). Prints a markdown table for
docs/performance.md.

    .venv/bin/python bench/bench_extensions.py [--repeat 7]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from bench_simulate import median_time  # a script beside this one

from furnace_model.effects import DeadTime, FuelChange, Radiation
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.parameters import PAPER_TABLE_V
from furnace_model.simulation.scenario import load_scenario
from furnace_model.simulation.structure import ModelStructure

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    scn = load_scenario(ROOT / "config/scenarios/paper_exp2.yaml")
    t, inputs = scn.sample_times(), scn.inputs()
    rng = np.random.default_rng(0)
    print(f"{t.size} samples (paper_exp2, 1-minute sampling), median of {args.repeat}\n")
    print("| structure | sets per call | one call | per set |")
    print("|---|---|---|---|")
    cases = [(DeadTime(furnace=PAPER), {"theta_dead": (1.0, 60.0)}, (1, 32, 1000)),
             (FuelChange(furnace=PAPER), {"t_fuel": (300.0, 3500.0)}, (1, 32, 1000)),
             (Radiation(furnace=PAPER), {"rad_share": (0.1, 0.9)}, (1, 11, 32))]
    for effect, spread, sizes in cases:
        ms = ModelStructure([effect], furnace=PAPER)
        for P in sizes:
            values = {k: v * np.exp(rng.normal(0, 0.1, P)) for k, v in PAPER_TABLE_V.items()}
            for p in effect.params:
                lo, hi = spread.get(p.name, (p.default, p.default))
                values[p.name] = rng.uniform(lo, hi, P)
            sec = median_time(lambda ms=ms, v=values: ms.simulate(v, inputs, t, scn.initial_c),
                              args.repeat)
            print(f"| + {effect.name} | {P} | {sec * 1e3:.1f} ms | {sec / P * 1e3:.2f} ms |",
                  flush=True)


if __name__ == "__main__":
    main()
