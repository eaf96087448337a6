"""Heat-up data in the tabular contract (CONTRACTS.md section 1), read into an Experiment.

Everything that breaks the contract is refused with the file, the column and the row (CSV:
the line number as an editor shows it) and nothing is guessed: an empty thermocouple cell is
a missing reading, not a zero, a burner count must be a whole number within the zone, a
pulse-fired zone's mean count and a modulated zone's rate must lie within 0 and the zone's
maximum, and a measured disturbance within its declared range.
MCAP logs become the same table through `furnace_model.log.experiment` (the resampling of
`logs export`) and are checked here like any file; `furnace_model.records` reads either.
"""

from __future__ import annotations

import contextlib
import os
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import DataError, DataWarning
from .extras import require
from .simulation.furnace import Disturbance, Furnace, HeatInput

TIME_COLUMNS = ("timestamp", "t_min")
DEFAULT_T_AIR_C = 30.0
TEMPERATURE_RANGE_C = (-273.15, 3000.0)
MAX_SPAN_MIN = 10 * 366 * 24 * 60.0
OUTAGE_PERIODS = 5.0
"""Rows further apart than this many of the record's usual spacings (`row_spacing_min`)
leave an outage between them: a simulation holds the row before's inputs across it, right
only if nothing changed there. A sample or two missing is an acquisition's ordinary loss;
five in a row is a stop."""
USUAL_SPACING = 0.95
"""The record's usual spacing between rows: the spacing this share of its rows keep or
less. A sampled record's period; a record logged on change (a historian's row only where a
value moved by its deadband, so that a row's absence means nothing moved) spaces its rows
by minutes to hours, and those gaps hold its inputs, as the model does."""


@dataclass
class Experiment:
    """One heat-up record of a furnace: readings and inputs per sample, time in minutes from
    the start. Thermocouples and zones in the furnace's order (the paper's: six, three)."""

    name: str
    t_min: np.ndarray  # (N,) strictly increasing
    tc: np.ndarray  # (N, thermocouples) NaN = missing reading
    burners: np.ndarray  # (N, zones) each zone's heat input: burners on, or its rate
    t_air: np.ndarray  # (N,)
    start_time: pd.Timestamp | None = None
    source: str = ""
    furnace: Furnace = field(kw_only=True)
    disturbances: np.ndarray | None = field(default=None, kw_only=True)
    """(N, disturbances) the furnace's measured disturbances, in its order."""
    signals: dict[str, np.ndarray] = field(default_factory=dict, kw_only=True)
    """Further logged numbers the model does not use (O2, pressure, a door switch, a
    disturbance nobody declared), by column: what the diagnosis asks the model's error to
    follow."""

    def __post_init__(self) -> None:
        k = len(self.furnace.disturbances)
        if self.disturbances is None:
            if k:
                raise ValueError(f"furnace '{self.furnace.name}' declares disturbances "
                                 f"({', '.join(self.furnace.disturbance_columns)}): a record "
                                 "of it needs their values")
            self.disturbances = np.zeros((self.t_min.size, 0))
        self.disturbances = np.asarray(self.disturbances, dtype=float).reshape(
            self.t_min.size, k)

    def __len__(self) -> int:
        return self.t_min.size

    @property
    def zone_temp(self) -> np.ndarray:
        """Zone temperature (N, zones): mean of the zone's good thermocouples, NaN when none."""
        return self.furnace.zone_means(self.tc)

    @property
    def burner_steps(self) -> int:
        """How many times the burner pattern changes: the excitation the data carry."""
        return int(np.any(np.diff(self.burners, axis=0) != 0, axis=1).sum())

    def rows(self, mask: np.ndarray) -> Experiment:
        """The samples `mask` selects, times kept as they are."""
        return Experiment(self.name, self.t_min[mask], self.tc[mask], self.burners[mask],
                          self.t_air[mask], self.start_time, self.source,
                          furnace=self.furnace, disturbances=self.disturbances[mask],
                          signals={k: v[mask] for k, v in self.signals.items()})

    def inputs_over_steps(self) -> np.ndarray:
        """The inputs over each step between samples, (N - 1, inputs) in the system's
        order: the heat and the disturbances held from the step's start, as the PLC holds
        them; ambient, which moves, at the step's middle."""
        air = np.asarray(self.t_air, dtype=float)[:, None]
        return np.concatenate([self.burners[:-1], 0.5 * (air[:-1] + air[1:]),
                               self.disturbances[:-1]], axis=1).astype(float)

    def without_readings(self, cells: Iterable[tuple[str, int | slice]]) -> Experiment:
        """The record with these thermocouple readings blank, as missing ones are: (column,
        row or rows)."""
        tc = self.tc.copy()
        for column, rows in cells:
            tc[rows, self.furnace.tc_columns.index(column)] = np.nan
        return replace(self, tc=tc)

    def time_words(self, t_min: float) -> str:
        """A time of the record as a reader finds it: its UTC date and minute where the
        record has a start time, else its minute."""
        if self.start_time is None:
            return f"minute {t_min:g}"
        return (self.start_time + pd.Timedelta(minutes=t_min)).strftime("%Y-%m-%d %H:%M") + "Z"

    def sample_period_min(self) -> float:
        return float(np.median(np.diff(self.t_min))) if len(self) > 1 else float("nan")

    def row_spacing_min(self) -> float:
        """The record's usual spacing between rows (`USUAL_SPACING`), in minutes."""
        if len(self) < 2:
            return float("nan")
        return float(np.quantile(np.diff(self.t_min), USUAL_SPACING))

    def outages(self, longest_min: float | None = None) -> list[tuple[float, float]]:
        """(last row before, first row after), in minutes, of every spacing between rows
        longer than `longest_min` (default: OUTAGE_PERIODS usual spacings)."""
        if len(self) < 3:
            return []
        if longest_min is None:
            longest_min = OUTAGE_PERIODS * self.row_spacing_min()
        k = np.flatnonzero(np.diff(self.t_min) > longest_min)
        return [(float(self.t_min[i]), float(self.t_min[i + 1])) for i in k]

    def between(self, lo: float, hi: float) -> Experiment:
        """The samples with lo <= t_min < hi, times kept as they are."""
        return self.rows((self.t_min >= lo) & (self.t_min < hi))

    def to_frame(self) -> pd.DataFrame:
        cols: dict[str, object] = {}
        if self.start_time is not None:
            ts = self.start_time + pd.to_timedelta(self.t_min, unit="min")
            cols["timestamp"] = ts.strftime("%Y-%m-%dT%H:%M:%S.%f").str[:-3] + "Z"
        else:
            cols["t_min"] = self.t_min
        for i, c in enumerate(self.furnace.tc_columns):
            cols[c] = self.tc[:, i]
        for i, (c, h) in enumerate(zip(self.furnace.burner_columns,
                                       self.furnace.heat_inputs, strict=True)):
            cols[c] = self.burners[:, i].astype(int) if h.whole else self.burners[:, i]
        cols["t_air"] = self.t_air
        for i, c in enumerate(self.furnace.disturbance_columns):
            cols[c] = self.disturbances[:, i]
        cols.update(self.signals)
        return pd.DataFrame(cols)


def resolution(y: np.ndarray) -> float:
    """The step a reading is logged to: the least gap between its distinct values (about
    nothing for a reading kept to full precision; 0 with fewer than two values)."""
    gaps = np.diff(np.unique(y[np.isfinite(y)]))  # every column's values on one grid
    gaps = gaps[gaps > 0]
    return float(gaps.min()) if gaps.size else 0.0


def listed(items: list[str], most: int = 5) -> str:
    """The first `most` items, and how many more."""
    more = f" and {len(items) - most} more" if len(items) > most else ""
    return ", ".join(items[:most]) + more


def outage_words(exp: Experiment) -> list[str]:
    """A warning per outage of the record (`Experiment.outages`), with its span."""
    return [f"{exp.name}: no rows for {gap_words(exp, [span])}: the model holds the inputs of "
            "the row before across it; if they changed there, fit the parts on either side "
            "as records of their own" for span in exp.outages()]


def gap_words(exp: Experiment, spans: list[tuple[float, float]]) -> str:
    """The record's outages `spans` (minutes) as a reader finds them: how long, from when."""
    from .progress import duration

    return (", ".join(f"{duration(60 * (hi - lo))} from {exp.time_words(lo)}"
                      for lo, hi in spans)
            + f" (more than {OUTAGE_PERIODS:g} times the record's usual row spacing)")


def write_table(frame: pd.DataFrame, path: str | Path) -> None:
    """Write the tabular contract as CSV or Parquet, chosen by the file's suffix."""
    path = Path(path)
    kind = table_kind(path)
    # Written aside and renamed: a full disk or a kill never leaves half a table, nor
    # destroys the file being replaced.
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if kind == "csv":
            frame.to_csv(tmp, index=False, float_format="%.3f")
        else:
            frame.to_parquet(tmp, index=False)
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise DataError(str(path), f"cannot write: {exc.strerror or exc}") from None


def table_kind(path: Path) -> str:
    """"csv" or "parquet" by the file's suffix; Parquet only where its extra is installed.
    Commands that write a table call it on their arguments, before the work."""
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return "csv"
    if suffix in (".parquet", ".pq"):
        require("parquet", f"{path}: a Parquet table")
        return "parquet"
    raise DataError(str(path), f"unsupported file type '{suffix or '(none)'}': use .csv or .parquet")


def read_table(path: str | Path, t_air_default: float = DEFAULT_T_AIR_C, *,
               start: pd.Timestamp | None = None, end: pd.Timestamp | None = None,
               furnace: Furnace) -> Experiment:
    """Read and check one file of the tabular contract (CSV or Parquet) against the
    furnace's columns."""
    path = Path(path)
    kind = table_kind(path)
    file = str(path)
    if not path.exists():
        raise DataError(file, "file not found")
    try:
        if kind == "csv":
            if path.stat().st_size == 0:
                raise DataError(file, "empty file: no header and no data")
            frame = _read_csv(path)
        else:
            frame = pd.read_parquet(path)
    except DataError:
        raise
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise DataError(file, f"not a readable CSV file: {_first_line(exc)}") from None
    except (OSError, ValueError) as exc:  # pyarrow's errors derive from these
        raise DataError(file, f"not a readable {kind} file: {_first_line(exc)}") from None
    return experiment_from_frame(frame, file, t_air_default,
                                 row_offset=2 if kind == "csv" else 1,
                                 row_label="line" if kind == "csv" else "row",
                                 start=start, end=end, furnace=furnace)


def _case_hint(wanted: list[str], cols: list[str]) -> str:
    """Words for columns the file has under another case than the names wanted."""
    found = [c for c in cols if c.lower() in {w.lower() for w in wanted} and c not in wanted]
    return (f"; the file has {', '.join(found)}: column names are matched as written, "
            "in lower case" if found else "")


def _read_csv(path: Path) -> pd.DataFrame:
    """A CSV's cells as text. A spreadsheet in a language whose decimal mark is a comma
    writes ';' between fields and ',' in its numbers, and one saved as text writes tabs:
    the header says which (a ';' or a tab and no ','), and a decimal comma is read as a
    point."""
    with path.open(encoding="utf-8-sig", errors="replace") as fh:
        header = fh.readline()
    sep = next((s for s in (";", "\t") if s in header and "," not in header), ",")
    frame = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True,
                        sep=sep, encoding="utf-8-sig")
    if sep == ",":
        return frame
    return frame.apply(lambda column: column.str.replace(",", ".", regex=False))


def experiment_from_frame(frame: pd.DataFrame, file: str = "<table>",
                          t_air_default: float = DEFAULT_T_AIR_C, row_offset: int = 1,
                          row_label: str = "row", start: pd.Timestamp | None = None,
                          end: pd.Timestamp | None = None, *,
                          furnace: Furnace) -> Experiment:
    """Check a table against the contract of a furnace and convert it. `row_offset` maps the
    frame's positional index to the number the user sees (2 for a CSV line under its
    header). `start`/`end` keep the rows timed in [start, end), as if the file held only
    those: the whole table is checked first, so an error names the row of the file. A
    `tc_` or `burners_` column the furnace does not have is refused (a file of another
    furnace); other extra columns are left alone."""
    cols = [str(c).strip() for c in frame.columns]
    frame = frame.set_axis(cols, axis=1)

    def err(message: str, column: str | None = None, pos: int | None = None) -> DataError:
        row = None if pos is None else pos + row_offset
        return DataError(file, message, column, row, row_label)

    dup = sorted({c for c in cols if cols.count(c) > 1})
    if dup:
        raise err(f"column(s) appear more than once: {', '.join(dup)}")
    time_cols = [c for c in TIME_COLUMNS if c in cols]
    if len(time_cols) != 1:
        raise err("needs exactly one time column, 'timestamp' (ISO 8601) or 't_min' (minutes)"
                  + ("; found both" if len(time_cols) == 2 else "; found neither"))
    tc_columns, burner_columns = furnace.tc_columns, furnace.burner_columns
    unknown = [c for c in cols if c.startswith(("tc_", "burners_"))
               and c not in tc_columns and c not in burner_columns]
    if unknown:
        raise err(f"unknown column(s) {', '.join(unknown)}: furnace '{furnace.name}' has "
                  f"{', '.join(tc_columns + burner_columns)}", unknown[0])
    missing = [c for c in (*burner_columns, *furnace.disturbance_columns) if c not in cols]
    if missing:
        raise err(f"missing required column(s): {', '.join(missing)} "
                  f"(furnace '{furnace.name}'){_case_hint(missing, cols)}")
    for z, n in zip(furnace.zones, furnace.thermocouples, strict=True):
        if not any(f"tc_{z}_{i}" in cols for i in range(1, n + 1)):
            names = [f"tc_{z}_{i}" for i in range(1, n + 1)]
            raise err(f"zone '{z}' has no thermocouple column (need {' or '.join(names)})"
                      + _case_hint(names, cols))
    if len(frame) == 0:
        raise err("no data rows")

    time_col = time_cols[0]
    start_time = None
    if time_col == "timestamp":
        stamps = _timestamps(frame[time_col], err)
        start_time = stamps[0]
        t_min = (stamps - start_time).total_seconds().to_numpy() / 60.0
    else:
        t_min = _numbers(frame[time_col], time_col, err, allow_empty=False)
    steps = np.diff(t_min)
    bad = np.nonzero(steps <= 0)[0]
    if bad.size:
        i = int(bad[0]) + 1
        what = "duplicate time" if steps[bad[0]] == 0 else "time goes backwards"
        raise err(f"{what}: rows must be in strictly increasing time order", time_col, i)

    if t_min[-1] - t_min[0] > MAX_SPAN_MIN:
        raise err(f"time spans {t_min[-1] - t_min[0]:.3g} minutes, more than ten years: "
                  "not one heat-up", time_col, len(frame) - 1)

    tc = np.full((len(frame), len(tc_columns)), np.nan)
    for j, c in enumerate(tc_columns):
        if c in cols:
            tc[:, j] = _temperatures(_numbers(frame[c], c, err, allow_empty=True), c, err)

    burners = np.empty((len(frame), furnace.n_zones))
    for j, (c, heat) in enumerate(zip(burner_columns, furnace.heat_inputs, strict=True)):
        burners[:, j] = _heat_input(_numbers(frame[c], c, err, allow_empty=False), heat,
                                    furnace.zones[j], c, err)
    disturbances = np.empty((len(frame), len(furnace.disturbances)))
    for j, d in enumerate(furnace.disturbances):
        disturbances[:, j] = _disturbance(_numbers(frame[d.column], d.column, err,
                                                   allow_empty=True), d, err)

    signals = _signals(frame, cols, furnace)
    if "t_air" in cols:
        t_air = _temperatures(_numbers(frame["t_air"], "t_air", err, allow_empty=True),
                              "t_air", err)
    else:
        t_air = np.full(len(frame), np.nan)

    if start is not None or end is not None:
        if time_col != "timestamp":
            raise err("has times in minutes ('t_min'), not on the PLC clock: --from/--to need "
                      "a 'timestamp' column")
        keep = np.ones(len(frame), dtype=bool)
        if start is not None:
            keep &= np.asarray(stamps >= start)
        if end is not None:
            keep &= np.asarray(stamps < end)
        if not keep.any():
            raise err(f"no rows in the window {window_words(start, end)}")
        stamps, tc, burners, t_air = stamps[keep], tc[keep], burners[keep], t_air[keep]
        disturbances = disturbances[keep]
        signals = {k: v[keep] for k, v in signals.items()}
        start_time = stamps[0]
        t_min = (stamps - start_time).total_seconds().to_numpy() / 60.0

    absent = [c for c in tc_columns if c not in cols]
    if absent:  # said once the file is known to be good: an error says all there is to say
        warnings.warn(DataWarning(file, f"furnace '{furnace.name}' has thermocouple(s) "
                                        f"{', '.join(absent)} that the file lacks: their zones "
                                        "are read from the others"), stacklevel=2)
    if "t_air" not in cols:
        warnings.warn(DataWarning(file, f"no 't_air' column: the ambient is taken as "
                                        f"{t_air_default:g} °C throughout; where the zones lose "
                                        "heat to an outside that moves (a building's weather), "
                                        "give its readings as t_air"), stacklevel=2)
    # Ambient changes slowly: an empty cell holds the last reading (the default before any).
    t_air = pd.Series(t_air).ffill().fillna(t_air_default).to_numpy()
    return Experiment(Path(file).stem, t_min, tc, burners, t_air, start_time, file,
                      furnace=furnace, disturbances=disturbances, signals=signals)


def _signals(frame: pd.DataFrame, cols: list[str], furnace: Furnace) -> dict[str, np.ndarray]:
    """The other columns that hold numbers (empty cells allowed), as signals: left alone by
    the model, offered to the diagnosis. A column of anything else is not a signal and is
    left alone as before."""
    used = {*TIME_COLUMNS, "t_air", *furnace.tc_columns, *furnace.burner_columns,
            *furnace.disturbance_columns}
    out = {}
    for c in cols:
        if c in used or c.startswith(("tc_", "burners_", "heat_")) or _row_label(c):
            continue
        col = frame[c]
        if pd.api.types.is_bool_dtype(col.dtype):
            v = col.to_numpy(dtype=float)
        elif pd.api.types.is_numeric_dtype(col.dtype):
            v = col.to_numpy(dtype=float, na_value=np.nan)
        else:
            text = col.astype(str).str.strip()
            v = pd.to_numeric(text.where(text != "", None), errors="coerce").to_numpy(float)
            if (np.isnan(v) & (text != "").to_numpy()).any():
                continue
        if np.isfinite(v).any() and not np.isinf(v).any() and not _counts_rows(v):
            out[c] = v
    return out


def _row_label(column: str) -> bool:
    """A table's own row numbers as a spreadsheet or pandas writes them, not a signal."""
    return column.lower() in ("index", "row", "") or column.startswith("Unnamed: ")


def _counts_rows(v: np.ndarray) -> bool:
    """Whether a column only numbers the rows (0, 1, 2, ...): a ramp the model would take for
    a heat input."""
    steps = np.diff(v)
    return v.size > 2 and bool(np.all(steps == 1.0))


def _heat_input(v: np.ndarray, heat: HeatInput, zone: str, column: str, err) -> np.ndarray:
    """A zone's heat-input column checked against how the zone is fired."""
    if heat.whole:
        frac = np.nonzero(v != np.round(v))[0]
        if frac.size:
            raise err(f"burner count must be a whole number, got {v[frac[0]]:g} (a zone "
                      "fired by modulated or pulse-fired burners says so in the furnace "
                      "description: heat: {kind: rate} or {kind: pulse})", column,
                      int(frac[0]))
    what = "burner count" if heat.kind != "rate" else f"heat input ({heat.unit})"
    neg = np.nonzero(v < 0)[0]
    if neg.size:
        raise err(f"{what} cannot be negative, got {v[neg[0]]:g}", column, int(neg[0]))
    over = np.nonzero(v > heat.max * (1 + 1e-9))[0]
    if over.size:
        most = (f"has {heat.max:g} burners" if heat.kind != "rate"
                else f"fires at most {heat.max:g} {heat.unit}")
        raise err(f"the {zone} zone {most}, got {v[over[0]]:g}", column, int(over[0]))
    return v


def _disturbance(v: np.ndarray, d: Disturbance, err) -> np.ndarray:
    """A measured disturbance: within its declared range; an empty cell holds the last
    reading (a slow signal logged less often than the rest), but the first must be given."""
    if v.size and np.isnan(v[0]):
        raise err(f"the first row has no value for disturbance '{d.name}' ({d.unit}): "
                  "nothing to hold", d.column, 0)
    if d.range is not None:
        lo, hi = d.range
        out = np.nonzero((v < lo) | (v > hi))[0]
        if out.size:
            raise err(f"{v[out[0]]:g} {d.unit} is outside the declared range of "
                      f"'{d.name}' ({lo:g} to {hi:g})", d.column, int(out[0]))
    return pd.Series(v).ffill().to_numpy()


def window_words(start: pd.Timestamp | None, end: pd.Timestamp | None) -> str:
    """A time window as the options that chose it."""
    parts = [f"--from {start.isoformat()}" if start is not None else "",
             f"--to {end.isoformat()}" if end is not None else ""]
    return " ".join(p for p in parts if p) or "(the whole record)"


def _numbers(col: pd.Series, name: str, err, allow_empty: bool) -> np.ndarray:
    if pd.api.types.is_bool_dtype(col.dtype):
        raise err("expected numbers, got true/false values", name)
    if pd.api.types.is_numeric_dtype(col.dtype):
        v = col.to_numpy(dtype=float, na_value=np.nan)
        empty = np.isnan(v)
    else:
        text = col.astype(str).str.strip()
        empty = ((text == "") | col.isna()).to_numpy()
        v = pd.to_numeric(text.where(~empty, None), errors="coerce").to_numpy(dtype=float)
        bad = np.nonzero(np.isnan(v) & ~empty)[0]
        if bad.size:
            raise err(f"not a number: '{text.iloc[bad[0]]}'", name, int(bad[0]))
    inf = np.nonzero(np.isinf(v))[0]
    if inf.size:
        raise err("not a finite number", name, int(inf[0]))
    if not allow_empty and empty.any():
        raise err("empty cell: a value is required here", name, int(np.nonzero(empty)[0][0]))
    return v


def _temperatures(v: np.ndarray, name: str, err) -> np.ndarray:
    """A reading beyond what any thermocouple survives is a broken export or a unit mix-up
    (kelvin, counts); fitting it would only overflow."""
    out = np.nonzero((v < TEMPERATURE_RANGE_C[0]) | (v > TEMPERATURE_RANGE_C[1]))[0]
    if out.size:
        lo, hi = TEMPERATURE_RANGE_C
        raise err(f"{v[out[0]]:g} °C is not a furnace temperature (expected {lo:g} to "
                  f"{hi:g})", name, int(out[0]))
    return v


def _timestamps(col: pd.Series, err) -> pd.DatetimeIndex:
    if pd.api.types.is_datetime64_any_dtype(col.dtype):
        idx = pd.DatetimeIndex(col)
        if idx.tz is None:
            raise err("timestamps need a UTC offset or Z (time zone unknown)", "timestamp")
        if idx.isna().any():
            raise err("empty cell: a value is required here", "timestamp",
                      int(np.nonzero(idx.isna())[0][0]))
        return idx.tz_convert("UTC")
    text = col.astype(str).str.strip()
    parsed = pd.to_datetime(text, format="ISO8601", utc=True, errors="coerce")
    bad = np.nonzero(parsed.isna().to_numpy())[0]
    if bad.size:
        i = int(bad[0])
        raise err(f"not an ISO 8601 time: '{text.iloc[i]}'", "timestamp", i)
    # utc=True silently treats a time without an offset as UTC; refuse instead of guessing.
    naive = ~text.str.contains(r"(?:Z|[+-]\d\d:?\d\d)$", regex=True)
    if naive.any():
        i = int(np.nonzero(naive.to_numpy())[0][0])
        raise err(f"timestamp has no UTC offset or Z: '{text.iloc[i]}'", "timestamp", i)
    return pd.DatetimeIndex(parsed)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
