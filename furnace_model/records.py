"""The records a command names, whatever their kind: each CSV or Parquet file of the tabular
contract is one (`furnace_model.experiment`), MCAP logs one per directory
(`furnace_model.log.experiment`)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import pandas as pd

from .experiment import DEFAULT_T_AIR_C, Experiment, read_table
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
