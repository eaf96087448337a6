"""Does an online diagnosis delay polling or the refit? The daemon polls `sim-plc` (as
bench_poll.py does: the default map at 10 Hz over loopback, logging MCAP) and a refit of a
day's window runs (`run_fit`, the worker's call, at the worker's priority), each once alone
and once beside a diagnosis started as the refit worker starts one (`DiagnosisProcess`: a
child process at `NICE` below, its candidates' pool with it, every effect, on a day of
production in closed loop with a drifting thermocouple). Prints poll jitter and CPU per
poll, and the refit's wall time (median of `--fits`), alone and beside, with their ratio.

    .venv/bin/python bench/bench_diagnosis_load.py [--seconds 30] [--fits 3] [--quick]
"""

from __future__ import annotations

import argparse
import logging
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))
from bench_poll import measure, start_simplc  # noqa: E402

from furnace_daq.diagnosisrunner import DiagnosisJob, DiagnosisProcess  # noqa: E402
from furnace_daq.diagnosistrigger import DiagnosisRequest  # noqa: E402
from furnace_daq.refit import FitJob, run_fit  # noqa: E402
from furnace_model.diagnosis.cases import draw_closed_loop_case  # noqa: E402
from furnace_model.simulation.parameters import PAPER_TABLE_V  # noqa: E402
from furnace_model.simulation.plant import Plant  # noqa: E402
from furnace_model.simulation.scenario import load_scenario  # noqa: E402

SCENARIOS = ROOT.parent / "config" / "scenarios"


def diagnosis() -> DiagnosisProcess:
    """A diagnosis of a production window, every effect, long enough to outlast the runs."""
    case = draw_closed_loop_case("sensor_drift", np.random.default_rng(3))
    window = case.fit[0].between(720.0, 2160.0)
    span = (0, int(window.t_min[-1] * 60e9))
    request = DiagnosisRequest("drift", "bench", window, span, window, span, seed=0)
    return DiagnosisProcess(DiagnosisJob(request, None, 3600.0))


def refit_wall(fits: int) -> float:
    """Median wall time of `run_fit` on a day of `week_steps`, started near the truth."""
    sc = load_scenario(SCENARIOS / "week_steps.yaml")
    window = Plant.from_scenario(sc, seed=1).run_scenario(sc).to_experiment().between(
        1440.0, 2880.0)
    start = {k: v * 1.05 for k, v in PAPER_TABLE_V.items()}
    walls = []
    for _ in range(fits):
        t0 = time.perf_counter()
        out = run_fit(FitJob(window, start, budget_s=600.0))
        walls.append(time.perf_counter() - t0)
        assert out["status"] == "ok", out["detail"]
    return statistics.median(walls)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=30.0, help="polling time per run")
    ap.add_argument("--fits", type=int, default=3, help="refits per run (median)")
    ap.add_argument("--quick", action="store_true", help="5 s of polling, one refit")
    args = ap.parse_args()
    seconds, fits = (5.0, 1) if args.quick else (args.seconds, args.fits)
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    sim, port = start_simplc()
    rows = {}
    try:
        for beside in (False, True):
            proc = diagnosis() if beside else None
            try:
                if proc is not None:
                    time.sleep(5.0)  # past its imports: fitting
                with tempfile.TemporaryDirectory() as tmp:
                    poll = measure(port, seconds, 10.0, Path(tmp))
                refit = refit_wall(fits)
                if proc is not None and proc.receive() is not None:
                    raise SystemExit("the diagnosis ended before the runs did: nothing beside")
            finally:
                if proc is not None:
                    proc.stop()
            rows[beside] = (poll, refit)
    finally:
        sim.terminate()
        sim.wait(10)
    (p0, r0), (p1, r1) = rows[False], rows[True]
    print(f"Polling at 10 Hz for {seconds:g} s and {fits} refit(s) of a day's window, alone and "
          "beside an online diagnosis (every effect, a production day).\n")
    print("| metric | alone | beside a diagnosis | ratio |")
    print("|---|---|---|---|")
    for name, key in (("period jitter p50", "jit_p50"), ("period jitter p99", "jit_p99"),
                      ("period jitter max", "jit_max"), ("CPU per poll", "cpu_per_poll_ms")):
        print(f"| {name} (ms) | {p0[key]:.2f} | {p1[key]:.2f} | {p1[key] / p0[key]:.2f} |")
    print(f"| skipped ticks | {p0['skipped']} | {p1['skipped']} | |")
    print(f"| refit wall time (s, median) | {r0:.2f} | {r1:.2f} | {r1 / r0:.2f} |")


if __name__ == "__main__":
    main()
