"""MCAP logs read as heat-up records (Experiments), through the resampling `furnace-daq logs
export` uses, so that `fit LOGS` and `fit` on the export of LOGS see the same rows.

What makes one record. A log directory is one furnace's history: its files (finished
`.mcap`, a dead or live writer's `.mcap.part`, `logs recover`'s `.recovered.mcap`) are joined
in time order into one record, as `logs export` joins the files it is given. Log files named
on a command line join the same way when they lie in one directory, with that directory's
files named through it; logs in different directories are different records. A gap in the
log (the daemon stopped) stays a gap: no rows (`Experiment.outages`), and the commands take
the parts on either side as records of their own (`furnace_model.records.between_outages`).

Left out of a directory: a `.mcap.part` whose writer died before writing anything (empty, or
cut inside the MCAP header), and a `.mcap.part` whose `.recovered.mcap` copy sits beside it
(the copy holds the same messages; reading both would count them twice). A file named on the
command line is always read, and refused with its name when it holds no log.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path

import pandas as pd

from ..errors import DataError
from ..experiment import DEFAULT_T_AIR_C, Experiment, experiment_from_frame
from ..simulation.furnace import Furnace
from .read import LOG_SUFFIX, PART_SUFFIX, log_furnace
from .resample import DEFAULT_PERIOD_S, resample_logs
from .salvage import MAGIC

RECOVERED_SUFFIX = ".recovered" + LOG_SUFFIX
_HEADER_OPCODE = 0x01


def is_log(path: str | Path) -> bool:
    """Whether a data argument names a log: a directory, or a `.mcap` / `.mcap.part` file."""
    path = Path(path)
    name = path.name.lower()
    return path.is_dir() or name.endswith((LOG_SUFFIX, LOG_SUFFIX + PART_SUFFIX))


def log_files(directory: str | Path) -> list[Path]:
    """The log files of a directory worth reading (see the module docstring), by name."""
    directory = Path(directory)
    try:
        entries = sorted(p for p in directory.iterdir() if p.is_file())
    except OSError as exc:
        raise DataError(str(directory), f"cannot list: {exc.strerror or exc}") from None
    names = {p.name for p in entries}
    found = []
    for p in entries:
        if p.name.startswith("."):
            continue
        if p.name.endswith(LOG_SUFFIX):
            found.append(p)
        elif p.name.endswith(LOG_SUFFIX + PART_SUFFIX):
            base = p.name[: -len(LOG_SUFFIX + PART_SUFFIX)]
            if base + RECOVERED_SUFFIX not in names and not _nothing_written(p):
                found.append(p)
    if not found:
        raise DataError(str(directory), f"no MCAP log in this directory (*{LOG_SUFFIX}, "
                                        f"*{LOG_SUFFIX}{PART_SUFFIX})")
    return found


def _nothing_written(path: Path) -> bool:
    """An empty file, or one cut inside its MCAP header: what a writer that died at once
    leaves. A file that is not MCAP at all is not this; reading it says so."""
    try:
        with path.open("rb") as f:
            head = f.read(len(MAGIC) + 9)
            size = path.stat().st_size
    except OSError:
        return False  # reading it names the fault
    if len(head) < len(MAGIC):
        return MAGIC.startswith(head)
    if head[: len(MAGIC)] != MAGIC:
        return False
    if len(head) < len(MAGIC) + 9:
        return True
    opcode, length = struct.unpack_from("<BQ", head, len(MAGIC))
    return opcode == _HEADER_OPCODE and size < len(MAGIC) + 9 + length


def group_logs(paths: Iterable[str | Path]) -> list[tuple[int, str, list[Path]]]:
    """The records that log arguments make, as (the position of the first argument naming
    it, what errors and the JSON call it, its files), in that order; see the module
    docstring."""
    groups: dict[Path, tuple[int, list[str], list[Path]]] = {}
    for i, arg in enumerate(paths):
        path = Path(arg)
        if path.is_dir():
            key, files = path.resolve(), log_files(path)
        else:
            key, files = path.parent.resolve(), [path]
        _, labels, have = groups.setdefault(key, (i, [], []))
        labels.append(str(path))
        seen = {p.resolve() for p in have}
        have.extend(p for p in files if p.resolve() not in seen)
    out = []
    for first, labels, files in groups.values():
        lone_file = len(labels) == 1 and not Path(labels[0]).is_dir()
        out.append((first, labels[0] if lone_file else _directory_label(labels), files))
    return out


def _directory_label(labels: list[str]) -> str:
    for label in labels:
        if Path(label).is_dir():
            return label
    return str(Path(labels[0]).parent)


def record_name(label: str) -> str:
    """A record's name in tables and plots: the directory's, or the file's without its
    log suffixes."""
    path = Path(label)
    if path.is_dir():
        return path.resolve().name
    name = path.name
    for suffix in (PART_SUFFIX, LOG_SUFFIX):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
    return name


def load_log(label: str, files: list[Path], t_air_default: float = DEFAULT_T_AIR_C,
             start: pd.Timestamp | None = None, end: pd.Timestamp | None = None,
             period_s: float = DEFAULT_PERIOD_S, furnace: Furnace | None = None) -> Experiment:
    """One record from log files, resampled as `logs export` does, with the rows whose bins
    start in [start, end) on the PLC clock. The furnace is the one the log records; when
    `furnace` is given (the command's --furnace) the log must be of it."""
    own = log_furnace(files, label)
    if furnace is not None and own != furnace:
        raise DataError(label, f"the log is of furnace '{own.name}' (its metadata record), "
                               f"not of furnace '{furnace.name}': give --furnace with the "
                               "log's description")
    frame = resample_logs(files, period_s, start, end, name=label, furnace=own)
    exp = experiment_from_frame(frame, label, t_air_default, row_offset=1,
                                row_label="resampled row", furnace=own)
    return replace(exp, name=record_name(label))
