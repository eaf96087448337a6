"""`fleet diagnose`: per furnace, one campaign fitted and another held out, as
`furnace-model diagnose` does; by default each campaign of the fleet file against the next,
or --pair FIT:HOLDOUT, or --rolling day|week|month of the logs against the next.

Writes verdicts.parquet, diagnose_failures.parquet and each diagnosis's JSON under
diagnoses/.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..job import FleetJob, JobResult, TaskSpec, file_id, write_table
from ..tables import DIAGNOSE_FAILURES, VERDICTS

if TYPE_CHECKING:
    import pandas as pd

    from ..description import Fleet, FleetFurnace

DIAGNOSES = "diagnoses"
VERDICT_COLUMNS = ["furnace", "fit_campaign", "holdout_campaign", "status", "effects",
                   "shrink_pct"]
ROLLING = {"day": "D", "week": "W-SUN", "month": "M"}
"""--rolling PERIOD: each calendar period (UTC; weeks Monday to Sunday) against the next."""

Span = tuple[str, int, int]


def campaign_pairs(f: FleetFurnace, scan_: dict, pairs: list[tuple[str, str]] | None,
                   rolling: str | None) -> tuple[list[tuple[Span, Span]], list[str]]:
    """The (fit, holdout) campaigns of one furnace, and notes on pairs it cannot have."""
    import pandas as pd

    notes: list[str] = []
    if rolling is not None:
        start = min(x["start_ns"] for x in scan_["files"])
        end = max(x["end_ns"] for x in scan_["files"])
        periods = pd.period_range(pd.Timestamp(start, tz="UTC").tz_localize(None),
                                  pd.Timestamp(end, tz="UTC").tz_localize(None),
                                  freq=ROLLING[rolling])
        spans = [(_period_name(p, rolling), int(p.start_time.value),
                  int((p + 1).start_time.value)) for p in periods]
        return list(zip(spans[:-1], spans[1:], strict=True)), notes
    camps = {c.name: (c.name, c.start_ns, c.end_ns) for c in f.campaigns}
    if pairs:
        out = []
        for a, b in pairs:
            missing = [n for n in (a, b) if n not in camps]
            if missing:
                notes.append(f"{f.name}: no campaign {', '.join(missing)}; pair {a}:{b} "
                             "left out")
                continue
            out.append((camps[a], camps[b]))
        return out, notes
    ordered = sorted(camps.values(), key=lambda c: c[1])
    if len(ordered) < 2:
        notes.append(f"{f.name}: fewer than two campaigns; nothing to diagnose")
    return list(zip(ordered[:-1], ordered[1:], strict=False)), notes


def _period_name(p: pd.Period, rolling: str) -> str:
    if rolling == "month":
        return p.strftime("%Y-%m")
    if rolling == "week":
        return p.start_time.strftime("%G-W%V")
    return p.strftime("%Y-%m-%d")


class DiagnoseJob(FleetJob):
    name = "diagnose"
    help = "campaign against campaign, per furnace"
    description = ("Per furnace, one campaign fitted and another held out (`furnace-model "
                   "diagnose`); default: each campaign of the fleet file against the next.")

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        how = parser.add_mutually_exclusive_group()
        how.add_argument("--pair", action="append", type=_pair, metavar="FIT:HOLDOUT",
                         help="campaign names, fitted:held out (repeatable)")
        how.add_argument("--rolling", choices=tuple(ROLLING),
                         help="each calendar day/week/month (UTC) of the logs against the next, "
                              "instead of the campaigns")

    def options(self, args: argparse.Namespace) -> dict[str, Any]:
        return {"pairs": args.pair, "rolling": args.rolling}

    def plan(self, fleet: Fleet, scans: dict[str, dict], effects_from: tuple[str, ...],
             pairs: list[tuple[str, str]] | None = None, rolling: str | None = None
             ) -> tuple[list[TaskSpec], list[str]]:
        from ..store import task_key
        from ..tasks import Pair, diagnose_pair, files_between

        s = fleet.diagnose
        specs, notes = [], []
        for f in fleet.furnaces:
            if f.name not in scans:
                continue
            files = scans[f.name]["files"]
            chosen, why = campaign_pairs(f, scans[f.name], pairs, rolling)
            notes += why
            for fit, hold in chosen:
                fit_files = tuple(files_between(files, fit[1], fit[2]))
                hold_files = tuple(files_between(files, hold[1], hold[2]))
                pair = Pair(f.name, fit, hold, fit_files, hold_files, f.ambient_default_c,
                            s.effects, s.period_s, s.seed, effects_from,
                            description=f.description)
                ident = [x["identity"] for x in files
                         if x["path"] in set(fit_files + hold_files)]
                key = task_key("diagnose", f.name, ident,
                               {"fit": fit, "holdout": hold, "settings": s,
                                "t_air": f.ambient_default_c,
                                "furnace": f.description.describe(),
                                "effects_from": [file_id(p) for p in effects_from]})
                specs.append(TaskSpec("diagnose", f.name, f"{fit[0]}:{hold[0]}",
                                      diagnose_pair, pair, key))
        return specs, notes

    def write(self, result: JobResult, out_dir: Path) -> list[Path]:
        import pandas as pd

        frame = pd.DataFrame(result.rows())
        if frame.empty:
            frame = pd.DataFrame(columns=VERDICT_COLUMNS)
        frame = frame.sort_values(["furnace", "fit_campaign", "holdout_campaign"],
                                  kind="stable")
        write_table(result.failures_frame(), out_dir / DIAGNOSE_FAILURES)
        folder = out_dir / DIAGNOSES
        folder.mkdir(exist_ok=True)
        for spec, v in result.results:
            name = f"{spec.furnace}__{spec.label.replace(':', '__')}.json"
            (folder / name).write_text(json.dumps(v["diagnosis"], indent=1, default=_nan_none)
                                       + "\n")
        return [write_table(frame.reset_index(drop=True), out_dir / VERDICTS)]


JOB = DiagnoseJob()


def run_diagnose(client, fleet: Fleet, out_dir: Path, *,
                 pairs: list[tuple[str, str]] | None = None, rolling: str | None = None,
                 effects_from: tuple[str, ...] = (), quiet: bool = False) -> JobResult:
    """Diagnose every furnace's campaign pairs; writes the tables, each diagnosis's JSON
    and the report under `out_dir`."""
    return JOB.run(client, fleet, out_dir, effects_from=effects_from, quiet=quiet,
                             pairs=pairs, rolling=rolling)


def _nan_none(x):
    return None if isinstance(x, float) and math.isnan(x) else str(x)


def _pair(text: str) -> tuple[str, str]:
    parts = text.split(":")
    if len(parts) != 2 or not all(parts):
        raise argparse.ArgumentTypeError(f"expected FIT:HOLDOUT campaign names, got '{text}'")
    return parts[0], parts[1]
