"""One Modbus device as the daemon keeps it: its source, its dialling and backoff, the
budget of one poll and the state of its connection.

Each device has its own link, so one that is down is redialled on its own schedule and never
marks the others' points. The link decides when to dial and how long a read may take; what
the daemon says about it (status messages, journal lines, counters) is told through the
callbacks it passes, so the schedule can be driven and checked without a log or a journal.

Schedule. A dial the device does not accept (refused, unreachable, no answer) costs it no
session and is retried every `retry_s` for the first `fast_for_s` of the outage, so a
restarted PLC is found within that interval. After that, and whenever a connection is lost
before one good poll (a PLC that accepts and hangs up at once, its connection limit reached),
the waits grow exponentially up to `max_s`, so such a PLC is not redialled at every tick.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable

from .deviceconfig import SERIAL_TRANSPORTS, PlcConfig
from .samplemerge import Heartbeat
from .sources import CONNECT_FAILURES, Sample, Source, SourceError, failure_kind

ReadOutcome = tuple[Sample | None, tuple[str, str] | None]
"""(sample, None), (None, (reason, kind)) when the poll failed, or (None, None) when the
device is away."""


async def sleep_unless(stop: asyncio.Event, seconds: float) -> None:
    """Wait `seconds`, or less when `stop` is set meanwhile: a stopping daemon must not sit
    out a backoff."""
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(stop.wait(), seconds)


class Link:
    """A device's source and the state of its connection and redials."""

    def __init__(self, device: PlcConfig, source: Source, named: bool):
        self.device, self.source = device, source
        self.name = device.name
        where = f"{getattr(source, 'host', '?')}:{getattr(source, 'port', '?')}"
        if device.transport in SERIAL_TRANSPORTS:
            where = device.where
        self.label = f"{device.name} ({where})" if named else where
        """How the journal names the device: host:port alone when it is the only one."""
        self.key = f"{device.name}:" if named else ""
        """Prefix of its journal kinds, so each device is rate-limited on its own."""
        self.state = "disconnected"
        self.detail = "starting"
        self.connected = asyncio.Event()
        self.need_dial = asyncio.Event()
        self.need_dial.set()
        self.consecutive_errors = 0
        self.dials_since_ok = 0  # dials since the last good poll: the backoff's step
        self.down_kind = "no connection yet"  # why the device is away, for the failure count
        self.outage_since = time.monotonic()  # the fast redial phase counts from here
        self.hangups = 0  # connections lost before one good poll: the backoff's step
        self.slow_steps = 0  # backoff waits after the fast redial phase
        self.connects = 0
        self.heartbeat = Heartbeat()
        self.was_stale = self.last_stale = False

    def named(self, text: str) -> str:
        """`text` prefixed with the device's name when the daemon has several devices."""
        return f"{self.name}: {text}" if self.key else text

    @property
    def read_budget_s(self) -> float:
        """The longest one poll of this device may take: its timeout, plus the pauses its
        workarounds ask for, its busy retries, and on a shared serial line the reads of
        the other devices it may wait behind."""
        n = len(getattr(self.source, "requests", ())) or 1
        return self.device.read_budget_s(n) + getattr(self.source, "line_wait_s", 0.0)

    # -- dialling ---------------------------------------------------------------------------
    def retry_after(self, kind: str, started: float, now: float) -> tuple[float, str]:
        """The wait before the next dial after one that failed with `kind` (started at
        `started`, failed at `now`, monotonic), and how the journal words the schedule."""
        backoff = self.device.reconnect
        self.down_kind = kind
        if kind in CONNECT_FAILURES and now - self.outage_since < backoff.fast_for_s:
            wait = max(0.0, backoff.fast_s - (now - started))  # start to start
            return wait, f"every {backoff.fast_s:g} s"
        wait = backoff.delay(self.slow_steps)
        self.slow_steps += 1
        return wait, f"in {wait:g} s (backing off up to {backoff.max_s:g} s)"

    async def keep_dialled(self, stop: asyncio.Event, *, on_dial: Callable[[], None],
                           on_failure: Callable[[Link, SourceError, int, float, str], None],
                           on_connected: Callable[[Link, int], None]) -> None:
        """Dial while disconnected, until `stop`. `on_dial()` before each dial,
        `on_failure(link, error, attempt, wait, how)` when one fails, `on_connected(link,
        attempt)` when one succeeds; `attempt` counts from 0 since the last good poll."""
        backoff = self.device.reconnect
        while not stop.is_set():
            if not self.need_dial.is_set():
                await self.need_dial.wait()
                if self.hangups:
                    await sleep_unless(stop, backoff.delay(self.hangups - 1))
                continue
            attempt = self.dials_since_ok
            self.dials_since_ok += 1
            on_dial()
            started = time.monotonic()
            try:
                await self.source.connect()
            except SourceError as exc:
                wait, how = self.retry_after(exc.kind, started, time.monotonic())
                on_failure(self, exc, attempt, wait, how)
                await sleep_unless(stop, wait)
                continue
            self.connects += 1
            self.consecutive_errors = 0
            self.heartbeat.reset()
            self.need_dial.clear()
            self.connected.set()
            on_connected(self, attempt)

    def lose(self, kind: str) -> None:
        """The connection is given up (`kind` of failure): the dialler takes over. Lost
        before one good poll, it counts as a hang-up and the next dial backs off; lost after
        a good poll, an outage starts now."""
        self.connected.clear()
        self.need_dial.set()
        self.consecutive_errors = 0
        self.down_kind = kind
        if self.dials_since_ok:  # lost before one good poll: the PLC accepts and hangs up
            self.hangups += 1
        else:  # the last poll was good: an outage starts here
            self.outage_since = time.monotonic()

    # -- polling ----------------------------------------------------------------------------
    @property
    def closed_by_peer(self) -> bool:
        """Connected as far as the daemon knows, but the source found its connection gone."""
        return self.connected.is_set() and not self.source.connected

    async def read(self) -> ReadOutcome:
        """One poll within the read budget; whatever goes wrong is a failure, never an
        exception, so a malformed reply cannot end acquisition."""
        if not self.connected.is_set():
            return None, None
        try:
            return await asyncio.wait_for(self.source.read(), self.read_budget_s), None
        except (SourceError, TimeoutError, OSError) as exc:
            return None, (str(exc) or "timeout", failure_kind(exc))
        except Exception as exc:  # a malformed reply must not end acquisition
            return None, (f"{type(exc).__name__}: {exc}", failure_kind(exc))

    def polled(self) -> None:
        """A good poll: the redial schedule starts afresh at the next outage."""
        self.consecutive_errors = self.dials_since_ok = 0
        self.hangups = self.slow_steps = 0

    def poll_failed(self) -> None:
        self.consecutive_errors += 1

    @property
    def failing(self) -> bool:
        """Whether the run of failed polls is long enough to drop the connection: a
        device that answers nothing on an open connection is redialled."""
        return self.consecutive_errors >= self.device.max_consecutive_errors
