"""The skeleton every fleet job shares: tasks planned from the fleet, those the store holds
skipped, the rest fanned out on the Dask client with progress, the rows gathered, the
tables and the report written.

A task that fails (a log that is no log, a worker killed more often than the scheduler
retries, a fit that raises) becomes one row of the job's failures table with its furnace,
its task and the reason; every other task completes. Dask itself moves a task off a worker
that dies to another worker, so a killed worker costs time, not results.

A job over a fleet file is a `FleetJob`: its name, its options, its plan and its tables;
`run` does the rest. The selfcheck, which has no fleet file, uses `run_tasks` alone.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

if TYPE_CHECKING:  # pandas and the fleet's modules: not for `furnace-daq fleet --help`
    import pandas as pd

    from furnace_model.progress import Progress

    from .description import Fleet
    from .store import Store


@dataclass
class TaskSpec:
    job: str
    furnace: str
    label: str
    fn: Callable[[object], dict]
    arg: object
    key: str


@dataclass
class Failure:
    furnace: str
    job: str
    task: str
    reason: str


@dataclass
class JobResult:
    results: list[tuple[TaskSpec, dict]] = field(default_factory=list)
    failures: list[Failure] = field(default_factory=list)
    cached: int = 0
    computed: int = 0
    notes: list[str] = field(default_factory=list)
    outputs: list[Path] = field(default_factory=list)
    """What the job wrote, for the command's last line."""

    def failures_frame(self) -> pd.DataFrame:
        import pandas as pd

        return pd.DataFrame([f.__dict__ for f in self.failures],
                            columns=["furnace", "job", "task", "reason"])

    def rows(self, key: str = "rows") -> list[dict]:
        """Every task's rows under `key`, in the order the tasks finished."""
        return [r for _, v in self.results for r in v[key]]


class FleetJob:
    """A batch job over the furnaces of a fleet file. A new job is a module in
    `furnace_daq.fleet.jobs` with one subclass: the command line finds it there."""

    name: ClassVar[str]
    help: ClassVar[str]
    description: ClassVar[str]

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """The job's own options, besides the fleet file, --out, --effects-from and the
        engine's, which every job over a fleet takes."""

    def options(self, args: argparse.Namespace) -> dict[str, Any]:
        """The keyword arguments of `plan` taken from the command line."""
        return {}

    def plan(self, fleet: Fleet, scans: dict[str, dict], effects_from: tuple[str, ...],
             **options: Any) -> tuple[list[TaskSpec], list[str]]:
        """The tasks, and notes on what the fleet cannot give."""
        raise NotImplementedError

    def write(self, result: JobResult, out_dir: Path) -> list[Path]:
        """The job's tables from the gathered rows, its failures' among them; returns the
        ones the command names when it ends."""
        raise NotImplementedError

    def run(self, client, fleet: Fleet, out_dir: Path, *, effects_from: tuple[str, ...] = (),
            quiet: bool = False, **options: Any) -> JobResult:
        from furnace_model.progress import Progress

        from .report import write_report
        from .store import Store

        result = JobResult()
        scans = scan(client, fleet, self.name, result)
        specs, result.notes = self.plan(fleet, scans, effects_from, **options)
        progress = Progress(self.name, len(specs), quiet=quiet)
        run_tasks(client, specs, Store(out_dir), progress, result)
        progress.close()
        result.outputs = [*self.write(result, out_dir), write_report(out_dir)]
        return result


def write_table(frame: pd.DataFrame, path: Path) -> Path:
    tmp = path.with_suffix(".parquet.tmp")
    frame.to_parquet(tmp, index=False)
    tmp.replace(path)
    return path


def _reason(exc: BaseException) -> str:
    name = type(exc).__name__
    if name == "KilledWorker":
        return f"every worker that ran it died (Dask gives up after its allowed failures): {exc}"
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return f"{name}: {text}" if name not in ("DataError", "ConfigError", "PluginError") \
        else text


def run_tasks(client, specs: list[TaskSpec], store: Store | None, progress: Progress,
              result: JobResult) -> None:
    """Run what the store does not hold; stored results count as done at once."""
    from distributed import as_completed

    todo = []
    for spec in specs:
        hit = store.get(spec.job, spec.furnace, spec.key) if store is not None else None
        if hit is not None:
            result.results.append((spec, hit))
            result.cached += 1
        else:
            todo.append(spec)
    progress.cached = progress.done = result.cached
    progress.show()
    if not todo:
        return
    futures = {}
    for spec in todo:
        fut = client.submit(spec.fn, spec.arg, pure=False,
                            key=f"{spec.job}-{spec.furnace}-{spec.label}-{spec.key[:12]}")
        futures[fut] = spec
    for fut in as_completed(list(futures)):
        spec = futures.pop(fut)
        try:
            value = fut.result()
        except Exception as exc:  # noqa: BLE001 - any task failure is a reported row
            result.failures.append(Failure(spec.furnace, spec.job, spec.label, _reason(exc)))
            progress.failure(spec.furnace, spec.label, result.failures[-1].reason)
            progress.finished(ok=False)
            continue
        finally:
            fut.release()
        result.computed += 1
        if store is not None:
            store.put(spec.job, spec.furnace, spec.key, value)
        result.results.append((spec, value))
        progress.finished()


def scan(client, fleet: Fleet, job: str, result: JobResult) -> dict[str, dict]:
    """Every furnace's files and spans (tasks on the cluster: the files may be visible only
    there); a furnace whose scan fails is a failure of the job and is left out."""
    from furnace_model.progress import Progress

    specs = [TaskSpec(job, f.name, "scan", _scan_task,
                      (f.name, tuple(map(str, f.logs)), f.description), "")
             for f in fleet.furnaces]
    progress = Progress(f"{job} (scan)", len(specs), quiet=True)  # failures still print
    got = JobResult()
    run_tasks(client, specs, None, progress, got)
    progress.close()
    result.failures += got.failures
    for spec, value in got.results:
        for reason in value.get("bad", []):
            result.failures.append(Failure(spec.furnace, job, "scan", reason))
            progress.failure(spec.furnace, "scan", reason + " (file left out)")
    return {spec.furnace: value for spec, value in got.results}


def _scan_task(arg: tuple) -> dict:
    from .tasks import scan_furnace

    return scan_furnace(*arg)


def file_id(path: str) -> list:
    """A plug-in file's identity in a task key: a changed plug-in is new work."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError:
        return [str(p), None, None]
    return [str(p.resolve()), st.st_size, st.st_mtime_ns]
