"""`fleet selfcheck`: the draws of `furnace-model selfcheck` as tasks, read with its own
options and reported with its own table and acceptance. It has no fleet file: its tasks are
draws of known-truth cases, not a furnace's logs.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

from ..job import JobResult, TaskSpec, file_id, run_tasks

if TYPE_CHECKING:
    from furnace_model.simulation.furnace import Furnace


def run_selfcheck(client, labels: list[str], draws: int, out_dir: Path, *, furnace: Furnace,
                  seed: int = 0, first: int = 0, form: str = "candidate",
                  candidates: tuple[str, ...] | None = None, noise: str = "white",
                  effects_from: tuple[str, ...] = (), mode: str = "heat-up",
                  quiet: bool = False) -> tuple[list, JobResult]:
    """Every (label, draw) of the selfcheck as a task; the Outcomes in the order
    `furnace-model selfcheck` reports them."""
    from furnace_model.diagnosis.selfcheck import Outcome
    from furnace_model.progress import Progress

    from ..store import Store, task_key
    from ..tasks import Draw, selfcheck_draw

    specs = []
    for label in labels:
        for k in range(first, first + draws):
            d = Draw(label, k, seed, form, candidates, noise, effects_from, furnace=furnace,
                     mode=mode)
            key = task_key("selfcheck", label, [file_id(p) for p in effects_from], d)
            specs.append(TaskSpec("selfcheck", label, f"draw {k}", selfcheck_draw, d, key))
    result = JobResult()
    progress = Progress("selfcheck", len(specs), quiet=quiet)
    run_tasks(client, specs, Store(out_dir), progress, result)
    progress.close()
    order = {(s.furnace, s.label): i for i, s in enumerate(specs)}
    got = sorted(result.results, key=lambda sv: order[(sv[0].furnace, sv[0].label)])
    outcomes = []
    for _, v in got:
        doc = dict(v["rows"][0])
        for k in ("shrink_pct", "gap_closed_pct", "elapsed_s"):
            if doc.get(k) is None:
                doc[k] = math.nan
        outcomes.append(Outcome(**doc))
    return outcomes, result
