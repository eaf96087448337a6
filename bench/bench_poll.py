"""Polling cost: the daemon polls the default map of `sim-plc` (a separate process, 3600x)
at 10 Hz over loopback and logs to MCAP. Reports CPU per poll, period jitter (actual tick
time against the monotonic grid) and MCAP bytes per hour of data. Prints a markdown table.

    .venv/bin/python bench/bench_poll.py [--seconds 60] [--rate 10] [--quick]
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import select
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from furnace_daq.daemon import Daemon
from furnace_daq.daqconfig import load_config
from furnace_daq.mcaplog import LogWriter
from furnace_daq.sources import ModbusSource
from furnace_model.log.read import read_messages
from furnace_model.log.schema import THERMOCOUPLES

ROOT = Path(__file__).resolve().parents[1]


def start_simplc() -> tuple[subprocess.Popen, int]:
    proc = subprocess.Popen([sys.executable, "-m", "furnace_daq.cli", "sim-plc", "--scenario",
                             str(ROOT / "config/scenarios/paper_exp1.yaml"), "--port", "0",
                             "--speed", "3600"], stdout=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 30)
    line = proc.stdout.readline() if ready else ""
    if not line.startswith("listening on "):
        proc.kill()
        raise SystemExit(f"sim-plc did not start: {line!r}")
    return proc, int(line.rsplit(":", 1)[1])


def measure(port: int, seconds: float, rate: float, log_dir: Path) -> dict:
    from dataclasses import replace
    cfg = load_config(ROOT / "config" / "gateway.yaml")
    cfg = replace(cfg, poll_period_s=1.0 / rate, refit=None,
                  plc=replace(cfg.plc, host="127.0.0.1", port=port))
    log = LogWriter(log_dir, flush_interval_s=cfg.log.flush_interval_s)
    daemon = Daemon(cfg, log, plc=ModbusSource(cfg))
    cpu0, wall0 = time.process_time(), time.perf_counter()
    counters = asyncio.run(daemon.run(seconds))
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    files = sorted(log_dir.glob("*.mcap"))
    t = np.array([lt for topic, _, lt, _ in read_messages(files) if topic == THERMOCOUPLES],
                 dtype=np.int64)
    period_ns = 1e9 / rate
    k = np.round((t - t[0]) / period_ns)
    lateness_ms = ((t - t[0]) - k * period_ns) / 1e6
    lateness_ms -= np.median(lateness_ms)
    size = sum(f.stat().st_size for f in files)
    return {"polls": counters.polls, "ok": counters.ok_polls, "skipped": counters.skipped_ticks,
            "cpu_per_poll_ms": 1e3 * cpu / counters.polls, "cpu_pct": 100 * cpu / wall,
            "jit_p50": float(np.percentile(np.abs(lateness_ms), 50)),
            "jit_p99": float(np.percentile(np.abs(lateness_ms), 99)),
            "jit_max": float(np.max(np.abs(lateness_ms))),
            "bytes_per_poll": size / max(len(t), 1), "seconds": seconds, "rate": rate}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=60.0, help="polling time (default 60)")
    ap.add_argument("--rate", type=float, default=10.0, help="polls per second (default 10)")
    ap.add_argument("--quick", action="store_true", help="5 s instead of --seconds")
    args = ap.parse_args()
    seconds = 5.0 if args.quick else args.seconds
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    sim, port = start_simplc()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            r = measure(port, seconds, args.rate, Path(tmp))
    finally:
        sim.terminate()
        sim.wait(10)
    one_hz_pct = r["cpu_per_poll_ms"] / 10.0  # ms per poll at 1 poll/s, as % of one core
    print(f"Default map (10 input registers + 26 discrete inputs, 2 requests) at {r['rate']:g} Hz "
          f"for {r['seconds']:g} s against sim-plc on loopback.\n")
    print("| metric | value |")
    print("|---|---|")
    print(f"| polls (ok / total, skipped ticks) | {r['ok']} / {r['polls']}, {r['skipped']} |")
    print(f"| CPU per poll (read, decode, 3 MCAP messages) | {r['cpu_per_poll_ms']:.2f} ms |")
    print(f"| CPU at {r['rate']:g} Hz | {r['cpu_pct']:.1f} % of one core |")
    print(f"| CPU at 1 Hz (from the per-poll cost) | {one_hz_pct:.2f} % of one core |")
    print(f"| period jitter p50 / p99 / max | {r['jit_p50']:.2f} / {r['jit_p99']:.2f} / "
          f"{r['jit_max']:.2f} ms |")
    print(f"| MCAP per hour at {r['rate']:g} Hz | "
          f"{r['bytes_per_poll'] * r['rate'] * 3600 / 2**20:.1f} MiB |")
    print(f"| MCAP per hour at 1 Hz (same bytes per poll) | "
          f"{r['bytes_per_poll'] * 3600 / 2**20:.2f} MiB |")


if __name__ == "__main__":
    main()
