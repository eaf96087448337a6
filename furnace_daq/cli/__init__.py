"""`furnace-daq`: thin front end over the library. Each subcommand lives in its own module
and registers itself through `register(subparsers)`, loading the library only inside its
`run()` so that `--help` answers without numpy, pandas or scipy. Errors the user can fix print
one line and exit non-zero, never a traceback."""

from __future__ import annotations

import argparse
import importlib
import sys

from furnace_model.cli.arguments import CommandParser, add_version
from furnace_model.errors import FurnaceError

COMMANDS: tuple[str, ...] = ("simplc", "run", "check", "config", "logs", "replay", "fleet")
"""Subcommand modules of this package, in the order `--help` lists them."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="furnace-daq",
        description="Furnace data acquisition: simulated PLC, polling daemon, MCAP logs.")
    add_version(parser)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=CommandParser)
    for name in COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except FurnaceError as exc:
        print(f"furnace-daq {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"furnace-daq {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
