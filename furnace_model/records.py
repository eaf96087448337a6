"""The records a command names, whatever their kind: each CSV or Parquet file of the tabular
contract is one (`furnace_model.experiment`), MCAP logs one per directory
(`furnace_model.log.experiment`); and a record's parts between its outages, which the
commands take as records of their own (`between_outages`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from pathlib import Path

import pandas as pd

from .errors import FurnaceError
from .experiment import DEFAULT_T_AIR_C, OUTAGE_PERIODS, Experiment, gap_words, read_table
from .log.experiment import group_logs, is_log, load_log
from .log.resample import DEFAULT_PERIOD_S
from .simulation.furnace import Furnace


def load_experiments(paths: Iterable[str | Path], t_air_default: float = DEFAULT_T_AIR_C, *,
                     start: pd.Timestamp | None = None, end: pd.Timestamp | None = None,
                     period_s: float | None = None, furnace: Furnace) -> list[Experiment]:
    """The records the data arguments of `fit`, `validate` and `diagnose` make, in their
    order: each CSV or Parquet file is one; MCAP logs are resampled as `logs export` does and
    make one per directory (`furnace_model.log.experiment`). `start`/`end` keep [start, end) of the PLC
    clock; `period_s` is the logs' resampling period (default that of `logs export`).
    `furnace`: the description the tables' columns, and the furnace a log records in its
    metadata, must match."""
    paths = [Path(p) for p in paths]
    logs = [i for i, p in enumerate(paths) if is_log(p)]
    groups = {logs[first]: (label, files)
              for first, label, files in group_logs(paths[i] for i in logs)}
    out = []
    for i, path in enumerate(paths):
        if i in groups:
            label, files = groups[i]
            out.append(load_log(label, files, t_air_default, start, end,
                                DEFAULT_PERIOD_S if period_s is None else period_s, furnace))
        elif i not in logs:
            out.append(read_table(path, t_air_default, start=start, end=end, furnace=furnace))
    return out


def load_experiment(path: str | Path, t_air_default: float = DEFAULT_T_AIR_C, *,
                    start: pd.Timestamp | None = None, end: pd.Timestamp | None = None,
                    period_s: float | None = None, furnace: Furnace) -> Experiment:
    """Read and check one file of the tabular contract, or one log file or log directory
    (`load_experiments` says how), against the furnace's columns."""
    if is_log(Path(path)):
        return load_experiments([path], t_air_default, start=start, end=end,
                                period_s=period_s, furnace=furnace)[0]
    return read_table(path, t_air_default, start=start, end=end, furnace=furnace)


MIN_PART_ROWS = 10
"""Rows a part between outages needs to be kept: fewer determine little beyond the part's
own start and offsets."""
MIN_PART_SHARE = 0.1
"""...and this share of the longest part's rows: a diagnosis of one record holds out a
whole part, and twenty rows before a short outage must not become the fitted record of
a month held out."""


def between_outages(exp: Experiment) -> tuple[list[Experiment], list[str]]:
    """exp's parts between its outages (`Experiment.outages`), each a record of its own
    (named exp's name, `-1`, `-2`, ...), and a warning that says so; exp itself where it has
    none. Across an outage the inputs are unknown: a model that held the last row's across
    it (a fit of the record whole) would carry a wrong state into the next part and be
    judged on it, where each part from its own start is fitted to what was measured, as
    the daemon's refit fits a window from the first reading after an outage. Parts of
    fewer than `MIN_PART_ROWS` rows, or `MIN_PART_SHARE` of the longest part's, are left
    out and named."""
    spans = exp.outages()
    if not spans:
        return [exp], []
    starts = [float(exp.t_min[0])] + [hi for _, hi in spans]
    ends = [lo for lo, _ in spans] + [float(exp.t_min[-1])]
    parts = [exp.rows((exp.t_min >= a) & (exp.t_min <= b)) for a, b in zip(starts, ends,
                                                                            strict=True)]
    least = max(MIN_PART_ROWS, MIN_PART_SHARE * max(len(p) for p in parts))
    kept = [dataclasses.replace(p, name=f"{exp.name}-{k + 1}")
            for k, p in enumerate(q for q in parts if len(q) >= least)]
    left = [(a, len(p)) for a, p in zip(starts, parts, strict=True) if len(p) < least]
    if not kept:
        raise FurnaceError(f"{exp.source or exp.name}: no part between its outages (rows more "
                           f"than {OUTAGE_PERIODS:g} times its usual row spacing apart) has "
                           f"{MIN_PART_ROWS} rows to fit")

    words = (f"{exp.name}: no rows for {gap_words(exp, spans)}: "
             "the inputs there are unknown, so it is taken as "
             f"{len(kept)} record{'s' if len(kept) > 1 else ''} "
             f"({', '.join(p.name for p in kept)}), each with its own initial state and "
             "offsets")
    if left:
        words += (f"; left out, fewer than {MIN_PART_ROWS} rows or a tenth of the longest "
                  "part's: " + ", ".join(f"{n} row{'s' if n > 1 else ''} from "
                                         f"{exp.time_words(a)}" for a, n in left))
    return kept, [words]


def read_records(paths: Iterable[str | Path], t_air_default: float = DEFAULT_T_AIR_C, *,
                 start: pd.Timestamp | None = None, end: pd.Timestamp | None = None,
                 period_s: float | None = None, furnace: Furnace
                 ) -> tuple[list[Experiment], list[str]]:
    """The records the commands and the fleet's jobs fit and diagnose: those
    `load_experiments` reads, each with its readings stuck at one value left out
    (`furnace_model.stuckreadings`), then its lone glitches (`furnace_model.glitches`), and
    taken as its parts between outages (`between_outages`), and the warnings that say what
    was done."""
    from .glitches import without_glitches
    from .stuckreadings import without_stuck

    out, words = [], []
    for e in load_experiments(paths, t_air_default, start=start, end=end, period_s=period_s,
                              furnace=furnace):
        e, stuck = without_stuck(e)
        e, glitched = without_glitches(e)
        parts, split = between_outages(e)
        out += parts
        words += stuck + glitched + split
    return out, words
