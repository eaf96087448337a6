"""Lines for the journal: stderr with sd-daemon(3) priority prefixes, rate-limited by kind.

Under systemd a service's stderr goes to the journal, which reads a leading `<N>` as the
line's syslog priority (`SyslogLevelPrefix=`, on by default), so `journalctl -p err` finds
the daemon's errors without a logging library or the journal's native protocol. Outside
systemd the same lines land on the terminal, prefix and all, as other sd-daemon services
print them.

A PLC that stays down fails at every retry, and a map with a wrong address at every poll:
the same line every second would bury everything else, so each kind of message is said at
most once per `repeat_s`, and the next time it is said it carries how often it happened in
between.

Libraries that log through Python's `logging` (the live view's foxglove-sdk, whose Rust core
is bridged into it) reach the journal the same way, through `JournalHandler`.
"""

from __future__ import annotations

import contextlib
import logging
import re
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TextIO

ERR, WARNING, NOTICE, INFO = 3, 4, 5, 6
"""sd-daemon(3) / syslog priorities: SD_ERR, SD_WARNING, SD_NOTICE, SD_INFO."""


@dataclass
class _Kind:
    last_said: float
    suppressed: int = 0
    priority: int = INFO
    text: str = ""


class Journal:
    """stderr lines with a priority prefix; the same `kind` at most once per `repeat_s`."""

    def __init__(self, repeat_s: float = 60.0, stream: TextIO | None = None,
                 clock: Callable[[], float] = time.monotonic):
        self.repeat_s = repeat_s
        self._stream = stream
        self._clock = clock
        self._kinds: dict[str, _Kind] = {}
        # a library's log records arrive on its own threads (JournalHandler)
        self._lock = threading.RLock()

    def say(self, priority: int, text: str, kind: str | None = None) -> bool:
        """Write `text` at `priority`; with a `kind`, only if that kind was not said within
        `repeat_s` (else counted). Returns whether the line was written."""
        with self._lock:
            return self._say(priority, text, kind)

    def _say(self, priority: int, text: str, kind: str | None) -> bool:
        if kind is not None:
            now = self._clock()
            seen = self._kinds.get(kind)
            if seen is not None and now - seen.last_said < self.repeat_s:
                seen.suppressed += 1
                seen.priority, seen.text = priority, text
                return False
            if seen is not None and seen.suppressed:
                text += (f" [{seen.suppressed} more like this in the last "
                         f"{now - seen.last_said:.0f} s]")
            self._kinds[kind] = _Kind(now, 0, priority, text)
        self._write(priority, text)
        return True

    def pump(self) -> None:
        """Say the repeats held back for a whole `repeat_s`, each kind once with its latest
        text and the count: the journal is never more than `repeat_s` behind a failure
        that goes on, even when it stops being reported."""
        with self._lock:
            now = self._clock()
            for seen in self._kinds.values():
                if seen.suppressed and now - seen.last_said >= self.repeat_s:
                    self._release(seen, now)

    def flush(self) -> None:
        """Say every repeat still untold (at stop)."""
        with self._lock:
            now = self._clock()
            for seen in self._kinds.values():
                if seen.suppressed:
                    self._release(seen, now)

    def _release(self, seen: _Kind, now: float) -> None:
        self._write(seen.priority, f"{seen.text} [{seen.suppressed} more like this in the "
                                   f"last {now - seen.last_said:.0f} s]")
        seen.suppressed = 0
        seen.last_said = now

    def _write(self, priority: int, text: str) -> None:
        stream = self._stream if self._stream is not None else sys.stderr
        line = " ".join(text.splitlines())  # the prefix holds for one line only
        with contextlib.suppress(OSError, ValueError):  # a broken stderr must not stop polling
            stream.write(f"<{priority}>{line}\n")  # one write: lines of two threads never mix
            stream.flush()


class JournalHandler(logging.Handler):
    """A library's log records as journal lines: `prefix: message`, with the priority of
    the record's level, rate-limited like the daemon's own kinds. A kind is a logger's
    message with its numbers taken out: a client that fails again and again from new
    ports is one kind, a client coming and one going are two.

    `most` is the most severe priority the lines may take: a library whose errors are not
    the daemon's (the live view's, when a client fails its handshake) is kept out of
    `journalctl -p err`, which shows why data stopped."""

    def __init__(self, journal: Journal, prefix: str, *, most: int = ERR):
        super().__init__(logging.INFO)
        self.journal, self.prefix, self.most = journal, prefix, most

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = f"{self.prefix}: {record.getMessage()}"
        except Exception:  # a record that cannot be formatted is the library's bug, not ours
            self.handleError(record)
            return
        level = (ERR if record.levelno >= logging.ERROR
                 else WARNING if record.levelno >= logging.WARNING else INFO)
        kind = f"log:{record.name}:{_DIGITS.sub('#', text)}"
        self.journal.say(max(level, self.most), text, kind)


_DIGITS = re.compile(r"\d+")
