"""`furnace-daq replay`: recorded MCAP logs through the daemon's online refit pipeline.

The same windows (cut on the PLC clock), the same warm-started fits and drift checks as the
live daemon with the same `refit:` settings; the /model/parameters and /model/events topics
go to one MCAP file and one line per refit is printed."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from furnace_model.cli.arguments import output_file
from furnace_model.log.messages import ModelDiagnosis, ModelEvent, ModelParameters


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="run recorded logs through the online refit",
                       description=__doc__)
    p.add_argument("files", nargs="+", type=Path, metavar="LOG",
                   help="MCAP logs (finished .mcap or a dead writer's .mcap.part), any order")
    p.add_argument("--out", type=output_file,
                   help="output MCAP of the /model topics (default: next to the first log, "
                        "<name>.model.mcap)")
    pace = p.add_mutually_exclusive_group()
    pace.add_argument("--speed", type=float, metavar="X",
                      help="replay X data seconds per wall second")
    pace.add_argument("--fast", action="store_true", help="as fast as possible (the default)")
    p.add_argument("--config", type=Path,
                   help="daemon YAML whose refit: section to use (default: the settings "
                        "recorded in the log's metadata, else the built-in refit defaults)")
    p.set_defaults(run=run)


def summary(message: ModelParameters) -> str:
    """One line per refit: window end, status, the parameters (a..f for the paper's
    furnace), RMSE per zone (or the reason)."""
    head = f"{message.window_end}  {message.status:<23}"
    if not message.fitted:
        return f"{head} {message.detail}"
    params = " ".join(f"{p}={v:.5g}" for p, v in message.params.items())
    rmse = "/".join(f"{v:.2f}" for v in (message.rmse_c or {}).values())
    return f"{head} {params}  rmse {rmse} °C  ({message.elapsed_s or 0:.2f} s)"


def run(args: argparse.Namespace) -> int:
    from ..daqconfig import load_config
    from ..replay import default_out, replay

    config = load_config(args.config) if args.config else None
    if config is not None and config.refit is None:
        print(f"furnace-daq replay: {args.config} has no refit: section (or it is disabled); "
              "using the refit defaults", file=sys.stderr)
    out = args.out or default_out(args.files)

    def echo(topic: str, message: ModelParameters | ModelEvent | ModelDiagnosis) -> None:
        if isinstance(message, ModelParameters):
            print(summary(message), flush=True)
        elif isinstance(message, ModelEvent):  # a diagnosis is told by its event
            print(f"  EVENT {message.kind}: {message.detail}", flush=True)

    t0 = time.perf_counter()
    msgs = replay(args.files, config, out, speed=args.speed, echo=echo)
    if config is None:
        from ..replay import settings

        source = settings(list(args.files), None)[2]
        print("refit settings: " + ("as recorded in the log" if source == "log" else
                                    "the defaults (the log records none)"), file=sys.stderr)
    ok = sum(m.fitted for m in msgs)
    print(f"{len(msgs)} refits ({ok} ok) in {time.perf_counter() - t0:.1f} s -> {out}",
          file=sys.stderr)
    return 0
