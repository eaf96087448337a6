"""`make demo` against its promise: the whole chain (sim-plc process, daemon, online refits,
export, whole-run fit, plots) in under two minutes on a 2-core machine. Runs the default demo
and reports wall time, CPU of the demo and its children, skipped poll ticks, the refits and
the last online model's errors against the truth. Prints a markdown table.

With `--story`, the online story test's run instead (tests/test_demo.py's production day
with a drifting thermocouple and a fuel change, 17 hours at 500x, refits of 6-h windows
every hour), against its aim of a minute of CPU: each online diagnosis's line is printed
under the table. `--against TREE` runs another source tree's demo alternately with this
one's (its modules first on the path, as bench_diagnose.py does), a row each.

    .venv/bin/python bench/bench_demo.py [--runs 1] [--speed 5000] [--story] [--against TREE]
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ROW = re.compile(r"^\s+(a|f|b/c|d/e)\s+\S+\s+\S+\s+([-+][\d.]+)%")
STORY = ("--scenario", str(ROOT / "tests" / "data" / "production_faults_day.yaml"), "--speed",
         "500", "--refit-window-h", "6", "--refit-period-h", "1")


def one(tree: Path, *args: str) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    with tempfile.TemporaryDirectory() as tmp:
        load = os.getloadavg()[0]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.monotonic()
        done = subprocess.run([sys.executable, "-m", "furnace_daq.demo", "--out", tmp, *args],
                              capture_output=True, text=True, cwd=tree, env=env)
        wall = time.monotonic() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"demo failed ({done.returncode}): {done.stderr[-2000:]}")
    polls = re.search(r"(\d+) of (\d+) polls answered, (\d+) ticks skipped; (\d+) refits, "
                      r"(\d+) ok", done.stdout)
    tail = done.stdout[done.stdout.index("4. Identified"):]
    errors = {m.group(1): float(m.group(2)) for m in map(ROW.match, tail.splitlines()) if m}
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return {"wall": wall, "cpu": cpu, "load": load, "polls": int(polls.group(2)),
            "skipped": int(polls.group(3)), "refits": int(polls.group(4)),
            "ok": int(polls.group(5)), "errors": errors,
            "diagnoses": [line.strip() for line in done.stdout.splitlines()
                          if line.startswith("   online diagnosis of ")]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--speed", default="5000")
    ap.add_argument("--story", action="store_true",
                    help="the online story test's run (its own speed)")
    ap.add_argument("--against", type=Path, metavar="TREE",
                    help="another source tree, run alternately with this one")
    args = ap.parse_args()
    trees = [ROOT] + ([args.against.resolve()] if args.against else [])
    demo = STORY if args.story else ("--speed", args.speed)
    runs = [(tree, one(tree, *demo)) for _ in range(args.runs) for tree in trees]
    what = ("the online story (production_faults_day, 17 simulated hours at 500x)" if args.story
            else f"make demo (paper_exp1, 55.2 simulated hours at {args.speed}x)")
    print(f"{what}, {len(runs)} run(s)\n")
    print("| run | tree | wall | CPU (all processes) | load avg at start | polls, skipped ticks "
          "| refits ok / all | last online model: a, f, b/c, d/e error |")
    print("|---|---|---|---|---|---|---|---|")
    for k, (tree, r) in enumerate(runs, 1):
        errs = ", ".join(f"{r['errors'][n]:+.2f}%" if n in r["errors"] else "-"
                         for n in ("a", "f", "b/c", "d/e"))
        print(f"| {k} | {tree} | {r['wall']:.1f} s | {r['cpu']:.1f} s | {r['load']:.1f} "
              f"| {r['polls']}, {r['skipped']} | {r['ok']} / {r['refits']} | {errs} |")
    for k, (_, r) in enumerate(runs, 1):
        for line in r["diagnoses"]:
            print(f"\nrun {k}: {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
