"""The fit's Jacobian: exact (closed-form sensitivities) against forward differences, and
what that does to a cold `fit` and to the paper pair's `diagnose`. Both ways run in the
same process on the same data, alternating, so the ratios hold on a busy machine. Prints
markdown tables for docs/performance.md.

    .venv/bin/python bench/bench_jacobian.py [--repeat 5] [--no-diagnose]

The paper pair is the worked example of docs/diagnosis.md (bench_diagnose.py); the fit is
of its first heat-up. CPU time of this process, one BLAS thread (the diagnosis's pool is set to
one worker so that all of its work is counted here). The six-zone rows are a random
heat-up of the shipped six-zone furnace, with its thermocouple offsets fitted; the
production rows a closed-loop record of the shipped paper_production scenario (seed 5), its
burners staged nearly every minute. Two trees compare by running this alternately in each.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from bench_diagnose import paper_pair

from furnace_model.blas import one_thread
from furnace_model.diagnosis import diagnose
from furnace_model.diagnosis import pool as diagnosis_pool
from furnace_model.diagnosis.cases import draw_case, draw_closed_loop_case, network_truth
from furnace_model.effects import EFFECTS
from furnace_model.identification import jacobian as jacobian_module
from furnace_model.identification import problem as problem_module
from furnace_model.identification.fit import fit
from furnace_model.identification.problem import Problem
from furnace_model.simulation.furnacefile import load_furnace
from furnace_model.simulation.structure import ModelStructure

SHIPPED = Path(__file__).resolve().parent.parent / "config" / "furnaces"

WAYS = {"exact": jacobian_module.jacobian, "differences": jacobian_module.forward_differences}


def cpu(f: Callable[[], object], repeat: int, inner: int = 1) -> float:
    """Median CPU seconds of one call."""
    out = []
    for _ in range(repeat):
        t = time.process_time()
        for _ in range(inner):
            f()
        out.append((time.process_time() - t) / inner)
    return statistics.median(out)


def row(label: str, prob: Problem, z: np.ndarray, repeat: int) -> None:
    t = {w: 1e3 * cpu(lambda f=f: f(prob, z), repeat, 20) for w, f in WAYS.items()}
    print(f"| {label} | {t['exact']:.2f} | {t['differences']:.2f} | "
          f"{t['differences'] / t['exact']:.1f} |")


def at_truth_row(records: list, name: str, label: str, repeat: int) -> None:
    """`row` for the records' network with effect `name` (or none), its offsets fitted, at
    the network's truth and the effect's defaults."""
    furnace = records[0].furnace
    structure = ModelStructure([] if name == "baseline" else [EFFECTS[name](furnace=furnace)],
                               furnace=furnace)
    prob = Problem(records, structure, {}, {}, zone_offsets=True)
    truth = {**structure.defaults(), **network_truth(furnace)}
    z = prob.start(prob.to_z(np.array([truth[n] for n in prob.names])))
    row(label.format(name=name, samples=len(records[0]), columns=prob.n), prob, z, repeat)


def using(way: str) -> None:
    problem_module.jacobian = WAYS[way]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--no-diagnose", action="store_true")
    args = ap.parse_args()
    with one_thread():  # as fit and diagnose run
        measure(args)


def measure(args: argparse.Namespace) -> None:
    data = paper_pair()
    furnace = data[0].furnace
    print("| structure (paper pair, 3311 + 3801 samples, unless named) | exact (ms) | differences (ms) "
          "| differences / exact |")
    print("|---|---|---|---|")
    for name in ("baseline", *(n for n in EFFECTS if n != "radiation")):
        effects = [] if name == "baseline" else [EFFECTS[name](furnace=furnace)]
        structure = ModelStructure(effects, furnace=furnace)
        prob = Problem(data, structure, {}, {})
        z = prob.start(prob.to_z(np.array([structure.defaults()[n] for n in prob.names])))
        row(name, prob, z, args.repeat)
    six = load_furnace(SHIPPED / "six-zone.yaml")
    records = draw_case(None, np.random.default_rng(3), furnace=six).fit
    for name in ("baseline", "wall_storage", "sensor_lag", "sensor_drift"):
        at_truth_row(records, name, "six-zone {name} ({samples} samples, {columns} columns)",
                     args.repeat)
    production = draw_closed_loop_case(None, np.random.default_rng(5)).fit
    for name in ("baseline", "sensor_lag", "wall_storage", "sensor_drift", "fuel_change",
                 "dead_time"):
        at_truth_row(production, name, "production, {name} ({samples} samples, in closed loop)",
                     args.repeat)
    print()
    rows = [("fit of paper_exp1_zone_burners, cold (GA + polish)",
             lambda: fit(data[:1], ModelStructure(furnace=furnace)))]
    if not args.no_diagnose:
        diagnosis_pool.WORKERS = 1
        rows.append(("diagnose the paper pair (one worker)", lambda: diagnose(data)))
    print("| job | exact (s) | differences (s) | differences / exact |")
    print("|---|---|---|---|")
    for label, job in rows:
        times: dict[str, list[float]] = {w: [] for w in WAYS}
        for _ in range(args.repeat if "fit" in label else max(1, args.repeat // 2)):
            for w in WAYS:
                using(w)
                times[w].append(cpu(job, 1))
        using("exact")
        med = {w: statistics.median(v) for w, v in times.items()}
        print(f"| {label} | {med['exact']:.2f} | {med['differences']:.2f} | "
              f"{med['differences'] / med['exact']:.2f} |")


if __name__ == "__main__":
    main()
