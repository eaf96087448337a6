"""`furnace-daq logs info|export|recover`: look into the acquisition logs, turn them into the
tabular contract for `furnace-model fit`, and rescue a file whose writer died."""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING

from furnace_model.cli.arguments import LOG_PERIOD_S, CommandParser, output_file
from furnace_model.log.schema import DAQ_STATUS, THERMOCOUPLES

if TYPE_CHECKING:
    import numpy as np

MAX_LISTED = 20


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("logs", help="inspect, export and recover MCAP logs", description=__doc__)
    lsub = p.add_subparsers(dest="logs_command", required=True, metavar="ACTION")

    info = lsub.add_parser("info", help="time span, topics, gaps, status changes, completeness",
                           description="A first look at one log or a rotated series of logs.")
    info.add_argument("files", nargs="+", type=Path, metavar="FILE")
    info.set_defaults(run=run_info)

    exp = lsub.add_parser("export", help="resample logs into the CSV/Parquet table of fit",
                          description="Thermocouples averaged over readings of quality ok per "
                                      "period, burner counts as in force, t_air averaged. "
                                      "Several files are merged in time order; a directory "
                                      "stands for its log files, as for furnace-model fit.")
    exp.add_argument("files", nargs="+", type=Path, metavar="FILE|DIR")
    exp.add_argument("--out", required=True, type=output_file, help="output .csv or .parquet")
    exp.add_argument("--period", type=float, default=LOG_PERIOD_S,
                     help="resampling period in seconds (default 60)")
    exp.add_argument("--start", help="first time exported, ISO 8601 with Z or an offset")
    exp.add_argument("--end", help="end of the export (exclusive), ISO 8601 with Z or an offset")
    if isinstance(exp, CommandParser):  # a window given backwards is an argument error
        exp.add_window("start", "end", "--start", "--end")
    exp.set_defaults(run=run_export)

    rec = lsub.add_parser("recover", help="rewrite a log whose writer died into a complete file",
                          description="Reads every complete record up to the cut and writes a "
                                      "new file; the input is left as it is.")
    rec.add_argument("file", type=Path, metavar="FILE")
    rec.add_argument("--out", type=output_file, help="output file (default FILE.recovered.mcap)")
    rec.set_defaults(run=run_recover)


def run_info(args: argparse.Namespace) -> int:
    import numpy as np

    from furnace_model.log.messages import DaqStatus
    from furnace_model.log.read import decode, iso_time, open_log

    counts: Counter[str] = Counter()
    tc_times: list[int] = []
    status: list[tuple[int, str, str]] = []
    first = last = None
    lines = []
    for path in args.files:
        log = open_log(path)
        n = 0
        for raw in log.raw():
            t = raw.message.log_time
            first = t if first is None else min(first, t)
            last = t if last is None else max(last, t)
            counts[raw.topic] += 1
            n += 1
            if raw.topic == THERMOCOUPLES:
                tc_times.append(t)
            elif raw.topic == DAQ_STATUS:
                msg = DaqStatus.from_json(decode(log.path, raw))
                status.append((t, msg.state, msg.detail))
        state = ("complete" if log.complete else
                 f"INCOMPLETE ({log.cut}); {n} messages readable; "
                 f"`furnace-daq logs recover {path}` writes a complete copy")
        lines.append(f"{path}: {state}")
    print("\n".join(lines))
    if first is None:
        print("no messages")
        return 0
    span_s = (last - first) / 1e9
    print(f"span: {iso_time(first)} .. {iso_time(last)} ({_duration(span_s)})")
    print("topics:")
    width = max(len(t) for t in counts)
    for topic, n in sorted(counts.items()):
        rate = f"{n / span_s:.3g}/s" if span_s > 0 else "-"
        print(f"  {topic:<{width}}  {n:>9} messages  {rate}")
    _print_gaps(np.sort(np.asarray(tc_times, dtype=np.int64)))
    status.sort()
    print(f"{DAQ_STATUS} changes: {len(status) or 'none'}")
    for t, state, detail in status[:MAX_LISTED]:
        print(f"  {iso_time(t)}  {state:<12}  {detail}")
    if len(status) > MAX_LISTED:
        print(f"  ... {len(status) - MAX_LISTED} more")
    _print_metadata(args.files)
    return 0


def _print_metadata(files: list[Path]) -> None:
    """Which software, host and furnace wrote the logs: their metadata record (docs/logs.md)."""
    import json

    from ..logmeta import read_metadata, recorded_refit

    meta = read_metadata(files)
    if meta is None:
        print("written by: not recorded (no furnace-daq metadata record)")
        return
    try:
        furnace = json.loads(meta.get("furnace", "{}")).get("name", "?")
    except (ValueError, AttributeError):
        furnace = "?"
    refit = recorded_refit(meta)
    print(f"written by: furnace-daq {meta.get('software_version', '?')} on "
          f"{meta.get('host', '?')}; furnace {furnace}; refit "
          + ("off" if refit is None else f"every {refit.get('period_s', '?')} s over "
             f"{refit.get('window_s', '?')} s, method {refit.get('method', '?')}"))


def _print_gaps(t: np.ndarray) -> None:
    import numpy as np

    from furnace_model.log.read import iso_time

    if t.size < 3:
        print(f"{THERMOCOUPLES} gaps: too few messages to tell")
        return
    dt = np.diff(t)
    period = float(np.median(dt))
    big = np.nonzero(dt > 3 * period)[0]
    head = f"{THERMOCOUPLES} gaps longer than 3 periods ({period / 1e9:.3g} s):"
    print(f"{head} {big.size or 'none'}")
    for i in big[:MAX_LISTED]:
        print(f"  {iso_time(int(t[i]))} .. {iso_time(int(t[i + 1]))}  ({_duration(dt[i] / 1e9)})")
    if big.size > MAX_LISTED:
        print(f"  ... {big.size - MAX_LISTED} more")


def _duration(s: float) -> str:
    if s < 120:
        return f"{s:.3g} s"
    if s < 7200:
        return f"{s / 60:.1f} min"
    return f"{s / 3600:.2f} h"


def run_export(args: argparse.Namespace) -> int:
    from furnace_model.experiment import table_kind, write_table
    from furnace_model.log.experiment import log_files
    from furnace_model.log.resample import parse_time, resample_logs

    table_kind(args.out)
    start = parse_time(args.start, "--start") if args.start else None
    end = parse_time(args.end, "--end") if args.end else None
    files = [f for p in args.files for f in (log_files(p) if p.is_dir() else [p])]
    frame = resample_logs(files, args.period, start, end)
    write_table(frame, args.out)
    tc = frame.filter(like="tc_")
    empty = int(tc.isna().all(axis=1).sum())
    print(f"{len(frame)} rows of {args.period:g} s from {frame['timestamp'].iloc[0]} to "
          f"{frame['timestamp'].iloc[-1]} ({empty} without a good thermocouple reading) "
          f"-> {args.out}")
    return 0


def run_recover(args: argparse.Namespace) -> int:
    from furnace_model.log.read import iso_time

    from ..logrecover import recover

    r = recover(args.file, args.out)
    note = "the input was complete already" if r.was_complete else r.cut
    print(f"saved {r.messages} messages from {iso_time(r.start_ns)} to {iso_time(r.end_ns)} "
          f"({_duration((r.end_ns - r.start_ns) / 1e9)}) -> {r.out} [{note}]")
    return 0
