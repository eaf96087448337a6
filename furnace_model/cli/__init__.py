"""`furnace-model`: thin front end over the library. Each subcommand lives in its own module
and registers itself through `register(subparsers)`, loading the library only inside its
`run()` so that `--help` answers without numpy, pandas or scipy. Errors the user can fix print
one line and exit non-zero, never a traceback."""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings

from ..errors import DataWarning, FurnaceError
from .arguments import CommandParser, add_version, preload_effects
from .names import sync_plugins

COMMANDS = ("simulate", "fit", "validate", "diagnose", "selfcheck")
"""Subcommand modules of this package, in the order `--help` lists them."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="furnace-model",
        description="Three-zone reheating-furnace model: simulate, identify, diagnose.")
    add_version(parser)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=CommandParser)
    for name in COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        preload_effects(argv)
    except FurnaceError as exc:
        print(f"furnace-model: error: {exc}", file=sys.stderr)
        return exc.exit_code
    args = build_parser().parse_args(argv)
    show = warnings.showwarning

    def say(message, category, *rest) -> None:
        if issubclass(category, DataWarning):
            print(f"furnace-model {args.command}: warning: {message}", file=sys.stderr)
        else:
            show(message, category, *rest)

    try:
        warnings.showwarning = say
        sync_plugins(installed=True)
        return int(args.run(args) or 0)
    except FurnaceError as exc:
        print(f"furnace-model {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"furnace-model {args.command}: interrupted", file=sys.stderr)
        return 130
    finally:
        warnings.showwarning = show


if __name__ == "__main__":
    sys.exit(main())
