"""Identification speed on a furnace other than the paper's: the six-zone ladder furnace
(config/furnaces/six-zone.yaml, 22 parameters) over its 3300-minute heat-up at 1-minute
samples (config/scenarios/six_zone_heatup.yaml, simulated with seed 1), fitted as
`furnace-model fit --furnace` does (zone offsets on). Prints a markdown row for
docs/performance.md.

    .venv/bin/python bench/bench_network.py [--repeat 7]

Beside it, the paper's furnace on its first experiment with the same call, so that the two
are timed side by side on the same busy machine.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from furnace_model.identification.fit import fit
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

ROOT = Path(__file__).resolve().parent.parent


def record(name: str):
    sc = load_scenario(ROOT / "config" / "scenarios" / f"{name}.yaml")
    return sc, Plant.from_scenario(sc, seed=1).run_scenario(sc).to_experiment(name)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    cases = [record("six_zone_heatup"), record("paper_exp1")]
    times: dict[str, list[float]] = {sc.name: [] for sc, _ in cases}
    worst: dict[str, float] = {}
    for _ in range(args.repeat):  # alternating, so that both see the same load
        for sc, exp in cases:
            t0 = time.perf_counter()
            res = fit([exp], sc.structure(), zone_offsets=True)
            times[sc.name].append(time.perf_counter() - t0)
            worst[sc.name] = max(abs(res.params[k] / v - 1) for k, v in sc.params.items())
    print("| record | zones | parameters | samples | median s | min s | max s | "
          "worst parameter error |")
    print("|---|---|---|---|---|---|---|---|")
    for sc, exp in cases:
        t = np.array(times[sc.name])
        print(f"| {sc.name} | {sc.furnace.n_zones} | {len(sc.structure().names)} | {len(exp)} "
              f"| {np.median(t):.2f} | {t.min():.2f} | {t.max():.2f} | "
              f"{100 * worst[sc.name]:.2f}% |")


if __name__ == "__main__":
    main()
