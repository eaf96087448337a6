"""`furnace-daq fleet`: batch jobs over a fleet of furnaces and their log histories, on
dask.distributed (a LocalCluster on this machine's cores, or --scheduler tcp://HOST:PORT).

  refit      every furnace's logs through the daemon's online refit (as `replay`), furnaces
             and history segments in parallel -> refit.parquet, drift_events.parquet
  diagnose   campaign against campaign per furnace -> verdicts.parquet, fleet_report.html
  selfcheck  the selfcheck's draws as tasks -> the table of `furnace-model selfcheck`

Results are stored under --out by furnace and a hash of input files and settings: a rerun
computes only what changed. A task that fails is reported with its furnace and reason, the
rest completes, and the exit code is 1 (docs/fleet.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from furnace_model.cli.arguments import CommandParser, output_dir, positive_int
from furnace_model.extras import require


def register(sub: argparse._SubParsersAction) -> None:
    from ..fleet import jobs as fleet_jobs
    from ..fleet.job import FleetJob

    p = sub.add_parser("fleet", help="batch jobs over a fleet of furnaces on Dask",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    jobs = p.add_subparsers(dest="job", required=True, metavar="JOB",
                            parser_class=CommandParser)
    for name in fleet_jobs.names():
        job = getattr(fleet_jobs.module(name), "JOB", None)
        if isinstance(job, FleetJob):
            j = jobs.add_parser(job.name, help=job.help, description=job.description)
            _fleet_file(j)
            job.add_arguments(j)
            _common(j)
            j.set_defaults(run=_run(job))
        elif name == "selfcheck":
            _register_selfcheck(jobs)


def _register_selfcheck(jobs: argparse._SubParsersAction) -> None:
    from furnace_model.cli.selfcheck import register as register_selfcheck

    holder = argparse.ArgumentParser(add_help=False).add_subparsers()
    register_selfcheck(holder)  # the selfcheck's own options, read exactly as it reads them
    own = holder.choices["selfcheck"]
    s = jobs.add_parser("selfcheck", help="the selfcheck's draws as tasks",
                        description="`furnace-model selfcheck` with every draw a task.",
                        parents=[own], conflict_handler="resolve")
    s.add_argument("--out", type=output_dir, required=True, metavar="DIR",
                   help="directory for stored results (created)")
    _engine(s)
    s.set_defaults(run=run_selfcheck)


def _fleet_file(p: argparse.ArgumentParser) -> None:
    p.add_argument("fleet", type=Path, metavar="FLEET.yaml", help="the fleet description")


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=output_dir, required=True, metavar="DIR",
                   help="directory for the tables, the report and stored results (created)")
    p.add_argument("--effects-from", action="append", type=Path, default=[], metavar="PATH.py",
                   help="load effects written as Python classes in this file, here and in "
                        "every worker (repeatable)")
    _engine(p)


def _engine(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("engine")
    g.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="a running Dask scheduler (default: a LocalCluster on this machine)")
    g.add_argument("--workers", type=positive_int, metavar="N",
                   help="LocalCluster worker processes (default: one per core)")
    g.add_argument("--dashboard", action="store_true",
                   help="serve the LocalCluster's dashboard on 127.0.0.1:8787")
    g.add_argument("--quiet", action="store_true",
                   help="print only failures (for cron)")


def _effects(paths: list[Path]) -> tuple[str, ...]:
    """Load the plug-ins here (their names check the fleet file) and pass them to the
    workers as absolute paths."""
    from furnace_model.cli.names import sync_plugins
    from furnace_model.effects.plugins import load_file

    for path in paths:
        load_file(path)
    sync_plugins(installed=True)
    return tuple(str(p.resolve()) for p in paths)


def _prepare(args: argparse.Namespace):
    from ..fleet.description import load_fleet

    require("fleet", "a fleet job")
    effects = _effects(args.effects_from)
    fleet = load_fleet(args.fleet)
    args.out.mkdir(parents=True, exist_ok=True)
    return fleet, effects


def _client(args: argparse.Namespace):
    from ..fleet.engine import open_client

    return open_client(args.scheduler, args.workers, args.dashboard)


def _finish(args: argparse.Namespace, result, outputs: list[str]) -> int:
    for note in result.notes:
        if not args.quiet:
            print(f"note: {note}", file=sys.stderr)
    if not args.quiet:
        print(f"{result.computed} task(s) run, {result.cached} from earlier runs, "
              f"{len(result.failures)} failed -> {', '.join(outputs)}", file=sys.stderr)
    return 1 if result.failures else 0


def _run(job):
    def run(args: argparse.Namespace) -> int:
        fleet, effects = _prepare(args)
        with _client(args) as client:
            result = job.run(client, fleet, args.out, effects_from=effects, quiet=args.quiet,
                             **job.options(args))
        return _finish(args, result, [str(p) for p in result.outputs])

    return run


def run_selfcheck(args: argparse.Namespace) -> int:
    """As `furnace-model selfcheck` (labels, table, --json, acceptance), draws as tasks."""
    from furnace_model.cli import selfcheck as sc

    from ..fleet.jobs.selfcheck import run_selfcheck as job

    require("fleet", "a fleet job")
    effects = _effects(args.effects_from or [])
    labels = sc.labels_of(args)
    args.out.mkdir(parents=True, exist_ok=True)
    with _client(args) as client:
        outcomes, result = job(client, labels, args.draws, args.out, seed=args.seed,
                               first=args.first_draw, form=args.form,
                               candidates=args.candidates, noise=args.noise,
                               effects_from=effects, quiet=args.quiet,
                               mode=sc.mode_of(args), furnace=sc.cases_furnace(args))
    rows = sc.report(args, outcomes, complete=not result.failures)
    code = _finish(args, result, [str(args.json)] if args.json else ["stdout"])
    failed = [r.label for r in rows if not r.passed]
    if failed:
        print(f"selfcheck: acceptance missed for {', '.join(failed)}", file=sys.stderr)
        return 1
    return code

