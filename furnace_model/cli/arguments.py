"""Argument pieces both command lines share. They stay light (no numpy, pandas or scipy), so
that `--help`, `--version` and a mistyped argument answer at once, and an output path that
cannot be written is refused when the arguments are read, not after the work it would hold."""

from __future__ import annotations

import argparse
import math
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..experiment import Experiment
    from ..simulation.furnace import Furnace

DISTRIBUTION = "furnace-daq"
"""The installed distribution both commands belong to (pyproject.toml's project name)."""


def version() -> str:
    """The installed version; from a source tree that was never installed, pyproject.toml's
    version marked as such."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed

    try:
        return installed(DISTRIBUTION)
    except PackageNotFoundError:
        import tomllib

        try:
            pyproject = Path(__file__).resolve().parents[2] / "pyproject.toml"
            return f"{tomllib.loads(pyproject.read_text())['project']['version']} (not installed)"
        except (OSError, KeyError, tomllib.TOMLDecodeError):
            return "unknown (not installed)"


class CommandParser(argparse.ArgumentParser):
    """A command's parser on which files may follow options: `diagnose a.csv --holdout b.csv
    c.csv` fits c.csv. argparse takes a command's positional files in one run, so the plain
    parser refuses c.csv; its intermixed parsing (options first, then the files left over)
    does not, but cannot parse a level that has subcommands, which keeps the plain one.

    It also checks the time windows its command declares (`add_window`) once every option
    is read: a window given backwards is an argument error, answered before any data is."""

    _intermixed = False

    def parse_known_args(self, args=None, namespace=None):
        if self._intermixed or any(a.nargs == argparse.PARSER for a in self._actions):
            return super().parse_known_args(args, namespace)
        self._intermixed = True  # parse_known_intermixed_args calls back here, twice
        try:
            namespace, extras = self.parse_known_intermixed_args(args, namespace)
        finally:
            self._intermixed = False
        for window in getattr(self, "_windows", ()):
            message = window.backwards(namespace)
            if message:
                self.error(message)
        return namespace, extras

    def add_window(self, start: str, end: str, start_option: str, end_option: str) -> None:
        """Declare two options as a window's start and end: `start` must come before `end`
        (dests; values are datetimes or ISO 8601 texts)."""
        self._windows = (*getattr(self, "_windows", ()),
                         TimeWindow(start, end, start_option, end_option))


class TimeWindow:
    """Two options bounding a window of time, as a command line gives them."""

    def __init__(self, start: str, end: str, start_option: str, end_option: str):
        self.start, self.end = start, end
        self.start_option, self.end_option = start_option, end_option

    def backwards(self, args: argparse.Namespace) -> str:
        """The argument error of a window whose start is not before its end; empty when it
        is, when either is missing, or when a text is not a time (the command's own reading
        of it says so)."""
        a, b = (_when(getattr(args, dest, None)) for dest in (self.start, self.end))
        if a is None or b is None or a < b:
            return ""
        return (f"argument {self.end_option}: {self.end_option} {b.isoformat()} is not later "
                f"than {self.start_option} {a.isoformat()}: the window would be empty "
                f"(give {self.start_option} before {self.end_option})")


def _when(value: object) -> datetime | None:
    """A window bound as a datetime with its time zone; None for none, or for a text that is
    not an ISO 8601 time with an offset."""
    if isinstance(value, datetime):
        return value if value.tzinfo is not None else None
    if isinstance(value, str):
        try:
            return plc_time(value)
        except argparse.ArgumentTypeError:
            return None
    return None


class _Version(argparse.Action):
    """argparse's own version action needs the text when the parser is built; looking it up
    loads importlib.metadata and scans the installed distributions, which --help has no use
    for, so it is looked up only when asked for."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS, **kwargs):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS,
                         help="print the installed version and exit")

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog} {version()}")
        parser.exit()


def add_version(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--version", action=_Version)


def positive_int(text: str) -> int:
    """A whole number of at least 1 (runs, generations, a horizon in samples)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: '{text}'") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {v}")
    return v


def output_file(text: str) -> Path:
    """argparse type of an output file: its directory must exist and the path must not be
    one. A missing directory is a typo far more often than a wish, so it is refused, never
    created."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is a directory; give a file name in it")
    if not path.parent.is_dir():
        what = "not a directory" if path.parent.exists() else "no such directory"
        raise argparse.ArgumentTypeError(f"{what}: {path.parent} (for {path})")
    return path


def output_dir(text: str) -> Path:
    """argparse type of a directory to fill: created (with its parents) when written to, as
    one expects of a directory named for output, but refused at once if it is a file."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{path} exists and is not a directory")
    return path


def add_furnace(parser: argparse.ArgumentParser) -> None:
    """--furnace: the furnace description the command works on (a file or a shipped name)."""
    parser.add_argument("--furnace", metavar="FURNACE.yaml",
                        help="furnace description (zones, links, burners, thermocouples): a "
                             "YAML file, or the name of a shipped one (six-zone, modulated; "
                             "config/furnaces/); default the paper's three-zone furnace")


def furnace_path(text: str) -> Path:
    """The description file --furnace names (`furnace_file`), or a ConfigError saying it is
    neither a file nor a shipped description's name."""
    from ..errors import ConfigError
    from ..simulation.furnacefile import furnace_file, shipped_furnaces

    path = furnace_file(text)
    if path is None:
        raise ConfigError(text, "", "file not found, nor a shipped description's name "
                                    f"({shipped_furnaces()})")
    return path


def furnace_of(args: argparse.Namespace):
    """The furnace --furnace names, checked; the paper's when none is named."""
    from ..simulation.furnace import PAPER
    from ..simulation.furnacefile import load_furnace

    text = getattr(args, "furnace", None)
    return PAPER if text is None else load_furnace(furnace_path(str(text)))


def scenario_path(text: str) -> Path:
    """The scenario --scenario names: a file, or the name of a shipped scenario
    (`paper_exp1`, config/scenarios/); else a ConfigError listing the shipped names."""
    from ..errors import ConfigError
    from ..shipped import SCENARIOS, shipped_named, shipped_names

    path = Path(text)
    if path.is_file():
        return path
    named = shipped_named(SCENARIOS, text)
    if named is not None:
        return named
    raise ConfigError(text, "", "file not found, nor a shipped scenario's name "
                                f"({', '.join(shipped_names(SCENARIOS))})")


def add_effects_from(parser: argparse.ArgumentParser) -> None:
    """--effects-from, read before the rest of the command line (`preload_effects`), so that
    the effects it defines are names like ours in every other argument."""
    parser.add_argument("--effects-from", action="append", type=Path, metavar="PATH.py",
                        help="load effects written as Python classes in this file (repeatable); "
                             "installed packages' effects load by themselves")


def preload_effects(argv: list[str]) -> None:
    """Load the plug-in files of --effects-from; a broken one is a PluginError naming it."""
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    pre.add_argument("--effects-from", action="append", default=[])
    files = pre.parse_known_args(argv)[0].effects_from
    if not files:
        return
    from ..effects.plugins import load_file
    from .names import sync_plugins

    for path in files:
        load_file(path)
    sync_plugins()


LOG_PERIOD_S = 60.0
"""Default resampling period of logs in seconds (`log.resample.DEFAULT_PERIOD_S`, which the
parsers cannot import without pandas)."""

DATA_HELP = "CSV or Parquet files, MCAP logs (.mcap, .mcap.part) or log directories"
"""What a data argument may name (docs/logs.md: one record per file or log directory)."""


def plc_time(text: str) -> datetime:
    """argparse type of --from/--to: ISO 8601 with Z or an offset; a time without one is
    refused, not guessed (the PLC clock is UTC in the logs)."""
    try:
        when = datetime.fromisoformat(text.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an ISO 8601 time: '{text}'") from None
    if when.tzinfo is None:
        raise argparse.ArgumentTypeError(f"'{text}' has no UTC offset or Z (time zone unknown)")
    return when


def positive_seconds(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: '{text}'") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return v


def add_data_window(parser: argparse.ArgumentParser) -> None:
    """--from/--to (a window of the PLC clock, on logs and timestamped tables alike) and
    --period (how logs are resampled), for every command that reads heat-up data."""
    g = parser.add_argument_group(
        "time window and logs",
        "MCAP logs are resampled as `furnace-daq logs export` does; a log directory, or log "
        "files in one directory, make one record (docs/logs.md)")
    g.add_argument("--from", dest="window_from", type=plc_time, metavar="TIME",
                   help="read from this time on, ISO 8601 with Z or an offset, on the PLC "
                        "clock (a log's publish time, a table's timestamp)")
    g.add_argument("--to", dest="window_to", type=plc_time, metavar="TIME",
                   help="read up to this time (exclusive), as --from")
    g.add_argument("--period", type=positive_seconds, metavar="S",
                   help=f"resampling period of MCAP logs in seconds (default {LOG_PERIOD_S:g}, as "
                        "`logs export`)")
    if isinstance(parser, CommandParser):
        parser.add_window("window_from", "window_to", "--from", "--to")


def data_window(args: argparse.Namespace) -> dict:
    """The keyword arguments of `records.load_experiments` that add_data_window's options
    give; --from must come before --to (the command line refuses it first, `CommandParser`;
    this holds for arguments built in code)."""
    import pandas as pd

    from ..errors import FurnaceError

    start, end = (None if v is None else pd.Timestamp(v).tz_convert("UTC")
                  for v in (args.window_from, args.window_to))
    if start is not None and end is not None and start >= end:
        raise FurnaceError(f"--from {start.isoformat()} is not before --to {end.isoformat()}")
    return {"start": start, "end": end, "period_s": args.period}


def read_data(paths: list[str], args: argparse.Namespace, furnace: Furnace,
              command: str) -> tuple[list[Experiment], list[str]]:
    """The records `paths` name within the data window, as `records.read_records` reads
    them, and its warnings (what reading left out or split), said on stderr as `command`'s
    and returned for the command's JSON."""
    import sys

    from ..records import read_records

    records, words = read_records(paths, **data_window(args), furnace=furnace)
    for w in words:
        print(f"{command}: warning: {w}", file=sys.stderr)
    return records, words
