"""Progress of a long job made of like tasks (a selfcheck's cases, a fleet job's furnaces):
tasks done of total, failures as they happen, and an estimate of the time left.

On a terminal one line with a bar is rewritten in place; otherwise (a log file, cron) a line
is printed at each tenth of the tasks. A failure, or a line the job wants kept (`note`), is
always its own line; `quiet` leaves only the failures, so that cron mails only when
something failed. The estimate is the mean time of the tasks done in this run times those
left: tasks taken from earlier runs cost nothing and say nothing of the rest.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

BAR = 24
"""Characters of the bar on a terminal."""


class Progress:
    def __init__(self, job: str, total: int, *, cached: int = 0, quiet: bool = False,
                 stream: TextIO | None = None, unit: str = "tasks"):
        self.job, self.total, self.cached, self.quiet = job, total, cached, quiet
        self.unit = unit
        self.stream = stream or sys.stderr
        self.done = cached
        self.failed = 0
        self.tty = self.stream.isatty()
        self._t0 = time.monotonic()
        self._last_tenth = -1
        self._open_line = False
        self.show()

    def left_s(self) -> float | None:
        """Seconds the tasks left will take at this run's pace; None before one is done."""
        ran = self.done - self.cached
        if ran <= 0:
            return None
        return (time.monotonic() - self._t0) / ran * max(self.total - self.done, 0)

    def line(self) -> str:
        cached = f" ({self.cached} from earlier runs)" if self.cached else ""
        failed = f", {self.failed} failed" if self.failed else ""
        left = self.left_s()
        eta = f", about {duration(left)} left" if left is not None and self.done < self.total \
            else ""
        return f"{self.job}: {self.done}/{self.total} {self.unit} done{cached}{failed}{eta}"

    def show(self) -> None:
        if self.quiet:
            return
        if self.tty:
            filled = BAR * self.done // max(1, self.total)
            bar = "[" + "#" * filled + "." * (BAR - filled) + "] "
            self.stream.write("\r" + bar + self.line() + "\x1b[K")
            self._open_line = True
            self.stream.flush()
            return
        tenth = self.done * 10 // max(1, self.total)
        if tenth != self._last_tenth:
            self._last_tenth = tenth
            print(self.line(), file=self.stream, flush=True)

    def finished(self, ok: bool = True) -> None:
        self.done += 1
        if not ok:
            self.failed += 1
        self.show()

    def note(self, text: str) -> None:
        """A line of its own (a case's result), kept above the bar; none when quiet."""
        if self.quiet:
            return
        self._end_line()
        print(text, file=self.stream, flush=True)

    def failure(self, furnace: str, task: str, reason: str) -> None:
        self._end_line()
        print(f"{self.job}: FAILED {furnace} {task}: {reason}", file=self.stream, flush=True)

    def close(self) -> None:
        """The last count stays on the screen."""
        self._end_line(keep=True)

    def _end_line(self, keep: bool = False) -> None:
        """Leave the bar's line: cleared for a line printed above the bar's next drawing,
        or kept."""
        if self._open_line:
            self.stream.write("\n" if keep else "\r\x1b[K")
            self.stream.flush()
            self._open_line = False


def duration(seconds: float) -> str:
    """'40 s', '12 min', '3.5 h': as precise as an estimate is."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"
