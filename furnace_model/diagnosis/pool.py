"""Candidates fitted side by side in a pool of processes: each fit is independent and
seconds to minutes long."""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed

from .candidate import CandidateResult
from .fitting import Task, relative_cost, run_task
from .limit import TimeLimit

WORKERS = 2
MANAGER_JOIN_S = 10.0  # dead workers are seen at once; a bound, never a wait


def run_all(tasks: list[Task], progress: Callable[[float], None],
            finished: Callable[[CandidateResult], None] | None = None,
            limit: TimeLimit | None = None,
            work: Callable[[Task], CandidateResult] = run_task) -> list[CandidateResult]:
    """`work`'s results of the tasks (a module-level function or a partial of one: the pool
    pickles it), in their order; `progress` hears the share done, `finished` each result as
    it comes. `limit`: the diagnosis's time limit, by which each task ends, fitted or named
    as not tried (`CandidateResult.cut`); it hears which were cut."""
    if not tasks:
        return []
    names: list[str] = []
    if limit is not None:
        tasks, names = limit.batch(tasks)
    results = _run(tasks, progress, finished or (lambda _c: None), work)
    if limit is not None:
        limit.heard(names, results)
    return results


def _run(tasks: list[Task], progress: Callable[[float], None],
         done: Callable[[CandidateResult], None],
         work: Callable[[Task], CandidateResult]) -> list[CandidateResult]:
    out: list[CandidateResult] = []
    if WORKERS > 1 and len(tasks) > 1:
        ctx = multiprocessing.get_context("fork")
        order = sorted(range(len(tasks)), key=lambda i: -relative_cost(tasks[i]))
        pool = ProcessPoolExecutor(max_workers=WORKERS, mp_context=ctx,
                                   initializer=die_with_parent, initargs=(os.getpid(),))
        try:
            futures = {pool.submit(work, tasks[i]): i for i in order}
            results = {}
            # heard as each finishes: the slow fit submitted first must not hold back the
            # lines of the quick ones that finish beside it
            for k, future in enumerate(as_completed(futures)):
                results[futures[future]] = future.result()
                done(results[futures[future]])
                progress((k + 1) / len(tasks))
        except BaseException:
            _stop(pool)
            raise
        pool.shutdown()
        return [results[i] for i in range(len(tasks))]
    for k, t in enumerate(tasks):
        out.append(work(t))
        done(out[-1])
        progress((k + 1) / len(tasks))
    return out


def _stop(pool: ProcessPoolExecutor) -> None:
    """End the pool's work now: on Ctrl-C, or a fit that raised. Leaving the pool as its
    context would (shutdown, waiting) runs every candidate still queued to its end, minutes
    on a long record, before the interrupted command can exit; and a worker that did not get
    the signal itself (only the command's process was signalled) goes on computing. The
    pool's manager thread is joined once its workers are dead: left running, it closes its
    wake-up pipe while the interpreter's exit handler writes to it, a traceback on stderr."""
    workers = list(getattr(pool, "_processes", None) or {})
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    for pid in workers:
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)
    if manager is not None:
        manager.join(timeout=MANAGER_JOIN_S)


PR_SET_PDEATHSIG = 1


def die_with_parent(parent: int) -> None:
    """A worker ends when the diagnosis that started it is killed (a supervisor's timeout
    sends SIGKILL, which no handler sees): left alone, it would compute its candidate for
    minutes as an orphan. Linux tells the worker through the parent-death signal; a parent
    that died before this ran is seen by its pid."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:
        os._exit(1)
