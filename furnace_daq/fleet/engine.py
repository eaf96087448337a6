"""The engine every fleet job runs on: a dask.distributed client.

By default a LocalCluster of worker processes on this machine (one per core, one thread
each: a fit is numpy-bound and holds the GIL between calls, so threads would only queue),
bound to 127.0.0.1 with the dashboard off. `--scheduler tcp://HOST:PORT` connects to a
running cluster instead; from there on the code path is the same.

Worker processes are daemonic under Dask, so nothing a task runs may start processes of its
own: `prepare_worker` turns the diagnosis's own candidate pool off (the candidates of one
diagnosis then run one after the other in the worker; the fleet's parallelism is across
tasks). Effects a user wrote (`--effects-from`) are loaded by the task itself, once per
worker process, so that a worker that joins late or is restarted after a crash has them too.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from furnace_model.errors import FurnaceError


class EngineError(FurnaceError):
    """The cluster cannot be started or reached."""

    exit_code = 1


def default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
               else (os.cpu_count() or 1))


@contextmanager
def open_client(scheduler: str | None = None, workers: int | None = None,
                dashboard: bool = False, timeout_s: float = 30.0) -> Iterator:
    """A connected `distributed.Client`; the LocalCluster it started (if any) is closed on
    exit, a running cluster is left running."""
    import logging

    from distributed import Client, LocalCluster

    # Dask's own INFO lines (scheduler and worker start, dashboard) are not ours to print:
    # progress and failures are reported by the jobs.
    for name in ("distributed", "distributed.scheduler", "distributed.nanny",
                 "distributed.core", "distributed.worker", "distributed.http.proxy"):
        logging.getLogger(name).setLevel(logging.WARNING)
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=timeout_s)
        except (OSError, TimeoutError) as exc:
            raise EngineError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        try:
            yield client
        finally:
            client.close()
        return
    n = workers or default_workers()
    # Without the dashboard the scheduler still serves a few HTTP routes (health, metrics):
    # on a port of the kernel's choosing, so that two jobs side by side do not contend for
    # 8787, and on loopback like everything else.
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                           host="127.0.0.1",
                           dashboard_address="127.0.0.1:8787" if dashboard else None,
                           scheduler_kwargs=None if dashboard else {
                               "dashboard": False, "dashboard_address": "127.0.0.1:0"},
                           silence_logs=logging.WARNING)
    try:
        client = Client(cluster)
        try:
            if dashboard:
                import sys

                print(f"dashboard: {client.dashboard_link}", file=sys.stderr)
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


_LOADED: set[str] = set()


def prepare_worker(effects_from: Sequence[str] = ()) -> None:
    """Run at the start of every task, in the worker: plug-in effects loaded (once per
    process) and the diagnosis's own process pool off."""
    from furnace_model.diagnosis import pool
    from furnace_model.effects import plugins

    pool.WORKERS = 1
    plugins.load_installed()
    for path in effects_from:
        key = str(Path(path).resolve())
        if key not in _LOADED:
            plugins.load_file(path)
            _LOADED.add(key)
