"""What a Dask worker runs. Every task takes file paths and small settings (never arrays: the
worker reads the logs itself, so nothing large crosses the network) and returns a small
plain table (lists of dicts), so any worker of any cluster that sees the same files can run
any task and the client only gathers rows.

- `scan_furnace`: a furnace's log files with their identity (size, mtime) and their span on
  the PLC clock, which the jobs need to cut segments and campaigns.
- `refit_segment`: the daemon's online refit chain (refit.WindowCutter + refit.RefitChain,
  the same windows and fits as `furnace-daq replay`) over the windows ending in one segment
  of a furnace's history, the chain started cold at the segment's start.
- `diagnose_pair`: `furnace-model diagnose` with one campaign fitted and another held out.
- `selfcheck_draw`: one draw of `furnace-model selfcheck`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from furnace_model.errors import DataError
from furnace_model.log.messages import ModelEvent, ModelParameters, number
from furnace_model.log.schema import FURNACE_TOPICS, THERMOCOUPLES, param_names
from furnace_model.simulation.furnace import Furnace

from ..daqconfig import RefitConfig
from .engine import prepare_worker

SPAN_MARGIN_NS = 3600 * 10**9
"""A file's span on the PLC clock is its log-time span shifted by its first reading's
(publish - log) offset; this margin on either side absorbs a PLC clock that drifts against
the host's within one file. A file is read only by the tasks whose time it may hold."""


# -- scan -----------------------------------------------------------------------------------

def list_files(logs: Sequence[str | Path]) -> list[Path]:
    """The log files of a furnace's `logs:` entries: a directory's files as a log directory
    is read (`log.experiment.log_files`), a file as named; one directory's files in order."""
    from furnace_model.log.experiment import log_files

    out: list[Path] = []
    for entry in logs:
        p = Path(entry)
        if p.is_dir():
            out += log_files(p)
        elif p.exists():
            out.append(p)
        else:
            raise DataError(str(p), "no such file or directory")
    return out


def file_identity(path: Path) -> list:
    """What says a file is the one a stored result was computed from: its path, size and
    modification time (a log is appended to or rewritten, never edited in place)."""
    st = path.stat()
    return [str(path.resolve()), st.st_size, st.st_mtime_ns]


def scan_furnace(furnace: str, logs: Sequence[str], description: Furnace) -> dict:
    """Per log file: path, identity, PLC-clock span. A file that is no readable log, or the
    log of another furnace than the fleet file's `description` of this one, is left out and
    listed in `bad` with the reason (the job reports each as a failure of the furnace, and
    goes on with the rest: one corrupt or misfiled log must not hide a year); a furnace with
    no usable file at all raises DataError naming its files' problems."""
    from furnace_model.log.read import open_log, read_metadata, recorded_furnace

    files = []
    bad: list[str] = []
    for path in list_files(logs):
        try:
            log = open_log(path)
            lo, hi = log.span()
            recorded = recorded_furnace(read_metadata([path]), str(path))
            if recorded != description:
                raise DataError(str(path), f"a log of furnace '{recorded.name}', and the "
                                f"fleet file says this furnace is '{description.name}'")
        except DataError as exc:
            bad.append(str(exc))
            continue
        offset = 0
        for _name, _data, log_ns, pub_ns in log.records({THERMOCOUPLES}):
            offset = pub_ns - log_ns
            break
        else:
            if lo == hi == 0:
                continue  # a file with no message at all: nothing to read
        files.append({"path": str(path), "identity": file_identity(path),
                      "start_ns": lo + offset, "end_ns": hi + offset})
    if not files:
        if bad:
            raise DataError(", ".join(map(str, logs)), "no readable log: " + "; ".join(bad))
        raise DataError(", ".join(map(str, logs)), "no furnace data in the logs")
    files.sort(key=lambda f: (f["start_ns"], f["path"]))
    return {"furnace": furnace, "files": files, "bad": bad}


def files_between(files: list[dict], lo_ns: int | None, hi_ns: int | None) -> list[str]:
    """Paths of the scanned files that may hold messages in [lo_ns, hi_ns] (None: open)."""
    out = []
    for f in files:
        if lo_ns is not None and f["end_ns"] + SPAN_MARGIN_NS < lo_ns:
            continue
        if hi_ns is not None and f["start_ns"] - SPAN_MARGIN_NS > hi_ns:
            continue
        out.append(f["path"])
    return out


# -- refit ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Segment:
    """The windows of one furnace whose end lies in (after_ns, until_ns]; None: open."""

    furnace: str
    index: int
    files: tuple[str, ...]
    refit: RefitConfig
    t_air_default: float
    after_ns: int | None
    until_ns: int | None
    effects_from: tuple[str, ...] = ()
    description: Furnace = field(kw_only=True)


def refit_segment(seg: Segment) -> dict:
    """Rows of the refit table and drift events of one segment. The chain starts cold at the
    segment's start: data are read from one window before it, so the first window fitted is
    full; windows ending at or before the start only fill the bins."""
    from furnace_model.log.read import read_messages

    from ..refit import RefitChain, WindowCutter

    prepare_worker(seg.effects_from)
    cpu0 = time.process_time()
    cfg = seg.refit
    cutter = WindowCutter(cfg, seg.t_air_default, furnace=seg.description)
    chain = RefitChain(cfg, seg.t_air_default, furnace=seg.description)
    window_ns = int(round(cfg.window_s * 1e9))
    read_from = None if seg.after_ns is None else seg.after_ns - window_ns
    rows: list[dict] = []
    events: list[dict] = []

    def take(window) -> bool:
        if seg.after_ns is not None and window.end_ns <= seg.after_ns:
            return True
        if seg.until_ns is not None and window.end_ns > seg.until_ns:
            return False
        msg, evs = chain.process(window)
        rows.append(parameter_row(seg.furnace, seg.index, msg, seg.description))
        events.extend(event_row(seg.furnace, seg.index, e) for e in evs)
        return True

    going = True
    for name, msg, _log_ns, pub_ns in read_messages(seg.files, FURNACE_TOPICS):
        if read_from is not None and pub_ns < read_from:
            continue
        for window in cutter.feed(name, msg, pub_ns):
            going = take(window)
            if not going:
                break
        if not going:
            break
    return {"rows": rows, "events": events, "cpu_s": time.process_time() - cpu0}


def parameter_row(furnace: str, segment: int, msg: ModelParameters,
                  description: Furnace) -> dict:
    """A /model/parameters message as a flat row: the furnace's parameters, their 95% bounds,
    RMSE and zone offset per zone, and what the fit flagged."""
    row = {"furnace": furnace, "segment": segment, "window_start": msg.window_start,
           "window_end": msg.window_end, "status": msg.status,
           "detail": msg.detail, "n_samples": msg.n_samples or 0}
    ci = msg.ci95 or {}
    rmse = msg.rmse_c or {}
    fitted = msg.fitted
    for p in param_names(description):
        row[p] = number(msg.params.get(p))
        lo, hi = ci.get(p, (None, None))
        row[f"{p}_ci95_lo"], row[f"{p}_ci95_hi"] = number(lo), number(hi)
    offsets = (msg.zone_offsets_c or {}) if fitted else {}
    for z in description.zones:
        row[f"rmse_{z}_c"] = number(rmse.get(z))
        row[f"offset_{z}_c"] = number(offsets.get(z))
    row["flagged"] = ",".join(f"{f['kind']}:{f['zone']}" for f in msg.flags or []) \
        if fitted else ""
    # False when the window kept the model in force: its parameters are that model's.
    row["fitted"] = fitted
    row["undetermined"] = ",".join(msg.undetermined or []) if fitted else ""
    row["elapsed_s"] = number(msg.elapsed_s)
    return row


def event_row(furnace: str, segment: int, e: ModelEvent) -> dict:
    return {"furnace": furnace, "segment": segment, "kind": str(e.kind),
            "parameter": e.parameter or "", "basis": e.basis or "window",
            "window_start": e.window_start or "", "window_end": e.window_end or "",
            "old": number(e.old), "new": number(e.new),
            "relative_change": number(e.relative_change), "detail": e.detail}


# -- diagnose -------------------------------------------------------------------------------

@dataclass(frozen=True)
class Pair:
    """One diagnosis: campaign `fit` fitted, campaign `holdout` held out."""

    furnace: str
    fit: tuple[str, int, int]
    """(campaign name, start ns, end ns) on the PLC clock."""
    holdout: tuple[str, int, int]
    fit_files: tuple[str, ...]
    holdout_files: tuple[str, ...]
    t_air_default: float
    effects: tuple[str, ...] | None
    period_s: float
    seed: int
    effects_from: tuple[str, ...] = ()
    description: Furnace = field(kw_only=True)


def diagnose_pair(pair: Pair) -> dict:
    """The verdict row of one diagnosis, and the diagnosis's JSON (CONTRACTS.md section 6)."""
    import pandas as pd

    from furnace_model.diagnosis import diagnose
    from furnace_model.records import read_records

    prepare_worker(pair.effects_from)
    cpu0 = time.process_time()
    read: list[str] = []

    def load(files, span):
        _, lo, hi = span
        records, words = read_records(files, pair.t_air_default,
                                      start=pd.Timestamp(lo, tz="UTC"),
                                      end=pd.Timestamp(hi, tz="UTC"), period_s=pair.period_s,
                                      furnace=pair.description)
        read.extend(words)
        return records

    d = diagnose(load(pair.fit_files, pair.fit), load(pair.holdout_files, pair.holdout),
                 effects=pair.effects, seed=pair.seed)
    v = d.verdict
    row = {"furnace": pair.furnace, "fit_campaign": pair.fit[0],
           "holdout_campaign": pair.holdout[0], "status": v.status,
           "effects": ",".join(v.effects), "shrink_pct": number(v.shrink_pct),
           "gap_closed_pct": number(getattr(v, "gap_closed_pct", math.nan)),
           "gap_zones": ",".join(d.gap_zones), "sentence": v.sentence,
           "elapsed_s": number(d.elapsed_s)}
    held = d.baseline.rmse_holdout_carried_c or {}
    for z in pair.description.zones:
        row[f"rmse_holdout_{z}_c"] = number(d.baseline.rmse_holdout_c[z])
        row[f"rmse_holdout_carried_offsets_{z}_c"] = number(held.get(z))
        row[f"noise_floor_{z}_c"] = number(d.noise_floor_c[z])
    row["flags"] = len(d.baseline.flags)
    row["read"] = "; ".join(read)  # what reading the logs left out or split
    row["cpu_s"] = time.process_time() - cpu0
    return {"rows": [row], "diagnosis": {**d.to_json(), "read": read}}


# -- selfcheck ------------------------------------------------------------------------------

@dataclass(frozen=True)
class Draw:
    label: str
    draw: int
    seed: int
    form: str
    candidates: tuple[str, ...] | None
    noise: str
    effects_from: tuple[str, ...] = ()
    furnace: Furnace = field(kw_only=True)
    """The description the cases run on (`selfcheck --furnace`, or the production
    scenario's with `--production`)."""
    mode: str = field(default="heat-up", kw_only=True)
    """Heat-ups or production records (`furnace_model.diagnosis.selfcheck.MODES`)."""


def selfcheck_draw(d: Draw) -> dict:
    """One case of `furnace-model selfcheck` (the same case for the same seed, label, draw
    and noise, whichever worker draws it)."""
    from furnace_model.diagnosis.selfcheck import check

    prepare_worker(d.effects_from)
    (outcome,) = check([d.label], 1, d.seed, form=d.form, candidates=d.candidates,
                       noise=d.noise, first=d.draw, mode=d.mode, furnace=d.furnace)
    return {"rows": [outcome.to_json()]}
