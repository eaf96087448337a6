"""`furnace-daq check`: dial the PLC (and the CAN bus, if configured), read every point of the
config's map once and print what came back: key path, table and address, raw registers,
decoded value, quality, error. Exit 0 when every point is ok, 1 when anything failed
(unreachable, refused block, sentinel or out-of-range value), 2 for a bad config."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("check", help="read every configured point once and report (commissioning)",
                       description=__doc__)
    p.add_argument("--config", required=True, type=Path, help="daemon YAML (config/gateway.yaml)")
    p.add_argument("--plc", metavar="HOST:PORT", help="PLC address, overrides plc.host/port")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import asyncio
    import logging

    from ..check import check, format_report
    from ..daqconfig import load_config
    from ..journal import ERR, Journal
    from .run import _plc_address

    config = load_config(args.config)
    if args.plc:
        host, port = _plc_address(args.plc)
        config = replace(config, plc=replace(config.plc, host=host, port=port))
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # the table says it all
    report = asyncio.run(check(config))
    print(format_report(report), flush=True)
    failed = report.failed
    if failed:
        # with an sd-daemon priority, as the daemon's lines: run from a unit (ExecStartPre=),
        # `journalctl -p err` finds it
        by_error: dict[str, list[str]] = {}
        for p in failed:
            by_error.setdefault(p.error or p.quality, []).append(p.key)
        why = "; ".join(f"{', '.join(keys)}: {error}" for error, keys in by_error.items())
        Journal(stream=sys.stderr).say(
            ERR, f"furnace-daq check: error: {len(failed)} of {len(report.points)} points "
                 f"failed: {why}")
        return 1
    print(f"all {len(report.points)} points ok ({report.elapsed_s:.2f} s)")
    return 0
