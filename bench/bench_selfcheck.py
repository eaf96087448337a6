"""The selfcheck's table as `furnace-model selfcheck` runs it (one process, whose diagnoses
fit their candidates two at a time in a pool of their own) against the same table on a
LocalCluster of 2 worker processes (`furnace-fleet selfcheck`: one draw a task, its
candidates fitted one after another): wall time of each, their ratio, the best ratio the
cluster's tasks allow (the longest draw, or the draws shared out evenly), and that the two
give the same verdict on every draw. The default rows (every
effect the selfcheck draws, and the control), `--draws` per row; the full table is ten.

    .venv/bin/python bench/bench_selfcheck.py [--draws 1] [--workers 2]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from furnace_daq.fleet.engine import open_client
from furnace_daq.fleet.jobs import run_selfcheck
from furnace_model.cli.selfcheck import labels_of
from furnace_model.diagnosis.selfcheck import check
from furnace_model.simulation.furnace import PAPER


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--draws", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    labels = labels_of(argparse.Namespace(first_draw=0, draws=args.draws, effects=None,
                                          furnace=None, all=False))
    print(f"rows: {', '.join(labels)}; {args.draws} draw(s) each", flush=True)

    t0, c0 = time.perf_counter(), time.process_time()
    one = check(labels, args.draws)
    t_one, c_one = time.perf_counter() - t0, time.process_time() - c0
    print(f"one process: {t_one:.1f} s wall, {c_one:.1f} s CPU", flush=True)

    with tempfile.TemporaryDirectory() as out, open_client(workers=args.workers) as client:
        t0 = time.perf_counter()
        many, result = run_selfcheck(client, labels, args.draws, Path(out), quiet=True,
                                     furnace=PAPER)
        t_many = time.perf_counter() - t0
    assert not result.failures, result.failures
    print(f"LocalCluster of {args.workers}: {t_many:.1f} s wall", flush=True)

    def key(o):
        return (o.label, o.draw, o.status, tuple(o.named), o.correct)

    same = [key(a) == key(b) for a, b in zip(one, many, strict=True)]
    print(f"\n| rows x draws | one process (s) | LocalCluster, {args.workers} workers (s) | "
          "ratio | same verdicts |")
    print("|---|---|---|---|---|")
    print(f"| {len(labels)} x {args.draws} | {t_one:.1f} | {t_many:.1f} | "
          f"{t_many / t_one:.2f} | {sum(same)} of {len(same)} |")
    tasks = [o.elapsed_s for o in many]
    print(f"\ncluster draws: {sum(tasks):.0f} s in all, the longest {max(tasks):.0f} s: at best "
          f"{max(max(tasks), sum(tasks) / args.workers):.0f} s of wall time on {args.workers}")
    slow = sorted(one, key=lambda o: -o.elapsed_s)[:5]
    print("\nlongest draws (one process): " + "; ".join(
        f"{o.label} {o.draw}: {o.elapsed_s:.0f} s" for o in slow))
    if not all(same):
        print("differ: " + "; ".join(f"{key(a)} vs {key(b)}" for a, b, s
                                     in zip(one, many, same, strict=True) if not s))


if __name__ == "__main__":
    main()
