"""MCAP log layer: cost of one write and of a flush+fsync, bytes per hour of plant data, and
the speed of `logs export` / `logs recover` on a day of 1 Hz data. Prints a markdown table.

    .venv/bin/python bench/bench_mcap.py [--hours H]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from furnace_daq.logrecover import recover
from furnace_daq.mcaplog import LogWriter
from furnace_model.log.resample import resample_logs
from furnace_model.simulation.furnace import PAPER

T0 = 1_772_431_200 * 10**9
S = 10**9


def one_second(rng: np.random.Generator, i: int) -> list[tuple[str, dict]]:
    """What the daemon logs per 1 Hz poll: thermocouples, burners, ambient."""
    tc = {s: round(float(900 + 50 * np.sin(i / 3000) + rng.normal(0, 1.5)), 1)
          for s in PAPER.sensors}
    burners = {"soak": [True] * 6 + [False] * 4, "heat": [True] * 3 + [False] * 5,
               "preheat": [False] * 8, "count_soak": 6, "count_heat": 3, "count_preheat": 0,
               "source": "modbus"}
    return [("/furnace/thermocouples", tc | {"quality": dict.fromkeys(PAPER.sensors, "ok")}),
            ("/furnace/burners", burners),
            ("/furnace/ambient", {"t_air": round(float(25 + rng.normal(0, 0.2)), 2)})]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--hours", type=float, default=24.0, help="hours of 1 Hz data (default 24)")
    args = ap.parse_args()
    seconds = int(args.hours * 3600)
    rng = np.random.default_rng(0)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        w = LogWriter(d, rotate_s=3600.0, flush_interval_s=5.0)
        write_s = flush_s = 0.0
        flushes = writes = 0
        for i in range(seconds):
            for topic, msg in one_second(rng, i):
                t = time.perf_counter()
                w.write(topic, msg, T0 + i * S)
                write_s += time.perf_counter() - t
                writes += 1
            if i % 5 == 4:  # the daemon's clock: a flush every 5 s of data
                t = time.perf_counter()
                w.maybe_flush(i)
                flush_s += time.perf_counter() - t
                flushes += 1
        w.close()
        files = sorted(d.glob("*.mcap"))
        total = sum(p.stat().st_size for p in files)
        rows.append(("write one message (mean)", f"{write_s / writes * 1e6:.1f} us"))
        rows.append(("maybe_flush with chunk close + fsync (mean)", f"{flush_s / flushes * 1e3:.2f} ms"))
        rows.append(("time in the log layer per second of data at 1 Hz",
                     f"{(write_s / seconds + flush_s / seconds) * 100:.3f} %"))
        rows.append(("bytes per hour, 1 Hz, 5 s chunks, zstd", f"{total / args.hours / 1e6:.2f} MB"))
        rows.append(("files (hourly rotation)", str(len(files))))
        t = time.perf_counter()
        frame = resample_logs(files, 60.0)
        rows.append((f"export {args.hours:g} h to 60 s rows ({len(frame)} rows)",
                     f"{time.perf_counter() - t:.2f} s"))
        cut = d / "cut.mcap.part"
        data = files[0].read_bytes()
        cut.write_bytes(data[: len(data) * 2 // 3])
        t = time.perf_counter()
        r = recover(cut)
        rows.append((f"recover 1 h file cut at 2/3 ({r.messages} messages)",
                     f"{(time.perf_counter() - t) * 1e3:.0f} ms"))
    print(f"| MCAP log, {args.hours:g} h of 1 Hz data | value |\n|---|---|")
    for k, v in rows:
        print(f"| {k} | {v} |")


if __name__ == "__main__":
    main()
