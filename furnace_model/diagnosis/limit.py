"""Which candidate fits a diagnosis's time limit cut: by the clock, or as a run recorded them.

A time limit makes a verdict depend on the host: a slower one leaves more fits unfitted. A
diagnosis that must be repeated elsewhere (the gateway's replay of its log) needs what the
limit cut, not the clock. Every batch of fits gets a number in the order the search runs
them and every fit its place in its batch, so a cut fit is named `batch.place`; the search
runs the same batches in the same order once the same fits are cut, because a fit that is not
cut ends as it would without a limit (`fitting.run_task`). Given such a record in place of a
time, the same fits are cut and no others, on any host.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Iterable, Sequence

from .candidate import CandidateResult
from .fitting import Task


class TimeLimit:
    """`seconds` from now, or (`cut` given) the fits a run recorded as cut; neither: none."""

    def __init__(self, seconds: float | None = None, cut: Iterable[str] | None = None):
        self.deadline = None if seconds is None else time.monotonic() + float(seconds)
        self.replayed = None if cut is None else frozenset(cut)
        self.cut: list[str] = []
        """The fits cut so far, as `batch.place`, in the order their batches ran."""
        self._batches = 0

    def batch(self, tasks: Sequence[Task]) -> tuple[list[Task], list[str]]:
        """The batch's tasks with the deadline each must keep, and their names."""
        n, self._batches = self._batches, self._batches + 1
        names = [f"{n}.{i}" for i in range(len(tasks))]
        if self.replayed is not None:
            # -inf: run_task names it not tried before it starts; None: fitted to its end
            return [dataclasses.replace(t, deadline=-math.inf if name in self.replayed
                                        else None)
                    for t, name in zip(tasks, names, strict=True)], names
        if self.deadline is not None:
            return [dataclasses.replace(t, deadline=self.deadline) for t in tasks], names
        return list(tasks), names

    def heard(self, names: Sequence[str], results: Sequence[CandidateResult]) -> None:
        self.cut += [n for n, c in zip(names, results, strict=True) if c.cut]
