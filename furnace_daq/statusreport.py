"""What the daemon says about itself: /daq/status messages on every change of connection
state (and periodically), the counters they carry, and the journal lines of troubles and of
their end.

Journal. Every change of connection state, every kind of failure and every event goes to
stderr with an sd-daemon priority prefix (journal.Journal: `<3>` errors, `<4>` warnings,
`<5>` notices), each kind at most once per `stderr_interval_s` with a count of the repeats,
so `journalctl -p err` shows why the data stopped. The end of a trouble the journal was told
of is always told. Failed polls are counted by kind (`Counters.failures`): a tick while
disconnected counts as the kind of the outage.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

from furnace_model.log.messages import (
    AnyMessage,
    DaqEvent,
    DaqEventKind,
    DaqStatus,
    Event,
    ModelEventKind,
)

from .daqconfig import DaqConfig
from .devicelink import Link
from .journal import ERR, INFO, NOTICE, WARNING, Journal
from .registers import COMM_ERROR, OK, STALE
from .sdnotify import Notifier
from .sources import Sample, SourceError

_D, _M = DaqEventKind, ModelEventKind
EVENT_PRIORITY: dict[DaqEventKind | ModelEventKind, int] = {
    _D.CAN_UNAVAILABLE: ERR, _D.REFIT_ERROR: ERR, _D.STATE_WRITE_FAILED: ERR,
    _D.ON_MODEL_ERROR: ERR, _D.WRITE_BACK_FAILED: ERR,
    _D.CLOCK_STEP: WARNING, _D.MISSED_TICK: WARNING, _D.BURNER_DISAGREEMENT: WARNING,
    _D.STATE_UNUSABLE: WARNING, _D.REFIT_ABANDONED: WARNING, _M.WINDOW_DROPPED: WARNING,
    _D.LOG_RECOVERED: WARNING, _D.LOG_GAP: WARNING,
    _D.PLC_CLOCK_RESET: NOTICE, _D.BURNER_AGREEMENT: NOTICE, _D.WRITE_BACK_OK: NOTICE,
    _M.DRIFT: NOTICE, _M.DIAGNOSIS: NOTICE, _M.DIAGNOSIS_FAILED: WARNING,
    _M.SENSOR_SET_ASIDE: WARNING,
    _D.REFIT_RESUMED: INFO,
}
"""Journal priority of each /daq/events and /model/events kind (others: notice). The kinds
are str-valued, so a kind read back as its name finds its priority too."""


@dataclass
class Counters:
    polls: int = 0
    ok_polls: int = 0
    comm_errors: int = 0
    skipped_ticks: int = 0
    connects: int = 0
    disconnects: int = 0
    connect_attempts: int = 0
    can_frames: int = 0
    disagreements: int = 0
    failures: dict[str, int] = field(default_factory=dict)
    """Polls that gave no data, by kind ('connection refused', 'poll timeout', ...); a tick
    while disconnected counts as the kind of failure that keeps the PLC away."""
    incomplete: dict[str, int] = field(default_factory=dict)
    """Polls that were logged with a part of the map the PLC answered without a value (a
    refused block, an S7 area or OPC UA node it has not got), by that part and why."""


def _by_kind(counts: dict[str, int]) -> str:
    return ", ".join(f"{n} {kind}" for kind, n in sorted(counts.items(), key=lambda kv: -kv[1]))


def summary(counters: Counters) -> tuple[int, str]:
    """The journal priority and text of the line the daemon ends with: the counters, then
    the failed polls by kind, so the journal says why there was no data without the log."""
    c = counters
    text = (f"stopped: {c.ok_polls}/{c.polls} polls ok, {c.comm_errors} errors, "
            f"{c.skipped_ticks} skipped ticks, {c.disconnects} drops")
    failed = sum(c.failures.values())
    if failed:
        text += f"; {failed} failed: {_by_kind(c.failures)}"
    if c.incomplete:
        text += f"; {sum(c.incomplete.values())} incomplete: {_by_kind(c.incomplete)}"
    priority = INFO
    if failed or c.incomplete:
        priority = ERR if c.polls and not c.ok_polls else WARNING
    return priority, text


class Reporter:
    """The daemon's status messages, counters and journal lines. Messages go out through
    `write` (the daemon's, which logs them and tells the journal of events); `log_error()`
    is the log's trouble, if any, which every status message carries."""

    def __init__(self, config: DaqConfig, links: Sequence[Link], journal: Journal,
                 notifier: Notifier, *, write: Callable[[AnyMessage, int, int], None],
                 wall_ns: Callable[[], int], log_error: Callable[[], str | None]):
        self.config, self.links, self.journal, self.notifier = config, links, journal, notifier
        self.write, self.wall_ns, self.log_error = write, wall_ns, log_error
        self.counters = Counters()
        self.detail = "starting"
        self._qualities: dict[str, str] = {}  # last quality of each point, told on change
        self._told_bad: set[str] = set()  # kinds whose bad news reached the journal
        self._last_status_mono = float("-inf")
        self._log_error_told: str | None = None
        self._missed_unreported = 0
        self._last_missed_event = float("-inf")

    @property
    def state(self) -> str:
        """connected when every device is; a device away makes the daemon disconnected
        (its points are missing), whichever device it is."""
        return "connected" if all(link.state == "connected" for link in self.links) \
            else "disconnected"

    def status(self, state: str | None, detail: str, link: Link | None = None) -> None:
        """A /daq/status message. With `link`, that device's state changed to `state`
        (named in `device`); without, `state` applies to every device (start, stop), None
        to none (a periodic or log-error message). `devices` holds each device's state."""
        if link is not None and state is not None:
            link.state, link.detail = state, detail
            detail = link.named(detail)
        elif state is not None:
            for each in self.links:
                each.state = state
        self.detail = detail
        self._last_status_mono = time.monotonic()
        now = self.wall_ns()
        msg = DaqStatus(self.state, detail, **asdict(self.counters),
                        period_s=self.config.poll_period_s,
                        devices={each.name: each.state for each in self.links},
                        device=None if link is None else link.name,
                        log_error=self.log_error() or None)
        self.write(msg, now, now)
        self.notifier.status(self.status_line())

    def status_line(self) -> str:
        c = self.counters
        line = (f"{self.state}: {c.ok_polls}/{c.polls} polls ok, {c.comm_errors} errors, "
                f"{c.skipped_ticks} skipped, {c.disconnects} drops")
        error = self.log_error()
        return line + (f"; LOG: {error}" if error else "")

    def periodic(self, now: float) -> None:
        """A status message when none went out for `status_interval_s` (monotonic `now`):
        the log says the daemon is alive and what it counted even when nothing changes."""
        if now - self._last_status_mono >= self.config.status_interval_s:
            self.status(None, self.detail)

    def tell_log_error(self) -> None:
        """A full disk (or its end) is news at once, to the journal and in a status
        message."""
        error = self.log_error()
        if error != self._log_error_told:
            self._log_error_told = error
            if error:
                self.journal.say(ERR, f"log: {error}")
            else:
                self.journal.say(NOTICE, "log: writing again")
            self.status(None, self.detail)

    def tell_event(self, message: Event) -> None:
        kind = str(message.kind)
        self.journal.say(EVENT_PRIORITY.get(message.kind, NOTICE),  # type: ignore[call-overload]
                         f"{kind}: {message.detail}", f"event:{kind}")

    def missed(self, n: int) -> None:
        """`n` ticks skipped: counted at once, but one /daq/events message per status
        interval at most, however long a stall."""
        self.counters.skipped_ticks += n
        self._missed_unreported += n
        now = time.monotonic()
        if now - self._last_missed_event >= self.config.status_interval_s:
            self._last_missed_event = now
            wall = self.wall_ns()
            self.write(DaqEvent(DaqEventKind.MISSED_TICK,
                                f"{self._missed_unreported} poll tick(s) skipped: a poll "
                                "or the host was slower than the period",
                                skipped=self._missed_unreported), wall, wall)
            self._missed_unreported = 0

    def tell_sample(self, link: Link, sample: Sample) -> None:
        """The journal hears of what the PLC answers without a value (a refused block, an
        area or a node it has not got) and of each point whose quality changes, not of
        every poll that repeats them."""
        keys = self.config.key_paths()
        for unread in sample.unread:
            self.count_failure(unread.kind, self.counters.incomplete)
            names = ", ".join(keys.get(n, n) for n in unread.items) or "no point"
            self.journal.say(ERR, f"PLC {link.label}: {unread.what}: {names} not read "
                                  "(check the map)", f"{link.key}unread:{unread.kind}")
        stale = link.was_stale
        for name, quality in sample.quality.items():
            before = self._qualities.get(name, OK)
            self._qualities[name] = quality
            if quality == before or quality in (COMM_ERROR, STALE):
                continue  # what was not read is told above, staleness below
            key = keys.get(name, name)
            if quality == OK:
                self.good_news(NOTICE, f"{key}: ok again", f"quality:{name}")
            else:
                self.bad_news(WARNING, f"{key}: {quality}", f"quality:{name}")
        now_stale = link.last_stale
        if now_stale != stale:
            link.was_stale = now_stale
            if now_stale:
                self.bad_news(WARNING, f"PLC {link.label}: values stale, heartbeat "
                                        f"unchanged for {self.config.stale_after_s:g} s "
                                        "(PLC program stopped?)", f"{link.key}stale")
            else:
                self.good_news(NOTICE, f"PLC {link.label}: values moving again",
                                f"{link.key}stale")

    def bad_news(self, priority: int, text: str, kind: str) -> None:
        if self.journal.say(priority, text, kind):
            self._told_bad.add(kind)
        else:
            self._told_bad.discard(kind)

    def good_news(self, priority: int, text: str, kind: str, first: bool = False) -> None:
        """The end of a trouble the journal was told of is always told: a reader must not
        be left believing the PLC is still away. Recoveries from troubles it was not told
        of (held back as repeats) are rate-limited like them."""
        if first or kind in self._told_bad:
            self._told_bad.discard(kind)
            self.journal.say(priority, text)
        else:
            self.journal.say(priority, text, f"{kind}:recovered")

    def count_failure(self, kind: str, counts: dict[str, int] | None = None) -> None:
        counts = self.counters.failures if counts is None else counts
        counts[kind] = counts.get(kind, 0) + 1

    # -- a device's connection and polls ----------------------------------------------------
    def dialling(self) -> None:
        self.counters.connect_attempts += 1

    def dial_failed(self, link: Link, exc: SourceError, attempt: int, wait: float,
                    how: str) -> None:
        link.detail = self.detail = link.named(f"{exc}; retry {attempt + 1} in {wait:.3g} s")
        self.journal.say(ERR, f"PLC {link.label}: {exc}; retrying {how}"
                         if link.key else f"PLC: {exc}; retrying {how}",
                         f"{link.key}dial:{exc.kind}")

    def connected(self, link: Link, attempt: int) -> None:
        self.counters.connects += 1
        self.status("connected", f"connected after {attempt + 1} attempt(s)", link)
        again = "" if link.connects == 1 else \
            f", {time.monotonic() - link.outage_since:.1f} s after it went away"
        self.good_news(NOTICE, f"PLC {link.label}: connected after {attempt + 1} "
                               f"attempt(s){again}", f"{link.key}lost",
                       first=link.connects == 1)

    def lost(self, link: Link, why: str) -> None:
        self.counters.disconnects += 1
        self.status("disconnected", why, link)
        self.bad_news(ERR, f"PLC {link.label}: connection lost: {why}", f"{link.key}lost")

    def poll_failed(self, link: Link, reason: str, kind: str) -> None:
        self.counters.comm_errors += 1
        self.count_failure(link.named(kind))
        self.journal.say(WARNING, f"PLC {link.label}: poll failed ({kind}): {reason}",
                         f"{link.key}poll:{kind}")

    def away(self, link: Link) -> None:
        """A tick while the device is away counts as the kind of the outage."""
        self.count_failure(link.named(link.down_kind))
