"""`fleet refit`: every furnace's logs through the online refit chain of `furnace-daq replay`,
furnaces (and, cut with --segment-days, segments of one furnace's history) in parallel.

Writes refit.parquet (a row per window), drift_events.parquet and refit_failures.parquet.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..job import FleetJob, JobResult, TaskSpec, write_table
from ..tables import DRIFT_EVENTS, REFIT, REFIT_FAILURES

if TYPE_CHECKING:
    import pandas as pd

    from ..description import Fleet

EVENT_COLUMNS = ["furnace", "segment", "kind", "parameter", "basis", "window_start",
                 "window_end", "old", "new", "relative_change", "detail"]


def segment_bounds(start_ns: int, end_ns: int, period_s: float, segment_days: float | None
                   ) -> list[tuple[int | None, int | None]]:
    """(after, until] bounds of the windows' ends: one open segment when not cut; else cuts
    every `segment_days` from the first midnight after the start, on the refit period's grid
    (a cut at a refit instant: no window is in two segments or in none)."""
    if not segment_days:
        return [(None, None)]
    step = int(round(segment_days * 86400e9))
    period = int(round(period_s * 1e9))
    day = 86400 * 10**9
    cut = (start_ns // day + 1) * day + step - day
    cuts = []
    while cut < end_ns:
        aligned = cut // period * period
        if not cuts or aligned > cuts[-1]:
            cuts.append(aligned)
        cut += step
    edges: list[int | None] = [None, *cuts, None]
    return list(zip(edges[:-1], edges[1:], strict=True))


class RefitJob(FleetJob):
    name = "refit"
    help = "the online refit over every furnace's logs"
    description = ("Every furnace's logs through the online refit chain of `furnace-daq "
                   "replay`, furnaces in parallel.")

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--segment-days", type=_positive_days, metavar="D",
                            help="cut each history into segments of D days, each started cold, "
                                 "so one furnace's year runs in parallel too (default: uncut, "
                                 "the replay timeline; docs/fleet.md says what a cut changes)")

    def options(self, args: argparse.Namespace) -> dict[str, Any]:
        return {"segment_days": args.segment_days}

    def plan(self, fleet: Fleet, scans: dict[str, dict], effects_from: tuple[str, ...],
             segment_days: float | None = None) -> tuple[list[TaskSpec], list[str]]:
        from ..store import task_key
        from ..tasks import Segment, files_between, refit_segment

        cfg = fleet.refit
        window_ns = int(round(cfg.window_s * 1e9))
        specs = []
        for f in fleet.furnaces:
            if f.name not in scans:
                continue
            files = scans[f.name]["files"]
            start = min(x["start_ns"] for x in files)
            end = max(x["end_ns"] for x in files)
            for i, (after, until) in enumerate(segment_bounds(start, end, cfg.period_s,
                                                              segment_days)):
                chosen = files_between(files, None if after is None else after - window_ns,
                                       until)
                seg = Segment(f.name, i, tuple(chosen), cfg, f.ambient_default_c, after, until,
                              effects_from, description=f.description)
                ident = [x["identity"] for x in files if x["path"] in chosen]
                key = task_key("refit", f.name, ident,
                               {"refit": cfg, "t_air": f.ambient_default_c, "after": after,
                                "until": until, "furnace": f.description.describe()})
                specs.append(TaskSpec("refit", f.name, f"segment {i}", refit_segment, seg, key))
        return specs, []

    def write(self, result: JobResult, out_dir: Path) -> list[Path]:
        write_table(result.failures_frame(), out_dir / REFIT_FAILURES)
        return [write_table(refit_frame(result.rows()), out_dir / REFIT),
                write_table(events_frame(result.rows("events")), out_dir / DRIFT_EVENTS)]


def refit_frame(rows: list[dict]) -> pd.DataFrame:
    import pandas as pd

    frame = pd.DataFrame(rows)
    if frame.empty:
        return frame
    for col in ("window_start", "window_end"):
        frame[col] = pd.to_datetime(frame[col], utc=True)
    return frame.sort_values(["furnace", "window_end"], kind="stable").reset_index(drop=True)


def events_frame(events: list[dict]) -> pd.DataFrame:
    import pandas as pd

    frame = pd.DataFrame(events, columns=EVENT_COLUMNS)
    for col in ("window_start", "window_end"):
        frame[col] = pd.to_datetime(frame[col], utc=True)
    return frame.sort_values(["furnace", "window_end"], kind="stable").reset_index(drop=True)


JOB = RefitJob()


def run_refit(client, fleet: Fleet, out_dir: Path, *, segment_days: float | None = None,
              effects_from: tuple[str, ...] = (), quiet: bool = False) -> JobResult:
    """Refit every furnace; writes the tables and the fleet report under `out_dir`."""
    return JOB.run(client, fleet, out_dir, effects_from=effects_from, quiet=quiet,
                          segment_days=segment_days)


def _positive_days(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: '{text}'") from None
    if not v > 0 or v != v:
        raise argparse.ArgumentTypeError(f"must be a positive number of days, got {text}")
    return v
