"""`sim-plc --from-log` start-up and serving cost: a log of H hours of the daemon's 1 Hz load
(thermocouples, burners, ambient) is written, then loaded as a PLC value source, and the
values of every PLC second are looked up as the server's scans do. Prints a markdown table.

    .venv/bin/python bench/bench_from_log.py [--hours 24]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from furnace_daq.logplayer import LogPlayer
from furnace_daq.mcaplog import LogWriter
from furnace_model.simulation.furnace import PAPER

T0 = 1_772_431_200 * 10**9
S = 10**9


def write(log_dir: Path, hours: float) -> int:
    rng = np.random.default_rng(0)
    n = int(hours * 3600)
    with LogWriter(log_dir, flush_interval_s=5.0) as log:
        for i in range(n):
            pub = T0 + i * S
            tc = {s: round(float(900 + 50 * np.sin(i / 3000) + rng.normal(0, 1.5)), 1)
                  for s in PAPER.sensors}
            tc["quality"] = {s: "ok" for s in PAPER.sensors}
            tc["plc_seconds"] = i
            on = 6 if (i // 1800) % 2 else 3
            log.write("/furnace/thermocouples", tc, pub, pub)
            log.write("/furnace/burners", {
                "soak": [k < on for k in range(10)], "heat": [False] * 8, "preheat": [False] * 8,
                "count_soak": on, "count_heat": 0, "count_preheat": 0, "source": "modbus"},
                pub, pub)
            log.write("/furnace/ambient", {"t_air": 30.0, "quality": "ok"}, pub, pub)
    return n


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--hours", type=float, default=24.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        n = write(Path(tmp), args.hours)
        files = sorted(Path(tmp).glob("*.mcap"))
        t0 = time.perf_counter()
        player = LogPlayer(files)
        load = time.perf_counter() - t0
        seconds = range(0, player.last_s + 1)
        t0 = time.perf_counter()
        for s in seconds:
            player.values_at(s)
        lookup = (time.perf_counter() - t0) / len(seconds)
    print(f"sim-plc --from-log, {args.hours:g} h of 1 Hz data ({3 * n} messages, "
          f"{len(files)} files)\n")
    print("| | value |\n|---|---|")
    print(f"| load the log (read, decode, index) | {load:.2f} s ({load / (3 * n) * 1e6:.1f} us "
          "per message) |")
    print(f"| values of one PLC second (one scan) | {lookup * 1e6:.1f} us |")
    print(f"| share of the default 0.1 s scan period (any --speed: one look-up per scan) | "
          f"{100 * lookup / 0.1:.3f} % |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
