"""`furnace-daq config --furnace F`: a ready daemon config for a furnace description, its
default register map written out (the map `sim-plc --furnace F` serves), for an engineer to
start from and edit to the plant PLC's I/O list."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from furnace_model.cli.arguments import output_file
from furnace_model.errors import FurnaceError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("config", help="write a daemon config for a furnace description",
                       description=__doc__)
    p.add_argument("--furnace", required=True, metavar="FURNACE.yaml",
                   help="furnace description: a YAML file, or the name of a shipped one "
                        "(paper, six-zone, modulated; config/furnaces/)")
    p.add_argument("--out", type=output_file,
                   help="write the config here (default: print it)")
    p.add_argument("--port", type=int, default=5020, help="plc.port (default 5020)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from furnace_model.cli.arguments import furnace_path
    from furnace_model.simulation.furnacefile import load_furnace

    from ..gatewayconfig import gateway_yaml

    path = furnace_path(args.furnace)
    furnace = load_furnace(path)
    if not 1 <= args.port <= 65535:
        raise FurnaceError(f"--port must be 1-65535, got {args.port}")
    if not Path(args.furnace).is_file():
        ref = args.furnace  # a shipped description: its name finds it wherever the config is
    else:  # the config finds its furnace relative to its own directory
        base = args.out.resolve().parent if args.out is not None else Path.cwd()
        ref = Path(os.path.relpath(path.resolve(), base)).as_posix()
    text = gateway_yaml(furnace, ref, port=args.port)
    if args.out is None:
        print(text, end="")
        return 0
    try:
        args.out.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise FurnaceError(f"{args.out}: cannot write: {exc.strerror or exc}") from None
    print(f"wrote {args.out}: the default map of furnace '{furnace.name}'")
    return 0
