"""`fleet fit`: every campaign of every furnace fitted on its own, as `furnace-model fit`
fits it (with zone offsets, its default): how each furnace's parameters move from campaign to campaign, with their
intervals, and a parameter file per campaign that `furnace-model validate` takes.

Writes campaign_fits.parquet (a row per furnace and campaign), fit_failures.parquet, and
each fit's JSON under fits/. Campaigns are resampled as the diagnose job resamples them
(the fleet file's `diagnose.period_s`).
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..job import FleetJob, JobResult, TaskSpec, write_table

if TYPE_CHECKING:
    from furnace_model.simulation.furnace import Furnace

    from ..description import Fleet

TABLE = "campaign_fits.parquet"
FAILURES = "fit_failures.parquet"
FITS = "fits"


@dataclass(frozen=True)
class CampaignFit:
    furnace: str
    campaign: tuple[str, int, int]
    """(name, start ns, end ns) on the PLC clock."""
    files: tuple[str, ...]
    t_air_default: float
    period_s: float
    seed: int
    description: Furnace
    effects_from: tuple[str, ...] = ()


def fit_campaign(task: CampaignFit) -> dict:
    """What a worker runs: one campaign read from its logs and fitted."""
    import pandas as pd

    from furnace_model.identification.fit import fit
    from furnace_model.records import read_records
    from furnace_model.simulation.structure import ModelStructure

    from ..engine import prepare_worker

    prepare_worker(task.effects_from)
    name, lo, hi = task.campaign
    data, read = read_records(task.files, task.t_air_default, start=pd.Timestamp(lo, tz="UTC"),
                              end=pd.Timestamp(hi, tz="UTC"), period_s=task.period_s,
                              furnace=task.description)
    result = fit(data, ModelStructure(furnace=task.description), seed=task.seed, zone_offsets=True)
    # what reading the logs left out first, as `furnace-model fit` says it
    result = replace(result, warnings=[*read, *result.warnings])
    row: dict[str, Any] = {"furnace": task.furnace, "campaign": name, "status": result.status,
                           "sigma_c": result.sigma_c, "elapsed_s": result.elapsed_s,
                           "undetermined": ",".join(result.undetermined)}
    for p, v in result.params.items():
        lo_p, hi_p = result.ci95.get(p, (math.nan, math.nan))
        row[p], row[f"{p}_ci95_lo"], row[f"{p}_ci95_hi"] = v, lo_p, hi_p
    for z, m in result.per_zone.items():
        row[f"rmse_{z}_c"] = m["rmse_c"]
    return {"rows": [row], "fit": result.to_json([str(f) for f in task.files])}


class FitJob(FleetJob):
    name = "fit"
    help = "every campaign fitted on its own, per furnace"
    description = ("Every campaign of every furnace fitted on its own (`furnace-model fit`): "
                   "the parameters campaign by campaign, with their intervals.")

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--campaign", action="append", metavar="NAME",
                            help="fit only this campaign (repeatable; default: all)")

    def options(self, args: argparse.Namespace) -> dict[str, Any]:
        return {"campaigns": args.campaign}

    def plan(self, fleet: Fleet, scans: dict[str, dict], effects_from: tuple[str, ...],
             campaigns: list[str] | None = None) -> tuple[list[TaskSpec], list[str]]:
        from ..store import task_key
        from ..tasks import files_between

        s = fleet.diagnose
        specs, notes = [], []
        for f in fleet.furnaces:
            if f.name not in scans:
                continue
            files = scans[f.name]["files"]
            chosen = [c for c in f.campaigns if not campaigns or c.name in campaigns]
            if not chosen:
                notes.append(f"{f.name}: no campaign to fit")
            for c in chosen:
                span = (c.name, c.start_ns, c.end_ns)
                these = tuple(files_between(files, c.start_ns, c.end_ns))
                task = CampaignFit(f.name, span, these, f.ambient_default_c, s.period_s,
                                   s.seed, f.description, effects_from)
                ident = [x["identity"] for x in files if x["path"] in these]
                key = task_key("fit", f.name, ident,
                               {"campaign": span, "period_s": s.period_s, "seed": s.seed,
                                "t_air": f.ambient_default_c,
                                "furnace": f.description.describe()})
                specs.append(TaskSpec("fit", f.name, c.name, fit_campaign, task, key))
        return specs, notes

    def write(self, result: JobResult, out_dir: Path) -> list[Path]:
        import pandas as pd

        frame = pd.DataFrame(result.rows())
        if not frame.empty:
            frame = frame.sort_values(["furnace", "campaign"], kind="stable")
        write_table(result.failures_frame(), out_dir / FAILURES)
        folder = out_dir / FITS
        folder.mkdir(exist_ok=True)
        for spec, v in result.results:
            (folder / f"{spec.furnace}__{spec.label}.json").write_text(
                json.dumps(v["fit"], indent=1, allow_nan=False) + "\n")
        return [write_table(frame.reset_index(drop=True), out_dir / TABLE), folder]


JOB = FitJob()
