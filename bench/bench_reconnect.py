"""Time from a restarted PLC accepting connections to the daemon's first good sample, with
the redial schedule of `config/gateway.yaml` as shipped (poll every 1 s, timeout 1 s).

The simulated PLC is stopped for a given time and started again on the same port (it then
refuses, as a PLC whose Modbus server is down does); the daemon runs in-process. Run it from
a tree to measure that tree's schedule:

    PYTHONPATH=. .venv/bin/python bench/bench_reconnect.py [--down 1 2 4 8 15]

Prints one row per outage and the maximum; docs/reliability.md ("Reconnect") holds a run.
"""

from __future__ import annotations

import argparse
import asyncio
import io
import logging
import random
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from daq_processes import free_port, messages, sim, start_daemon  # noqa: E402

from furnace_daq.daqconfig import parse_config  # noqa: E402
from furnace_model.config import Node  # noqa: E402
from furnace_model.log.schema import THERMOCOUPLES  # noqa: E402


def shipped(port: int):
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["refit"]["enabled"] = False
    doc["plc"].update(host="127.0.0.1", port=port)
    return parse_config(Node(doc, "gateway.yaml"))


async def one(down_s: float, log_dir: Path) -> tuple[float, int]:
    """(seconds from accepting to the first good sample, dials while down)."""
    cfg = shipped(free_port())
    plc = await sim(cfg.plc.port)
    kw = {}
    try:  # a tree with the journal: keep its lines off the table
        from furnace_daq.journal import Journal
        kw["journal"] = Journal(stream=io.StringIO())
    except ImportError:
        pass
    daemon, task = start_daemon(cfg, log_dir, 3.0 + down_s + 40.0, **kw)
    await asyncio.sleep(2.0)
    await plc.stop()
    before = daemon.counters.connect_attempts
    await asyncio.sleep(down_s)
    plc = await sim(cfg.plc.port)
    accepting_ns = time.time_ns()
    dials = daemon.counters.connect_attempts - before
    while daemon.counters.connects < 2 or daemon.counters.ok_polls == 0:
        await asyncio.sleep(0.05)
    await asyncio.sleep(1.5)  # a good poll after the reconnect is logged by now
    daemon.stop()
    await task
    await plc.stop()
    first = min(lt for t, m, lt in messages(log_dir) if t == THERMOCOUPLES and lt > accepting_ns
                and all(q == "ok" for q in m["quality"].values()))
    return (first - accepting_ns) / 1e9, dials


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--down", type=float, nargs="+", default=[1, 2, 3, 4, 6, 8, 11, 15],
                    help="outage lengths in seconds, each plus a random 0-1 s (default "
                         "1 2 3 4 6 8 11 15)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    rng = random.Random(args.seed)
    cfg = shipped(1)
    print(f"reconnect {cfg.plc.reconnect}, poll {cfg.poll_period_s:g} s, "
          f"timeout {cfg.plc.timeout_s:g} s")
    print("| PLC down | dials while down | accepting -> first good sample |")
    print("|---|---|---|")
    worst = 0.0
    for down in args.down:
        down += rng.uniform(0.0, 1.0)  # no luck of phase between outage and redials
        with tempfile.TemporaryDirectory() as tmp:
            delay, dials = asyncio.run(one(down, Path(tmp)))
        worst = max(worst, delay)
        print(f"| {down:.2f} s | {dials} | {delay:.2f} s |", flush=True)
    print(f"max {worst:.2f} s")


if __name__ == "__main__":
    main()
