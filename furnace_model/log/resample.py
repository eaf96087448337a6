"""MCAP logs -> the tabular contract (CONTRACTS.md section 1), resampled to a fixed period.

One resampling for every reader, so that the same log gives the same rows whichever way it
is read: `furnace-daq logs export` writes them to a file, the daemon's online refit and
replay cut windows out of them, and `furnace-model fit|validate|diagnose` read a log into
an Experiment through them (the model's package holds it: docs/logs.md).

Time base: the publish time, i.e. the PLC clock when the PLC has one (a simulator running
faster than real time logs hours of process per host minute), else the host clock.

Per bin [t, t + period), one row timed at the mean time of the thermocouple messages with a
good reading in the bin (the bin's centre when it has none): the mean of 1 Hz readings stands
for the middle of its bin, and a row labelled with the bin's start would put the data half a
bin late against the model (b and c about 13% high when fitted):
- each thermocouple is the mean of its readings of quality `ok` in the bin; a bin without one
  stays empty (missing), never filled in;
- burner counts are the state in force at the row's time (the last message up to then, also
  from before the bin): a state holds until it changes. When the daemon reads burners both
  from the PLC and from CAN flame scanners, the PLC's (`source: modbus`) are used;
- `t_air` is the mean of the usable ambient readings, empty when there are none.
Besides, every burner change gets a row of its own at the instant of the first message that
saw it, carrying the new counts and empty thermocouple and ambient cells (missing readings,
CONTRACTS.md section 1): the model's inputs then change when the burners did, not at the next
row (which put f 0.4-0.8% low). A change within 1 ms of a bin's row is carried by that row.
A row is written for every bin in which the daemon logged furnace data; a bin with nothing
logged (daemon stopped, disk full) has no row at all, and a bin before the first known burner
state has none either, since burner counts are required.

Inputs that are not whole burners (a furnace description says how each zone is fired):
- a rate-fired zone's heat input (/furnace/heat) and each measured disturbance
  (/furnace/disturbances) are their time mean over each row, from the row's time to the
  next row's (the last row as long as the one before), each `ok` reading held until the
  next: the model holds a row's input until the next row, so the row carries what the
  plant got meanwhile, and a row with no reading of its own holds the last one. A bin
  before the first reading of every one of them has no row, as before the first burner
  state;
- a pulse-fired zone's burners (/furnace/burners, each burner on or off as it pulses) are
  the mean count over each row in the same way, duty times burners: its pulses are not
  changes of their own rows;
- the register map's extra signals (/furnace/signals) are their time means too (a bit as
  the fraction of the row it was on), in a column of each signal's name, empty before a
  signal's first reading; a text signal has none.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from ..errors import DataError
from ..heldmeans import held_means, row_edges
from ..simulation.furnace import Furnace
from .messages import (
    Ambient,
    Burners,
    Disturbances,
    FurnaceMessage,
    Heat,
    NamedReadings,
    Signals,
    Thermocouples,
    as_message,
    number,
)
from .read import iso_time, log_furnace, read_messages
from .schema import AMBIENT, BURNERS, DISTURBANCES, FURNACE_TOPICS, HEAT, THERMOCOUPLES


class Binned(NamedTuple):
    """Resampled rows in time order (see the module docstring): row time (ns), thermocouple
    means (n, thermocouples), each zone's heat input (n, zones: burner counts in force, a
    pulse-fired zone's mean count, a rate's mean), t_air mean (n,), the start of the bin each
    row lies in (ns), whether the row is a bin's readings (False: a burner change), the
    disturbances' means (n, disturbances) and the signals' means by name."""

    t: np.ndarray
    tc: np.ndarray
    burners: np.ndarray
    t_air: np.ndarray
    bin_start: np.ndarray
    reading: np.ndarray
    disturbances: np.ndarray
    signals: dict[str, np.ndarray]


MERGE_NS = 1_000_000
"""A burner change this close to a bin's row is carried by it (the export's time resolution)."""


class Resampler:
    """The binning of the module docstring, fed one message at a time: `logs export` feeds it
    a whole log, the online refit and replay feed it as data arrive and cut windows out of
    it. One implementation, so an exported table and a refit window agree bin for bin.

    Messages are buffered as plain lists and binned in one vectorised pass when a table is
    asked for; `forget` drops what no later window can need, so a daemon running for months
    holds one window of bins. The thermocouples and zones are those of `furnace`: a log
    records its furnace (log.read.log_furnace)."""

    def __init__(self, step_ns: int, origin_ns: int, furnace: Furnace):
        self.step_ns = int(step_ns)
        self.origin_ns = int(origin_ns)
        self.furnace = furnace
        self._sensors = furnace.sensors
        self._n = n = len(furnace.sensors)
        self._all_ok = dict.fromkeys(furnace.sensors, "ok")
        self._tc_t: list[int] = []
        self._tc_v: list[list[float]] = []
        self._air_t: list[int] = []
        self._air_v: list[float] = []
        self._seen_t: list[int] = []  # burner messages: they mark their bin as logged
        # per bin: sums and counts of the n thermocouples and t_air, and whether logged
        self._bins = np.zeros(0, dtype=np.int64)
        # columns: n thermocouples, t_air, time of the thermocouple messages within the bin
        self._sum = np.zeros((0, n + 2))
        self._cnt = np.zeros((0, n + 2))
        # burner changes (time, counts of the zones fired by burners) per source; unchanged
        # repeats are not kept
        self._burners: dict[bool, tuple[list[int], list[tuple[float, ...]]]] = {
            True: ([], []), False: ([], [])}
        # ok readings (time, value) of each rate-fired zone, disturbance and signal by name
        self._heat = {furnace.zones[i]: _Series() for i in furnace.rated}
        self._disturbances = {d.name: _Series() for d in furnace.disturbances}
        self._signals: dict[str, _Series] = {}
        self._texts: set[str] = set()
        self._unsorted = False
        self._last_burner_msg: Burners | None = None
        self._last_burner_raw: dict | None = None
        self._last_burner_pub: int | None = None

    def add(self, topic: str, msg: FurnaceMessage | dict, pub_ns: int) -> None:
        """One furnace message (a decoded dict is read as its topic's class). A decoded
        reading with every thermocouple ok and a number is binned as it is: that is nearly
        every message of a log, and building its object would double the cost of reading."""
        raw = msg if type(msg) is dict else None
        if raw is not None:
            if topic == THERMOCOUPLES and raw.get("quality") == self._all_ok:
                values = [raw.get(s) for s in self._sensors]
                if all(type(v) is float for v in values):
                    self._tc_t.append(pub_ns)
                    self._tc_v.append(values)
                    return
            if raw is self._last_burner_raw:  # read_messages hands repeats over as one
                msg = self._last_burner_msg
        msg = as_message(topic, msg, self.furnace)
        if isinstance(msg, Thermocouples):
            self._tc_t.append(pub_ns)
            if msg.quality == self._all_ok:  # the usual case, checked in one comparison
                values = [msg.values.get(s) for s in self._sensors]
                if all(type(v) is float for v in values):
                    self._tc_v.append(values)
                    return
            self._tc_v.append([msg.reading(s) for s in self._sensors])
        elif isinstance(msg, Burners):
            self._seen_t.append(pub_ns)
            if msg is self._last_burner_msg and pub_ns >= (self._last_burner_pub or 0):
                return  # read_messages hands repeated messages over as one
            counts = tuple(_counts(msg, self.furnace))
            times, states = self._burners[msg.source == "modbus"]
            self._last_burner_msg, self._last_burner_pub = msg, pub_ns
            self._last_burner_raw = raw
            if times and pub_ns >= times[-1]:
                if states[-1] == counts:
                    return
            elif times:
                self._unsorted = True
            times.append(pub_ns)
            states.append(counts)
        elif isinstance(msg, Ambient):
            self._air_t.append(pub_ns)
            self._air_v.append(number(msg.t_air) if msg.usable else math.nan)
        elif isinstance(msg, NamedReadings):
            self._seen_t.append(pub_ns)
            if isinstance(msg, Heat):
                series = self._heat
            elif isinstance(msg, Disturbances):
                series = self._disturbances
            else:
                assert isinstance(msg, Signals)
                series = self._signals
                # text (a recipe name) has no mean over a row: no column of its own
                self._texts.update(n for n, v in msg.values.items() if isinstance(v, str))
                for name in (*msg.unit, *msg.quality):
                    if name not in self._texts:
                        series.setdefault(name, _Series())
                for name in self._texts:
                    series.pop(name, None)
            for name, one in series.items():
                value = msg.reading(name)
                if math.isfinite(value):
                    one.add(pub_ns, value)

    def _consolidate(self) -> None:
        if not (self._tc_t or self._air_t or self._seen_t):
            return
        n_tc, n_air, n = len(self._tc_t), len(self._air_t), self._n
        values = np.full((n_tc + n_air + len(self._seen_t), n + 2), np.nan)
        values[:n_tc, :n] = np.asarray(self._tc_v, dtype=float).reshape(-1, n)
        values[n_tc:n_tc + n_air, n] = self._air_v
        t = np.asarray(self._tc_t + self._air_t + self._seen_t, dtype=np.int64)
        new_keys = (t - self.origin_ns) // self.step_ns
        within = (t[:n_tc] - self.origin_ns - new_keys[:n_tc] * self.step_ns) / 1e9
        values[:n_tc, n + 1] = np.where(np.isfinite(values[:n_tc, :n]).any(axis=1), within,
                                        np.nan)
        good = np.isfinite(values)
        keys = np.concatenate([self._bins, new_keys])
        sums = np.concatenate([self._sum, np.where(good, values, 0.0)])
        counts = np.concatenate([self._cnt, good.astype(float)])
        bins, pos = np.unique(keys, return_inverse=True)
        self._bins = bins
        self._sum = np.zeros((bins.size, n + 2))
        self._cnt = np.zeros((bins.size, n + 2))
        np.add.at(self._sum, pos, sums)
        np.add.at(self._cnt, pos, counts)
        for buf in (self._tc_t, self._tc_v, self._air_t, self._air_v, self._seen_t):
            buf.clear()

    def _burner_timeline(self) -> tuple[np.ndarray, np.ndarray]:
        times, states = self._burners[True] if self._burners[True][0] else self._burners[False]
        bt = np.asarray(times, dtype=np.int64)
        bc = np.asarray(states, dtype=float).reshape(-1, len(self.furnace.switched))
        if self._unsorted:
            order = np.argsort(bt, kind="stable")
            bt, bc = bt[order], bc[order]
        return bt, bc

    def _first_known(self) -> int | None:
        """The time from which every heat input and disturbance has a value (the burner
        state, each rate, each disturbance); None while one has none yet. Every furnace has
        a heat input (its description refuses one without)."""
        firsts = [one.first for one in (*self._heat.values(), *self._disturbances.values())]
        if self.furnace.switched:
            times = self._burners[True][0] or self._burners[False][0]
            firsts.append(min(times) if times else None)
        known = [f for f in firsts if f is not None]
        return max(known) if len(known) == len(firsts) else None

    def table(self, lo_ns: int | None = None, hi_ns: int | None = None) -> Binned:
        """The rows of the logged bins whose start lies in [lo_ns, hi_ns) and whose inputs
        (burner state, rates, disturbances) are known by the bin's end, with the burner
        changes inside them (see Binned)."""
        self._consolidate()
        m = self._in_range(lo_ns, hi_ns)
        starts = self.origin_ns + self._bins[m] * self.step_ns
        total, count = self._sum[m], self._cnt[m]
        bt, bc = self._burner_timeline()
        first = self._first_known()
        known = np.zeros(starts.size, dtype=bool) if first is None \
            else starts + self.step_ns > first
        starts, total, count = starts[known], total[known], count[known]
        means = np.full(total.shape, np.nan)
        np.divide(total, count, out=means, where=count > 0)
        ns = self._n  # thermocouples; then t_air, then the readings' time within the bin
        within = np.where(np.isfinite(means[:, ns + 1]), means[:, ns + 1] * 1e9,
                          self.step_ns / 2)
        t = starts + np.round(within).astype(np.int64)
        # changes (not the first state) inside the rows' bins, unless a bin's row carries them;
        # with pulse-fired zones only the changes of whole burners: pulses are row means
        furnace = self.furnace
        kinds = [furnace.heat_inputs[i].kind for i in furnace.switched]
        ct, cb = bt[1:], bc[1:]
        if "pulse" in kinds and ct.size:
            whole = [k == "burners" for k in kinds]
            moved = np.any(np.diff(bc[:, whole], axis=0) != 0, axis=1)
            ct, cb = ct[moved], cb[moved]
        if ct.size and starts.size:
            key = (ct - self.origin_ns) // self.step_ns
            pos = np.searchsorted(starts, self.origin_ns + key * self.step_ns)
            inside = (pos < starts.size) & (starts[np.minimum(pos, starts.size - 1)]
                                            == self.origin_ns + key * self.step_ns)
            near = np.abs(t[np.minimum(pos, starts.size - 1)] - ct) < MERGE_NS
            sel = inside & ~near
            ct, cb, cstart = ct[sel], cb[sel], starts[pos[sel]]
        else:
            ct, cb, cstart = ct[:0], cb[:0], starts[:0]
        state = np.maximum(np.searchsorted(bt, t + MERGE_NS, side="left") - 1, 0)
        n, k = t.size, ct.size
        rows_t = np.concatenate([t, ct])
        order = np.argsort(rows_t, kind="stable")
        rows_t = rows_t[order]
        tc = np.concatenate([means[:, :ns], np.full((k, ns), np.nan)])[order]
        held = np.concatenate([bc[state] if n and bt.size else np.zeros((n, bc.shape[1])),
                               cb])[order]
        air = np.concatenate([means[:, ns], np.full(k, np.nan)])[order]
        reading = np.concatenate([np.ones(n, bool), np.zeros(k, bool)])[order]
        edges = row_edges(rows_t, self.step_ns)
        burners = np.zeros((rows_t.size, furnace.n_zones))
        for col, (i, kind) in enumerate(zip(furnace.switched, kinds, strict=True)):
            burners[:, i] = held[:, col] if kind == "burners" \
                else held_means(bt, bc[:, col], edges)
        if not furnace.modulated:
            burners = burners.astype(int)
        for i in furnace.rated:
            burners[:, i] = self._heat[furnace.zones[i]].means(edges)
        dist = np.column_stack([self._disturbances[d.name].means(edges)
                                for d in furnace.disturbances]) if furnace.disturbances \
            else np.zeros((rows_t.size, 0))
        signals = {name: one.means(edges) for name, one in self._signals.items()}
        return Binned(rows_t, tc, burners, air, np.concatenate([starts, cstart])[order],
                      reading, dist, signals)

    def logged_bins(self, lo_ns: int | None = None, hi_ns: int | None = None) -> int:
        """How many bins in [lo_ns, hi_ns) hold any message, burner state known or not."""
        self._consolidate()
        return int(np.count_nonzero(self._in_range(lo_ns, hi_ns)))

    def _in_range(self, lo_ns: int | None, hi_ns: int | None) -> np.ndarray:
        starts = self.origin_ns + self._bins * self.step_ns
        m = np.ones(starts.size, dtype=bool)
        if lo_ns is not None:
            m &= starts >= lo_ns
        if hi_ns is not None:
            m &= starts < hi_ns
        return m

    def forget(self, before_ns: int) -> None:
        """Drop the bins that start before `before_ns`, keeping the burner state in force."""
        self._consolidate()
        keep = self.origin_ns + self._bins * self.step_ns >= before_ns
        self._bins, self._sum, self._cnt = self._bins[keep], self._sum[keep], self._cnt[keep]
        for times, states in self._burners.values():
            if self._unsorted or not times:
                continue
            cut = int(np.searchsorted(np.asarray(times, dtype=np.int64), before_ns, "left")) - 1
            if cut > 0:
                del times[:cut]
                del states[:cut]
        for one in (*self._heat.values(), *self._disturbances.values(),
                    *self._signals.values()):
            one.forget(before_ns)


class _Series:
    """The `ok` readings of one analog input or signal, (time ns, value), held from each
    reading until the next."""

    def __init__(self) -> None:
        self.t: list[int] = []
        self.v: list[float] = []
        self.first: int | None = None
        """The earliest reading's time: kept as they come, since the online refit asks at
        every window and a week of readings is long to scan."""

    def add(self, t_ns: int, value: float) -> None:
        self.t.append(t_ns)
        self.v.append(value)
        self.first = t_ns if self.first is None else min(self.first, t_ns)

    def means(self, edges: np.ndarray) -> np.ndarray:
        """The time mean over each [edges[i], edges[i+1]); NaN for a row that ends before
        the first reading."""
        if not self.t:
            return np.full(max(edges.size - 1, 0), np.nan)
        t = np.asarray(self.t, dtype=np.int64)
        order = np.argsort(t, kind="stable")
        out = held_means(t[order], np.asarray(self.v, dtype=float)[order], edges)
        return np.where(edges[1:] > t[order[0]], out, np.nan)

    def forget(self, before_ns: int) -> None:
        """Drop the readings before `before_ns` but the one in force then."""
        if not self.t:
            return
        t = np.asarray(self.t, dtype=np.int64)
        order = np.argsort(t, kind="stable")
        cut = int(np.searchsorted(t[order], before_ns, "left")) - 1
        if cut > 0:
            self.t = t[order][cut:].tolist()
            self.v = np.asarray(self.v, dtype=float)[order][cut:].tolist()
            self.first = self.t[0]


DEFAULT_PERIOD_S = 60.0
"""The resampling period of `logs export` and of the model's commands reading logs."""


def resample_logs(paths: Iterable[str | Path], period_s: float = DEFAULT_PERIOD_S,
                  start: pd.Timestamp | None = None, end: pd.Timestamp | None = None,
                  name: str | None = None, furnace: Furnace | None = None) -> pd.DataFrame:
    """The resampled table of one or more log files (a rotated series is merged in time),
    with the rows whose bins start in [start, end) on the PLC clock, in the columns of the
    log's furnace (its metadata record; `furnace` to give it). `name` is what an error
    names (default: the files)."""
    paths = [Path(p) for p in paths]
    if not period_s > 0 or not math.isfinite(period_s):
        raise DataError("--period", f"must be a positive number of seconds, got {period_s}")
    period_ns = int(round(period_s * 1e9))
    lo = None if start is None else start.value
    hi = None if end is None else end.value
    where = name if name is not None else ", ".join(map(str, paths))
    if furnace is None:
        furnace = log_furnace(paths, where)
    binner = Resampler(period_ns, lo if lo is not None else 0, furnace)
    records = read_messages(paths, FURNACE_TOPICS)
    for topic, msg, _log_ns, pub_ns in records:
        # inputs are held: their last value before the range counts in its first row
        held = topic not in (THERMOCOUPLES, AMBIENT)
        if held or ((lo is None or pub_ns >= lo) and (hi is None or pub_ns < hi)):
            try:
                binner.add(topic, msg, pub_ns)
            except DataError as exc:  # the message's fault: say in which log and when
                raise DataError(where, f"at {iso_time(pub_ns)} (publish time): {exc}") from None
    rows = binner.table(lo, hi)
    if rows.t.size == 0:
        if binner.logged_bins(lo, hi) == 0:
            raise DataError(where, "no furnace data (thermocouples, burners, ambient) in the "
                                   "chosen time range")
        raise DataError(where, "no " + " and ".join(_inputs(furnace)) + " logged up to the "
                               "chosen range")
    return table_frame(rows.t, rows.tc, rows.burners, rows.t_air, furnace,
                       rows.disturbances, rows.signals)


def _inputs(furnace: Furnace) -> list[str]:
    """The inputs a row needs, in words: where an export without rows missed them."""
    out = [f"burner state on {BURNERS}"] if furnace.switched else []
    if furnace.rated:
        out.append(f"heat input on {HEAT}")
    if furnace.disturbances:
        out.append(f"disturbance on {DISTURBANCES}")
    return out


def table_frame(t: np.ndarray, tc: np.ndarray, burners: np.ndarray,
                air: np.ndarray, furnace: Furnace, disturbances: np.ndarray | None = None,
                signals: dict[str, np.ndarray] | None = None) -> pd.DataFrame:
    """Resampled arrays as the tabular contract (CONTRACTS.md section 1), in the furnace's
    columns (`tc_<zone>_<k>`, each zone's heat input `burners_<zone>` or `heat_<zone>`,
    `t_air`, the disturbances'), then a column per signal."""
    stamps = pd.to_datetime(np.round(t / 1e6).astype(np.int64), unit="ms", utc=True)
    frame = pd.DataFrame({"timestamp": stamps.strftime("%Y-%m-%dT%H:%M:%S.%f").str[:-3] + "Z"})
    for j, c in enumerate(furnace.tc_columns):
        frame[c] = tc[:, j]
    for j, (c, h) in enumerate(zip(furnace.burner_columns, furnace.heat_inputs, strict=True)):
        frame[c] = burners[:, j].astype(int) if h.whole else burners[:, j].astype(float)
    frame["t_air"] = air
    for j, c in enumerate(furnace.disturbance_columns):
        frame[c] = disturbances[:, j] if disturbances is not None else np.nan
    for name, values in (signals or {}).items():
        frame[name] = values
    return frame


def _counts(msg: Burners, furnace: Furnace) -> list[float]:
    out = msg.zone_counts(furnace)
    if any(math.isnan(v) for v in out):
        raise DataError(BURNERS, f"message without burner counts: {str(msg.to_json())[:200]}")
    for i, v in zip(furnace.switched, out, strict=True):
        z, n = furnace.zones[i], furnace.burners[i]
        if not 0 <= v <= n:
            raise DataError(BURNERS, f"burner count of zone {z} outside 0..{n}: {v:g}")
    return out


def parse_time(text: str, option: str) -> pd.Timestamp:
    """An ISO 8601 time with a UTC offset or Z; a time without one is refused, not guessed."""
    try:
        ts = pd.Timestamp(text)
    except (ValueError, TypeError):
        raise DataError(option, f"not an ISO 8601 time: '{text}'") from None
    if ts.tzinfo is None:
        raise DataError(option, f"'{text}' has no UTC offset or Z (time zone unknown)")
    return ts.tz_convert("UTC")
