"""MCAP logs -> the tabular contract (CONTRACTS.md section 1), resampled to a fixed period.

Time base: the publish time, i.e. the PLC clock when the PLC has one (a simulator running
faster than real time logs hours of process per host minute), else the host clock.

Per bin [t, t + period), labelled with its start t:
- each thermocouple is the mean of its readings of quality `ok` in the bin; a bin without one
  stays empty (missing), never filled in;
- burner counts are the state in force at the end of the bin (the last message up to then,
  also from before the bin): a state holds until it changes. When the daemon reads burners
  both from the PLC and from CAN flame scanners, the PLC's (`source: modbus`) are used;
- `t_air` is the mean of the usable ambient readings, empty when there are none.
A row is written for every bin in which the daemon logged furnace data; a bin with nothing
logged (daemon stopped, disk full) has no row at all, and a bin before the first known burner
state has none either, since burner counts are required.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pandas as pd

from furnace_model import SENSORS, ZONES
from furnace_model.errors import DataError
from furnace_model.experiment import BURNER_COLUMNS, TC_COLUMNS

from .logschema import AMBIENT, BURNERS, THERMOCOUPLES
from .mcaplog import read_messages


def export_frame(paths: Iterable[str | Path], period_s: float = 60.0,
                 start: pd.Timestamp | None = None, end: pd.Timestamp | None = None
                 ) -> pd.DataFrame:
    """The resampled table of one or more log files (a rotated series is merged in time)."""
    paths = [Path(p) for p in paths]
    if not period_s > 0 or not math.isfinite(period_s):
        raise DataError("--period", f"must be a positive number of seconds, got {period_s}")
    period_ns = int(round(period_s * 1e9))
    lo = None if start is None else start.value
    hi = None if end is None else end.value
    origin = lo if lo is not None else 0

    tc_bins, tc_vals = [], []
    air_bins, air_vals = [], []
    burner_t, burner_counts, burner_plc = [], [], []
    seen_bins: set[int] = set()
    for topic, msg, _log_ns, pub_ns in read_messages(paths, (THERMOCOUPLES, BURNERS, AMBIENT)):
        inside = (lo is None or pub_ns >= lo) and (hi is None or pub_ns < hi)
        b = (pub_ns - origin) // period_ns
        if topic == BURNERS:
            burner_t.append(pub_ns)
            burner_counts.append(_counts(msg))
            burner_plc.append(msg.get("source") == "modbus")
        elif topic == THERMOCOUPLES and inside:
            tc_bins.append(b)
            tc_vals.append(_good_readings(msg))
        elif topic == AMBIENT and inside:
            air_bins.append(b)
            air_vals.append(_number(msg.get("t_air"))
                            if msg.get("quality", "ok") == "ok" else math.nan)
        if inside:
            seen_bins.add(b)
    if not seen_bins:
        raise DataError(", ".join(map(str, paths)),
                        "no furnace data (thermocouples, burners, ambient) in the chosen time range")

    bins = np.array(sorted(seen_bins), dtype=np.int64)
    bin_end = origin + (bins + 1) * period_ns
    bt = np.asarray(burner_t, dtype=np.int64)
    bc = np.asarray(burner_counts, dtype=float).reshape(-1, 3)
    plc = np.asarray(burner_plc, dtype=bool)
    if plc.any():  # one source of truth per poll
        bt, bc = bt[plc], bc[plc]
    order = np.argsort(bt, kind="stable")
    bt, bc = bt[order], bc[order]
    last = np.searchsorted(bt, bin_end, side="left") - 1  # last state strictly before the end
    known = last >= 0
    if not known.any():
        raise DataError(", ".join(map(str, paths)),
                        "no burner state logged on /furnace/burners up to the chosen range")
    bins, last = bins[known], last[known]

    tc = _bin_means(np.asarray(tc_bins, dtype=np.int64), np.asarray(tc_vals).reshape(-1, 6), bins)
    air = _bin_means(np.asarray(air_bins, dtype=np.int64),
                     np.asarray(air_vals, dtype=float).reshape(-1, 1), bins)[:, 0]
    stamps = pd.to_datetime(origin + bins * period_ns, unit="ns", utc=True)
    frame = pd.DataFrame({"timestamp": stamps.strftime("%Y-%m-%dT%H:%M:%S.%f").str[:-3] + "Z"})
    for j, c in enumerate(TC_COLUMNS):
        frame[c] = tc[:, j]
    for j, c in enumerate(BURNER_COLUMNS):
        frame[c] = bc[last, j].astype(int)
    frame["t_air"] = air
    return frame


def _bin_means(keys: np.ndarray, values: np.ndarray, bins: np.ndarray) -> np.ndarray:
    """Mean of the finite values per bin, NaN for a bin with none."""
    out = np.full((bins.size, values.shape[1]), np.nan)
    if keys.size == 0:
        return out
    pos = np.searchsorted(bins, keys)
    hit = (pos < bins.size) & (bins[np.minimum(pos, bins.size - 1)] == keys)
    pos, values = pos[hit], values[hit]
    good = np.isfinite(values)
    total = np.zeros_like(out)
    count = np.zeros_like(out)
    np.add.at(total, pos, np.where(good, values, 0.0))
    np.add.at(count, pos, good)
    np.divide(total, count, out=out, where=count > 0)
    return out


def _good_readings(msg: dict) -> list[float]:
    quality = msg.get("quality") or {}
    return [_number(msg.get(s)) if quality.get(s) == "ok" else math.nan for s in SENSORS]


def _counts(msg: dict) -> list[float]:
    out = []
    for z in ZONES:
        n = msg.get(f"count_{z}")
        if n is None and isinstance(msg.get(z), list):
            n = sum(bool(v) for v in msg[z])
        out.append(_number(n))
    if any(math.isnan(v) for v in out):
        raise DataError("/furnace/burners", f"message without burner counts: {msg}")
    return out


def _number(v: object) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return math.nan
    return float(v) if math.isfinite(v) else math.nan


def parse_time(text: str, option: str) -> pd.Timestamp:
    """An ISO 8601 time with a UTC offset or Z; a time without one is refused, not guessed."""
    try:
        ts = pd.Timestamp(text)
    except (ValueError, TypeError):
        raise DataError(option, f"not an ISO 8601 time: '{text}'") from None
    if ts.tzinfo is None:
        raise DataError(option, f"'{text}' has no UTC offset or Z (time zone unknown)")
    return ts.tz_convert("UTC")
