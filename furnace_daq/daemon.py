"""The acquisition loop: poll the PLC (and read the flame scanners) on a fixed period, log
every sample with its quality to MCAP, and keep going whatever the PLC does.

Scheduling. Ticks sit on a grid of the monotonic clock (t0 + k * period), so the period never
drifts; when a tick is missed (a slow read, a stalled host) the loop skips to the next grid
point and counts the skipped ticks instead of bursting to catch up. A read never takes longer
than the PLC timeout.

Connection. The daemon starts whether or not the PLC answers; a connector task redials
while the PLC is down, and a run of failed polls drops the connection and hands it back to
the connector. A dial the PLC does not accept (refused, unreachable, unanswered) costs it no
session and is retried at a short fixed interval for the first minutes of an outage, so a
restarted PLC is polled within about a second of accepting connections; a PLC that accepts
and hangs up, or one down for longer, gets exponential backoff (capped). The first poll on a
new connection runs at once and the tick grid restarts there. Every change of state is one
message on /daq/status, so a gap in the data is always explained next to it.

Journal. Every change of connection state, every kind of failure and every event also goes
to stderr with an sd-daemon priority prefix, each kind rate-limited (statusreport), so
`journalctl -p err` shows why the data stopped.

Parts. This module is the loop and the wiring; each job it runs is a part that can be
driven alone: devicelink (a device's dialling, backoff and reads), samplemerge (several
devices as one, staleness), plcclock (publish time), messagebuild (log messages, the burner
comparison), statusreport (status messages, counters, journal lines), refitpump and
statewriter (online refits and their state files).

Time. log_time is host UTC at acquisition. publish_time is the PLC's clock when the map has
one: epoch + PLC seconds, the epoch given in the config or anchored at the first reading (and
re-anchored, with an event, when the PLC clock jumps back after a PLC restart). A step of
the host clock never reorders the log: log time follows a step forward and absorbs a step
back by running slow until the host clock catches up (logclock.LogClock); each step is a
clock_step event on /daq/events.

Refits. With a `refit:` section every furnace message the daemon logs is also fed to a
RefitRunner (refitworker), which cuts windows on the PLC clock and fits them in a worker
process; the loop only checks for finished fits once per tick. Results go to /model/* with
log_time = host time of the result and publish_time = the window's end on the data clock,
to `on_model`, and atomically to <state_dir>/model.json (written from a thread: a slow disk
must not delay a poll), with the chain's state in <state_dir>/refit_chain.json, from which
a restarted daemon goes on.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable
from typing import Protocol

from furnace_model.log.messages import (
    Ambient,
    AnyMessage,
    Burners,
    DaqEvent,
    DaqEventKind,
    Disturbances,
    Heat,
    Thermocouples,
)
from furnace_model.log.schema import DAQ_EVENTS

from .daqconfig import DaqConfig
from .devicelink import Link, sleep_unless
from .journal import NOTICE, Journal
from .logclock import LogClock
from .messagebuild import FlameComparison, MessageBuilder
from .plcclock import PlcClock
from .protocols import make_source
from .refitpump import RefitPump
from .samplemerge import merge
from .sdnotify import Notifier
from .sources import (
    CanSource,
    Sample,
    Source,
    SourceError,
)
from .statusreport import EVENT_PRIORITY, Counters, Reporter, summary

__all__ = ["EVENT_PRIORITY", "Counters", "Daemon", "Log", "summary"]
"""The journal's priorities, the counters and the closing summary are the status reporter's
(statusreport); they are named here too, where the daemon's users look for them."""


class Log(Protocol):
    error: str | None

    def write(self, topic: str, message: dict, log_time_ns: int,
              publish_time_ns: int | None = None) -> None: ...

    def maybe_flush(self, now_monotonic: float) -> None: ...

    def close(self) -> None: ...


class Daemon:
    def __init__(self, config: DaqConfig, log: Log, *, plc: Source | None = None,
                 flame: Source | None = None, notifier: Notifier | None = None,
                 wall_ns: Callable[[], int] = time.time_ns,
                 on_model: Callable[[dict], None] | None = None,
                 journal: Journal | None = None):
        self.config = config
        self.journal = journal if journal is not None else Journal(config.stderr_interval_s)
        self.log = log
        if plc is not None:  # a source given by the caller: the only device
            self.links = [Link(config.devices[0], plc, config.several_devices)]
        else:
            self.links = [Link(d, make_source(config, d), config.several_devices)
                          for d in config.devices]
        self.plc = self.links[0].source
        self.flame = flame
        if flame is None and config.burner_source in ("can", "both") and config.can is not None:
            self.flame = CanSource(config.can)
        self.notifier = notifier or Notifier({})
        self.wall_ns = LogClock(wall_ns)
        self.reporter = Reporter(config, self.links, self.journal, self.notifier,
                                 write=self._write, wall_ns=self.wall_ns,
                                 log_error=lambda: self.log.error)
        self.counters = self.reporter.counters
        self._stop = asyncio.Event()
        self._wake = asyncio.Event()  # stop, or a new connection to poll at once
        self._poll_now = False
        self._where = ", ".join(link.label for link in self.links)
        self.plc_clock = PlcClock(None if config.clock is None or config.clock.epoch is None
                                  else config.clock.epoch.value)
        self.messages = MessageBuilder(config)
        self.flame_comparison = FlameComparison(config.furnace.switched_zones,
                                                config.disagreement_polls)
        self.refit: RefitPump | None = None
        if config.refit is not None:
            self.refit = RefitPump(
                config.refit, t_air_default=config.ambient_default_c, furnace=config.furnace,
                wall_ns=self.wall_ns, event=self._event, tell=self.reporter.tell_event,
                log_write=lambda *args: self.log.write(*args),
                plc_clock_seen=lambda: self.plc_clock.seen, on_model=on_model)

    # -- life cycle ----------------------------------------------------------------------------
    def stop(self) -> None:
        self._stop.set()
        self._wake.set()

    async def run(self, duration_s: float | None = None) -> Counters:
        """Poll until stop() (SIGTERM) or `duration_s`; always ends with a finished log."""
        t_start = time.monotonic()
        for link in self.links:
            link.outage_since = t_start
        where = self._where
        self.notifier.ready(f"polling {where} every {self.config.poll_period_s:g} s")
        self.reporter.status("disconnected", f"starting; dialling PLC at {where}")
        if self.refit is not None:
            self.refit.start()
        tasks = [asyncio.create_task(
            link.keep_dialled(self._stop, on_dial=self.reporter.dialling,
                              on_failure=self.reporter.dial_failed,
                              on_connected=self._connected), name=f"{link.name} connector")
            for link in self.links]
        if self.flame is not None:
            tasks.append(asyncio.create_task(self._open_flame(), name="can connector"))
        try:
            # The first tick waits (at most one timeout) for the first dial, so a reachable
            # PLC's first sample is not lost to the connection set-up.
            first = [asyncio.create_task(link.connected.wait()) for link in self.links]
            await asyncio.wait(first, timeout=max(link.device.timeout_s for link in self.links))
            for task in first:
                task.cancel()
            t0 = time.monotonic()
            await self._loop(t0, None if duration_s is None else duration_s - (t0 - t_start))
        finally:
            self.notifier.stopping()
            for task in tasks:
                task.cancel()
            for task in tasks:
                with contextlib.suppress(asyncio.CancelledError):
                    await task
            for link in self.links:
                await link.source.close()
            if self.flame is not None:
                await self.flame.close()
            if self.refit is not None:
                await self.refit.finish(self.notifier.watchdog)
            self.journal.flush()
            self.reporter.status("disconnected", "stopping")
            self.log.close()
            self.notifier.close()
        return self.counters

    async def _loop(self, t0: float, duration_s: float | None) -> None:
        period = self.config.poll_period_s
        end = None if duration_s is None else t0 + duration_s
        k = 0
        while not self._stop.is_set():
            due = t0 + k * period
            if end is not None and due >= end:
                break
            delay = due - time.monotonic()
            if delay > 0 and not self._poll_now:
                self._wake.clear()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), delay)
                if self._stop.is_set():
                    break
            if self._poll_now:
                # A new connection is polled at once, not up to a period later, and the grid
                # restarts from here: that poll may follow the last one by less than a period.
                t0, k = time.monotonic(), 0
                if end is not None and t0 >= end:
                    break
            self._poll_now = False
            await self.tick()
            k += 1
            late = time.monotonic() - (t0 + k * period)
            if late > 0:  # the next grid point has passed already: skip, do not burst
                missed = int(late // period) + 1
                k += missed
                self.reporter.missed(missed)

    # -- one tick -----------------------------------------------------------------------------
    async def tick(self) -> None:
        """Read every source once, log what came back, feed the watchdog."""
        c = self.counters
        c.polls += 1
        log_ns = self.wall_ns()
        step = self.wall_ns.take_step()
        if step is not None:
            self._write(DaqEvent(DaqEventKind.CLOCK_STEP, self.wall_ns.describe(step),
                                 step_s=step / 1e9), log_ns, log_ns)
        plc_sample = await self._poll_devices(log_ns)
        flame_sample = None
        if self.flame is not None and self.flame.connected:
            with contextlib.suppress(SourceError):
                flame_sample = await self.flame.read()
                c.can_frames = getattr(self.flame, "frames", 0)
            if flame_sample is not None and flame_sample.burners is not None:
                self._write(self.messages.burners(flame_sample, "can"), log_ns, log_ns)
        if plc_sample is not None and flame_sample is not None:
            event = self.flame_comparison.compare(plc_sample, flame_sample)
            if event is not None:
                if event.kind == DaqEventKind.BURNER_DISAGREEMENT:
                    c.disagreements += 1
                self._write(event, log_ns, log_ns)
        if self.refit is not None:
            self.refit.pump()
        now = time.monotonic()
        self.reporter.periodic(now)
        self.log.maybe_flush(now)
        self.reporter.tell_log_error()
        self.journal.pump()
        self.notifier.watchdog(now)

    async def _poll_devices(self, log_ns: int) -> Sample | None:
        """Every device read at once, each within its own budget: one that hangs costs the
        tick its timeout but never the others' values. Returns the devices' samples merged
        (None when no device delivered); a device that failed or is away leaves its points
        comm_error, with the reason in the thermocouple message's `error`."""
        c = self.counters
        results = await asyncio.gather(*(self._read(link) for link in self.links))
        good: list[tuple[Link, Sample]] = []
        failed: list[tuple[Link, str, str]] = []
        missing: list[str] = []
        for link, (sample, failure) in zip(self.links, results, strict=True):
            if sample is not None:
                link.polled()
                link.last_stale = link.heartbeat.stale(sample.heartbeat, time.monotonic(),
                                                       self.config.stale_after_s)
                good.append((link, sample))
            elif failure is not None:
                reason, kind = failure
                link.poll_failed()
                self.reporter.poll_failed(link, reason, kind)
                failed.append((link, reason, kind))
                missing.append(link.named(reason))
            else:  # away: counted as the kind of the outage
                self.reporter.away(link)
                missing.append(link.named(f"not connected ({link.down_kind})"))
        merged: Sample | None = None
        if good:
            if len(good) == len(self.links):
                c.ok_polls += 1
            merged = merge(good, missing, self.config.furnace.switched_zones,
                           self.config.burner_source)
            self._log_plc(merged, log_ns)
            for link, sample in good:
                self.reporter.tell_sample(link, sample)
        elif failed:
            # no reading: the sensors' fields are absent (the schema has no null), quality says why
            self._write(self.messages.no_reading(missing), log_ns, log_ns)
        for link, reason, kind in failed:
            if link.failing:
                await link.source.close()
                self._lost(link, f"{link.consecutive_errors} failed polls in a row, last: "
                                 f"{reason}", kind)
        return merged

    async def _read(self, link: Link) -> tuple[Sample | None, tuple[str, str] | None]:
        if link.closed_by_peer:
            self._lost(link, "connection closed by the PLC", "connection lost")
        return await link.read()

    def _lost(self, link: Link, why: str, kind: str) -> None:
        link.lose(kind)
        self.reporter.lost(link, why)

    def plc_items(self) -> list:
        return [it for link in self.links for it in getattr(link.source, "items", ())]

    # -- logging a PLC sample -------------------------------------------------------------------
    def _log_plc(self, sample: Sample, log_ns: int) -> None:
        pub, reset = self.plc_clock.publish_ns(sample.plc_seconds, log_ns)
        if reset is not None:
            self._write(reset, log_ns, log_ns)
        for message in self.messages.readings(sample, pub):
            self._write(message, log_ns, pub)

    # -- connections ------------------------------------------------------------------------------
    def _connected(self, link: Link, attempt: int) -> None:
        self._poll_now = True  # poll at once, not at the next tick of the grid
        self._wake.set()
        self.reporter.connected(link, attempt)

    async def _open_flame(self) -> None:
        assert self.flame is not None
        attempt = 0
        while not self._stop.is_set() and not self.flame.connected:
            try:
                await self.flame.connect()
            except SourceError as exc:
                now = self.wall_ns()
                self._event(DaqEvent(DaqEventKind.CAN_UNAVAILABLE, str(exc)), now)
                await sleep_unless(self._stop, self.config.plc.reconnect.delay(attempt))
                attempt += 1
        if self.flame.connected and attempt:
            self.journal.say(NOTICE, "CAN bus open again", "event:can_unavailable")

    # -- writing ----------------------------------------------------------------------------------
    def _write(self, message: AnyMessage, log_ns: int, pub_ns: int) -> None:
        self.log.write(message.TOPIC, message.to_json(), log_ns, pub_ns)
        if isinstance(message, DaqEvent):
            self.reporter.tell_event(message)
        if self.refit is not None and isinstance(message, Thermocouples | Burners | Ambient
                                                 | Heat | Disturbances):
            self.refit.feed(message, pub_ns)

    def _event(self, message: DaqEvent, now_ns: int) -> None:
        """A /daq/events message, also told to the journal."""
        self.log.write(DAQ_EVENTS, message.to_json(), now_ns, now_ns)
        self.reporter.tell_event(message)

    @property
    def state(self) -> str:
        """connected when every device is (see Reporter.state)."""
        return self.reporter.state
