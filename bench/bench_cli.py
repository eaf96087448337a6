"""How fast the two commands answer `--help` and `--version`: the installed console scripts
(next to this interpreter) run as a user runs them, each answer repeated; wall time from
start to exit, and from `-X importtime` what was imported and how long that took. Aim: every
answer under 0.3 s (the median: on a shared machine a single run can wait for a core). Prints a markdown table for docs/performance.md.

    .venv/bin/python bench/bench_cli.py [--repeat 15]

The scripts import the package the environment resolves: run from a source tree with
PYTHONPATH=. to measure that tree.
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


def wall(argv: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def imports(argv: list[str]) -> tuple[float, list[str]]:
    """Seconds spent importing, and the heavy packages among the imports."""
    env = {**os.environ, "PYTHONPROFILEIMPORTTIME": "1"}
    err = subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         text=True, env=env).stderr
    total, heavy = 0, set()
    for line in err.splitlines():
        if not line.startswith("import time:") or "|" not in line[13:]:
            continue
        _self, cumulative, name = line[13:].split("|")
        if not cumulative.strip().isdigit():
            continue  # the header line
        if not name[1:].startswith(" "):  # top level: its cumulative time holds the rest
            total += int(cumulative)
        if name.strip().split(".")[0] in HEAVY:
            heavy.add(name.strip().split(".")[0])
    return total / 1e6, sorted(heavy)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=15)
    args = ap.parse_args()
    floor = [wall([sys.executable, "-c", "pass"]) for _ in range(args.repeat)]
    rows = []
    for answer in ANSWERS:
        argv = [str(BIN / answer[0]), *answer[1:]]
        try:
            wall(argv)  # warm the file cache
        except subprocess.CalledProcessError as exc:  # an older tree without the option
            print(f"{' '.join(answer)}: exit {exc.returncode}", file=sys.stderr)
            continue
        times = [wall(argv) for _ in range(args.repeat)]
        imp, heavy = imports(argv)
        rows.append((" ".join(answer), statistics.median(times), max(times), imp, heavy))
    print(f"each answer run {args.repeat} times; an empty interpreter (`python -c pass`) "
          f"takes {1e3 * statistics.median(floor):.0f} ms\n")
    print("| command | wall median | wall max | imports | heavy libraries loaded |")
    print("|---|---|---|---|---|")
    for name, med, top, imp, heavy in rows:
        print(f"| `{name}` | {1e3 * med:.0f} ms | {1e3 * top:.0f} ms | {1e3 * imp:.0f} ms | "
              f"{', '.join(heavy) or 'none'} |")
    slow = [r[0] for r in rows if r[1] >= 0.3]
    print(f"\nmedian {'under 0.3 s for every answer' if not slow else 'over 0.3 s: ' + ', '.join(slow)}")


if __name__ == "__main__":
    main()
