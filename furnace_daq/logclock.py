"""The log's time stamps: host UTC, kept in order when the host clock steps.

The poll schedule runs on the monotonic clock, so a host clock step cannot disturb it; the
log time is read from the host's UTC clock and would go back with it. A log whose time runs
backwards reorders itself in every reader that merges by time, so:

- a step forward is followed at once (a gap in log time, nothing reordered);
- a step back of at most `max_slew_s` is absorbed: log time keeps advancing at
  (1 - `slew`) of the real rate until the host clock has caught up with it, so it never goes
  back; a step of X seconds is absorbed after X / `slew` seconds;
- a bigger step back (a day by default: a host clock that was plainly wrong and has been
  corrected) is followed, log time goes back there: absorbing it would keep the log wrong
  for days.

Every step larger than `step_s` is reported once, through `take_step()`, so the daemon can
write it to /daq/events next to the data it affects.
"""

from __future__ import annotations

import time
from collections.abc import Callable


class LogClock:
    """Callable like `time.time_ns`: the log time now, in ns since the UNIX epoch."""

    def __init__(self, wall_ns: Callable[[], int] = time.time_ns, *,
                 monotonic_ns: Callable[[], int] = time.monotonic_ns, step_s: float = 1.0,
                 slew: float = 0.5, max_slew_s: float = 86400.0):
        if not 0 < slew < 1:
            raise ValueError("slew must be between 0 and 1")
        self.wall_ns, self.monotonic_ns = wall_ns, monotonic_ns
        self.step_ns = int(step_s * 1e9)
        self.slew = slew
        self.max_slew_ns = int(max_slew_s * 1e9)
        self._last: tuple[int, int, int] | None = None  # (wall, monotonic, log time) last call
        self._steps: list[int] = []

    def __call__(self) -> int:
        wall, mono = self.wall_ns(), self.monotonic_ns()
        if self._last is None:
            out = wall
        else:
            last_wall, last_mono, last_out = self._last
            elapsed = mono - last_mono
            step = (wall - last_wall) - elapsed
            if abs(step) > self.step_ns:
                self._steps.append(step)
            behind = wall - (last_out + elapsed)  # > 0: the host clock is ahead of the log
            if behind >= 0 or -behind > self.max_slew_ns:
                out = wall
            else:
                out = last_out + elapsed - min(-behind, int(self.slew * elapsed))
        self._last = (wall, mono, out)
        return out

    def take_step(self) -> int | None:
        """The host clock steps (ns, negative = back) seen since the last call, summed;
        None when there was none."""
        if not self._steps:
            return None
        total, self._steps = sum(self._steps), []
        return total

    def describe(self, step_ns: int) -> str:
        s = step_ns / 1e9
        if s > 0:
            return f"host clock stepped forward by {s:.3f} s; log time follows it"
        if -step_ns > self.max_slew_ns:
            return (f"host clock stepped back by {-s:.3f} s, more than {self.max_slew_ns / 1e9:g} s: "
                    "log time follows it and goes back here")
        return (f"host clock stepped back by {-s:.3f} s; log time keeps going forward at "
                f"{1 - self.slew:g}x speed until the host clock catches up "
                f"(in {-s / self.slew:.3f} s)")
