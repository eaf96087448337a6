"""How fast the two commands answer `--help` and `--version`: the installed console scripts
(next to this interpreter) run as a user runs them, each answer repeated; wall time from
start to exit, and from `-X importtime` what was imported and how long that took. Aim: every
answer under 0.3 s (the median: on a shared machine a single run can wait for a core).
Prints a markdown table for docs/performance.md.

    .venv/bin/python bench/bench_cli.py [--repeat 15] [--against TREE]

The scripts import the package the environment resolves: run with PYTHONPATH=. to measure
this source tree. `--against TREE` runs each answer alternately from another source tree
(e.g. a checkout of an older commit), so that both see the same load.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

BIN = Path(sys.executable).parent
HEAVY = ("numpy", "pandas", "scipy", "matplotlib", "pymodbus", "mcap", "can", "pyarrow", "yaml")
ANSWERS = [
    ("furnace-model", "--version"), ("furnace-model", "--help"),
    *[("furnace-model", c, "--help") for c in
      ("simulate", "fit", "validate", "diagnose", "selfcheck")],
    ("furnace-daq", "--version"), ("furnace-daq", "--help"),
    *[("furnace-daq", *c.split(), "--help") for c in
      ("sim-plc", "run", "logs", "logs info", "logs export", "logs recover", "replay")],
]


def wall(argv: list[str], env: dict) -> float | None:
    """Seconds from start to exit; None when the answer fails (an older tree without it)."""
    t0 = time.perf_counter()
    done = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    return time.perf_counter() - t0 if done.returncode == 0 else None


def imports(argv: list[str], env: dict) -> tuple[float, list[str]]:
    """Seconds spent importing, and the heavy packages among the imports."""
    err = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                         env={**env, "PYTHONPROFILEIMPORTTIME": "1"}).stderr
    total, heavy = 0, set()
    for line in err.splitlines():
        if not line.startswith("import time:") or line.count("|") != 2:
            continue
        _self, cumulative, name = line[13:].split("|")
        if not cumulative.strip().isdigit():
            continue  # the header line
        if not name[1:].startswith(" "):  # top level: its cumulative time holds the rest
            total += int(cumulative)
        if name.strip().split(".")[0] in HEAVY:
            heavy.add(name.strip().split(".")[0])
    return total / 1e6, sorted(heavy)


def measure(argv: list[str], envs: list[dict], repeat: int) -> list[tuple | None]:
    """(median, max, import seconds, heavy packages) per environment, runs interleaved."""
    times: list[list[float]] = [[] for _ in envs]
    for env in envs:
        wall(argv, env)  # warm the file cache
    for _ in range(repeat):
        for i, env in enumerate(envs):
            t = wall(argv, env)
            if t is not None:
                times[i].append(t)
    return [(statistics.median(ts), max(ts), *imports(argv, env)) if ts else None
            for ts, env in zip(times, envs, strict=True)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--against", type=Path, metavar="TREE",
                    help="another source tree, measured alternately with this one")
    args = ap.parse_args()
    envs = [dict(os.environ)]
    if args.against:
        envs.append({**os.environ, "PYTHONPATH": str(args.against.resolve())})
    empty = measure([sys.executable, "-c", "pass"], envs[:1], args.repeat)[0]
    print(f"each answer run {args.repeat} times; an empty interpreter (`python -c pass`) "
          f"takes {1e3 * empty[0]:.0f} ms\n")
    head = "| command | wall median | wall max | imports | heavy libraries loaded |"
    if args.against:
        head += f" {args.against}: wall median | its heavy libraries |"
    print(head)
    print("|---" * (head.count("|") - 1) + "|")
    slow = []
    for answer in ANSWERS:
        got = measure([str(BIN / answer[0]), *answer[1:]], envs, args.repeat)
        cells = []
        for m in got:
            if m is None:
                cells.append("fails | |" if m is got[-1] and len(got) > 1 else "fails | | | |")
                continue
            med, top, imp, heavy = m
            cells.append(f"{1e3 * med:.0f} ms | " + ("" if m is got[-1] and len(got) > 1 else
                                                      f"{1e3 * top:.0f} ms | {1e3 * imp:.0f} ms | ")
                         + f"{', '.join(heavy) or 'none'} |")
        print(f"| `{' '.join(answer)}` | " + " ".join(cells))
        if got[0] is None or got[0][0] >= 0.3:
            slow.append(" ".join(answer))
    print(f"\nmedian {'under 0.3 s for every answer' if not slow else 'over 0.3 s: ' + ', '.join(slow)}")


if __name__ == "__main__":
    main()
