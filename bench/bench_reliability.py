"""Reliability figures, measured on the real processes over loopback: the loss per SIGKILL
of the daemon (against what the PLC served), SIGTERM, the time back to good data after each
kind of wire fault, and a soak's memory and descriptors. Rewrites the table between the
markers in docs/reliability.md (--no-write: print only).

    .venv/bin/python bench/bench_reliability.py [--kills 20] [--soak-min 120] [--quick]
"""

from __future__ import annotations

import argparse
import signal
import statistics
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the harnesses the tests use, so both measure alike

from crash_runs import (  # noqa: E402
    FLUSH_S,
    PERIOD_S,
    ServedReads,
    daemon_config,
    good_readings,
    kill_runs,
    max_loss_polls,
    wait_polling,
)
from daq_processes import furnace_daq, start_simplc, stop  # noqa: E402
from faultproxy import ThreadedFaultProxy  # noqa: E402
from soak_run import BACK_WITHIN_S, soak  # noqa: E402

from furnace_model.log.salvage import has_footer  # noqa: E402

DOC = ROOT / "docs" / "reliability.md"
START, END = "<!-- reliability-table:start -->", "<!-- reliability-table:end -->"


def crash_series(kills: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        logs = tmp / "logs"
        logs.mkdir()
        config = daemon_config(tmp)
        sim, port = start_simplc("--speed", "600", "--scan-s", "0.05")
        try:
            with ThreadedFaultProxy(port) as proxy:
                served = ServedReads(proxy)
                t0 = time.monotonic()
                runs = kill_runs(logs, proxy, served, config, kills, seed=2026)
                # a last start recovers the last kill's file
                daq = furnace_daq("run", "--config", str(config), "--plc",
                                  f"127.0.0.1:{proxy.port}", "--log-dir", str(logs),
                                  "--duration", "0.5")
                daq.communicate(timeout=60)
                elapsed = time.monotonic() - t0
                served.take()
        finally:
            stop(sim)
        files = sorted(logs.glob("*.mcap"))
        whole = all(has_footer(f) for f in files) and not list(logs.glob("*.part"))
    lost = [k.lost for k in runs]
    return {"kills": kills, "lost_max": max(lost), "lost_mean": statistics.mean(lost),
            "served": sum(k.served for k in runs), "bound": max_loss_polls(), "whole": whole,
            "files": len(files), "s": elapsed}


def sigterm_run() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        sim, port = start_simplc("--speed", "600", "--scan-s", "0.05")
        try:
            with ThreadedFaultProxy(port) as proxy:
                daq = furnace_daq("run", "--config", str(daemon_config(tmp)), "--plc",
                                  f"127.0.0.1:{proxy.port}", "--log-dir", str(tmp / "logs"))
                wait_polling(daq)
                time.sleep(3.0)
                daq.send_signal(signal.SIGTERM)
                daq.communicate(timeout=30)
                time.sleep(0.05)
                served = ServedReads(proxy).take()
        finally:
            stop(sim)
        files = list((tmp / "logs").glob("*mcap*"))
        logged = good_readings(files)
        ok = len(files) == 1 and files[0].suffix == ".mcap" and has_footer(files[0])
    return {"served": served, "logged": logged, "closed": ok, "exit": daq.returncode}


def table(crash: dict, term: dict, s, soak_min: float) -> str:
    back = defaultdict(list)
    for f in s.faults:
        back[f.mode].append(f.back_s if f.back_s is not None else float("inf"))
    rows = [
        "| what | promise | measured |",
        "|---|---|---|",
        f"| SIGKILL at random moments ({crash['kills']} kills, {crash['served']} polls served, "
        f"poll {PERIOD_S:g} s, flush {FLUSH_S:g} s) | at most {crash['bound']} polls "
        f"(one flush interval + 2) lost per kill | max {crash['lost_max']}, mean "
        f"{crash['lost_mean']:.1f} polls ({crash['lost_max'] * PERIOD_S:.2f} s) |",
        f"| files after the kills, recovered at the next start | every file opens with a footer "
        f"| {crash['files']} files, {'all whole' if crash['whole'] else 'NOT ALL WHOLE'} |",
        f"| SIGTERM | file closed (footer, no `.part`), nothing lost | "
        f"{'closed' if term['closed'] else 'NOT CLOSED'}, {term['logged']} of "
        f"{term['served']} served polls logged, exit {term['exit']} |",
    ]
    for mode, times in sorted(back.items()):
        rows.append(f"| back to good data after `{mode}` ({len(times)}x, 0.6 s each) | within "
                    f"2 x backoff cap + timeout + period = {BACK_WITHIN_S:.2g} s | max {max(times):.2f} s, "
                    f"median {statistics.median(times):.2f} s |")
    rows += [
        f"| soak: {soak_min:g} simulated minutes at {s.speed:g}x ({s.wall_s:.0f} s), refits on, "
        f"{len(s.faults)} faults | RSS growth after warm-up under 5% | {s.rss_growth():+.1%} "
        f"({s.rss_kib[-1][1] / 1024:.0f} MiB) |",
        f"| soak: open descriptors | no growth | {s.fd_growth():+d} |",
        f"| soak: polls answered within the timeout | every one logged | {s.logged_ok} logged "
        f"of {s.answered} answered, {len(s.missing)} missing |",
        f"| soak: online refits | keep running under faults | "
        f"{', '.join(f'{n} {k}' for k, n in sorted(s.refits.items())) or 'none'} |",
    ]
    return "\n".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=20)
    ap.add_argument("--soak-min", type=float, default=120.0, help="simulated minutes")
    ap.add_argument("--speed", type=float, default=120.0)
    ap.add_argument("--quick", action="store_true", help="8 kills, a 30-minute soak")
    ap.add_argument("--no-write", action="store_true", help="print, leave the doc alone")
    args = ap.parse_args()
    if args.quick:
        args.kills, args.soak_min = 8, 30.0
    t0 = time.monotonic()
    crash = crash_series(args.kills)
    print(f"crash: {crash}", file=sys.stderr, flush=True)
    term = sigterm_run()
    print(f"sigterm: {term}", file=sys.stderr, flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        s = soak(Path(tmp), args.soak_min, args.speed, fault_every_sim_min=4.0)
    print(f"soak: rss {s.rss_growth():+.2%}, fds {s.fd_growth():+d}, {len(s.faults)} faults",
          file=sys.stderr, flush=True)
    text = table(crash, term, s, args.soak_min)
    text += (f"\n\nMeasured by `bench/bench_reliability.py` in {time.monotonic() - t0:.0f} s "
             f"on {time.strftime('%Y-%m-%d', time.gmtime())}.")
    print(text)
    if not args.no_write and not args.quick:
        doc = DOC.read_text()
        if START not in doc or END not in doc:
            print(f"{DOC}: markers {START} / {END} not found", file=sys.stderr)
            return 1
        head, rest = doc.split(START, 1)
        _, tail = rest.split(END, 1)
        DOC.write_text(f"{head}{START}\n{text}\n{END}{tail}")
        print(f"table written to {DOC}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
