"""Progress of a fleet job: tasks done of total and failures as they happen.

On a terminal one line is rewritten in place; otherwise (a log file, cron) a line is printed
at each tenth of the tasks. A failure is always its own line, naming the furnace, the task
and the reason; `quiet` leaves only those, so that cron mails only when something failed.
"""

from __future__ import annotations

import sys
from typing import TextIO


class Progress:
    def __init__(self, job: str, total: int, *, cached: int = 0, quiet: bool = False,
                 stream: TextIO | None = None):
        self.job, self.total, self.cached, self.quiet = job, total, cached, quiet
        self.stream = stream or sys.stderr
        self.done = cached
        self.failed = 0
        self.tty = self.stream.isatty()
        self._last_tenth = -1
        self._open_line = False
        self.show()

    def line(self) -> str:
        cached = f" ({self.cached} from earlier runs)" if self.cached else ""
        failed = f", {self.failed} failed" if self.failed else ""
        return f"{self.job}: {self.done}/{self.total} tasks done{cached}{failed}"

    def show(self) -> None:
        if self.quiet:
            return
        if self.tty:
            self.stream.write("\r" + self.line() + "\x1b[K")
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

    def failure(self, furnace: str, task: str, reason: str) -> None:
        if self._open_line:
            self.stream.write("\n")
            self._open_line = False
        print(f"{self.job}: FAILED {furnace} {task}: {reason}", file=self.stream, flush=True)

    def close(self) -> None:
        if self._open_line:
            self.stream.write("\n")
            self.stream.flush()
            self._open_line = False
