"""The live view's cost to the log: one `LogWriter.write` without the live view, with it and
no client, and with it and one Foxglove client (@foxglove/ws-protocol under node, from
tests/node) subscribed to every topic. Rounds alternate the three so that the machine's other
load falls on each alike. Prints a markdown table.

    .venv/bin/python bench/bench_liveview.py [--messages N] [--rounds R]
"""

from __future__ import annotations

import argparse
import shutil
import socket
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from furnace_daq.liveview import LiveView, LiveViewConfig
from furnace_daq.mcaplog import LogWriter
from furnace_model.simulation.furnace import PAPER

ROOT = Path(__file__).resolve().parents[1]
NODE_DIR = ROOT / "tests" / "node"
T0 = 1_772_431_200 * 10**9
TC = ({s: 900.0 + i for i, s in enumerate(PAPER.sensors)}
      | {"quality": dict.fromkeys(PAPER.sensors, "ok")})


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run(case: str, n: int) -> float:
    """Mean seconds per write for one case."""
    with tempfile.TemporaryDirectory() as tmp:
        log = LogWriter(tmp, flush_interval_s=5.0)
        view = client = None
        if case != "off":
            view = LiveView(LiveViewConfig("127.0.0.1", free_port()), furnace=PAPER)
            log.listeners.append(view.send)
        if case == "client":
            client = subprocess.Popen(["node", "live_client.mjs", view.url, "60"], cwd=NODE_DIR,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            time.sleep(1.5)  # connected and subscribed
        t = time.perf_counter()
        for i in range(n):
            log.write("/furnace/thermocouples", TC, T0 + i * 10**9)
            if i % 1000 == 999:
                log.maybe_flush(i)
        dt = time.perf_counter() - t
        log.close()
        if client is not None:
            client.kill()
            client.wait()
        if view is not None:
            view.close()
    return dt / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--messages", type=int, default=20000)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    cases = ["off", "server"]
    if shutil.which("node") and (NODE_DIR / "node_modules" / "@foxglove").is_dir():
        cases.append("client")
    times: dict[str, list[float]] = {c: [] for c in cases}
    for _ in range(args.rounds):
        for c in cases:
            times[c].append(run(c, args.messages))
    names = {"off": "no live view", "server": "live view, no client",
             "client": "live view, one client subscribed to every topic"}
    print(f"| LogWriter.write, {args.messages} messages x {args.rounds} rounds | median |")
    print("|---|---|")
    for c in cases:
        print(f"| {names[c]} | {statistics.median(times[c]) * 1e6:.1f} us |")


if __name__ == "__main__":
    main()
