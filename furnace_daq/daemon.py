"""The acquisition loop: poll the PLC (and read the flame scanners) on a fixed period, log
every sample with its quality to MCAP, and keep going whatever the PLC does.

Scheduling. Ticks sit on a grid of the monotonic clock (t0 + k * period), so the period never
drifts; when a tick is missed (a slow read, a stalled host) the loop skips to the next grid
point and counts the skipped ticks instead of bursting to catch up. A read never takes longer
than the PLC timeout.

Connection. The daemon starts whether or not the PLC answers; a connector task dials with
exponential backoff (capped) while the PLC is down, and a run of failed polls drops the
connection and hands it back to the connector. Every change of state is one message on
/daq/status, so a gap in the data is always explained next to it.

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
import json
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Protocol

from furnace_model import SENSORS, ZONES
from furnace_model.logschema import (
    AMBIENT,
    BURNERS,
    DAQ_EVENTS,
    DAQ_STATUS,
    MODEL_PARAMETERS,
    THERMOCOUPLES,
)

from .daqconfig import DaqConfig
from .logclock import LogClock
from .refitworker import RefitRunner
from .registers import COMM_ERROR, OK, STALE
from .sdnotify import Notifier
from .sources import CanSource, ModbusSource, Sample, Source, SourceError
from .statefile import write_json_atomic

MODEL_FILE = "model.json"
CHAIN_FILE = "refit_chain.json"
STOP_WAIT_S = 10.0
"""At stop, how long windows already cut may still be fitted."""
FURNACE_TOPICS = frozenset((THERMOCOUPLES, BURNERS, AMBIENT))


class Log(Protocol):
    error: str | None

    def write(self, topic: str, message: dict, log_time_ns: int,
              publish_time_ns: int | None = None) -> None: ...

    def maybe_flush(self, now_monotonic: float) -> None: ...

    def close(self) -> None: ...


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


class Daemon:
    def __init__(self, config: DaqConfig, log: Log, *, plc: Source | None = None,
                 flame: Source | None = None, notifier: Notifier | None = None,
                 wall_ns: Callable[[], int] = time.time_ns,
                 on_model: Callable[[dict], None] | None = None):
        self.config = config
        self.log = log
        self.plc = plc if plc is not None else ModbusSource(config)
        self.flame = flame
        if flame is None and config.burner_source in ("can", "both") and config.can is not None:
            self.flame = CanSource(config.can)
        self.notifier = notifier or Notifier({})
        self.wall_ns = LogClock(wall_ns)
        self.counters = Counters()
        self.state = "disconnected"
        self.detail = "starting"
        self._stop = asyncio.Event()
        self._connected = asyncio.Event()
        self._need_dial = asyncio.Event()
        self._need_dial.set()
        self._missed_unreported = 0
        self._last_missed_event = float("-inf")
        self._consecutive_errors = 0
        self._dials_since_ok = 0  # dials since the last good poll: the backoff's step
        self._epoch_ns: int | None = None
        if config.clock is not None and config.clock.epoch is not None:
            self._epoch_ns = config.clock.epoch.value
        self._last_plc_s: float | None = None
        self._heartbeat: tuple[float, float] | None = None  # (value, monotonic time it changed)
        self._disagree: tuple[frozenset[str], int] = (frozenset(), 0)
        self._reported_disagreement: frozenset[str] = frozenset()
        self._last_status_mono = float("-inf")
        self._log_error_told: str | None = None
        self.on_model = on_model
        self.refit: RefitRunner | None = None
        if config.refit is not None:
            self.refit = RefitRunner(config.refit, self._model_message,
                                     t_air_default=config.ambient_default_c,
                                     max_queue=config.refit.queue_max)
        self._state_writer: ThreadPoolExecutor | None = None
        self._state_error: str | None = None  # set by the writer thread
        self._state_reported: str | None = None

    # -- life cycle ----------------------------------------------------------------------------
    def stop(self) -> None:
        self._stop.set()

    async def run(self, duration_s: float | None = None) -> Counters:
        """Poll until stop() (SIGTERM) or `duration_s`; always ends with a finished log."""
        t_start = time.monotonic()
        where = f"{getattr(self.plc, 'host', '?')}:{getattr(self.plc, 'port', '?')}"
        self.notifier.ready(f"polling {where} every {self.config.poll_period_s:g} s")
        self._status("disconnected", f"starting; dialling PLC at {where}")
        if self.refit is not None:
            self._resume_chain()
            self.refit.start()
            self._state_writer = ThreadPoolExecutor(1, thread_name_prefix="state-writer")
        tasks = [asyncio.create_task(self._connector(self.plc), name="plc connector")]
        if self.flame is not None:
            tasks.append(asyncio.create_task(self._open_flame(), name="can connector"))
        try:
            # The first tick waits (at most one timeout) for the first dial, so a reachable
            # PLC's first sample is not lost to the connection set-up.
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._connected.wait(), self.config.plc.timeout_s)
            t0 = time.monotonic()
            await self._loop(t0, None if duration_s is None else duration_s - (t0 - t_start))
        finally:
            self.notifier.stopping()
            for task in tasks:
                task.cancel()
            for task in tasks:
                with contextlib.suppress(asyncio.CancelledError):
                    await task
            await self.plc.close()
            if self.flame is not None:
                await self.flame.close()
            await self._finish_refits()
            self._status("disconnected", "stopping")
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
            if delay > 0:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._stop.wait(), delay)
                if self._stop.is_set():
                    break
            await self.tick()
            k += 1
            late = time.monotonic() - (t0 + k * period)
            if late > 0:  # the next grid point has passed already: skip, do not burst
                missed = int(late // period) + 1
                k += missed
                self.counters.skipped_ticks += missed
                self._missed(missed)

    def _missed(self, n: int) -> None:
        """One /daq/events message per status interval at most, however long a stall."""
        self._missed_unreported += n
        now = time.monotonic()
        if now - self._last_missed_event >= self.config.status_interval_s:
            self._last_missed_event = now
            wall = self.wall_ns()
            self._write(DAQ_EVENTS, {"kind": "missed_tick", "detail":
                                     f"{self._missed_unreported} poll tick(s) skipped: a poll "
                                     "or the host was slower than the period",
                                     "skipped": self._missed_unreported}, wall, wall)
            self._missed_unreported = 0

    # -- one tick -----------------------------------------------------------------------------
    async def tick(self) -> None:
        """Read every source once, log what came back, feed the watchdog."""
        c = self.counters
        c.polls += 1
        log_ns = self.wall_ns()
        step = self.wall_ns.take_step()
        if step is not None:
            self._write(DAQ_EVENTS, {"kind": "clock_step", "detail": self.wall_ns.describe(step),
                                     "step_s": step / 1e9}, log_ns, log_ns)
        plc_sample: Sample | None = None
        if self._connected.is_set() and not self.plc.connected:
            self._lost("connection closed by the PLC")
        if self._connected.is_set():
            try:
                plc_sample = await asyncio.wait_for(self.plc.read(), self.config.plc.timeout_s)
            except (SourceError, TimeoutError, OSError) as exc:
                await self._poll_failed(log_ns, str(exc) or "timeout")
            except Exception as exc:  # a malformed reply must not end acquisition
                await self._poll_failed(log_ns, f"{type(exc).__name__}: {exc}")
            else:
                self._consecutive_errors = self._dials_since_ok = 0
                c.ok_polls += 1
                self._log_plc(plc_sample, log_ns)
        flame_sample = None
        if self.flame is not None and self.flame.connected:
            with contextlib.suppress(SourceError):
                flame_sample = await self.flame.read()
                c.can_frames = getattr(self.flame, "frames", 0)
            if flame_sample is not None and flame_sample.burners is not None:
                self._write(BURNERS, self._burner_message(flame_sample, "can"), log_ns, log_ns)
        if plc_sample is not None and flame_sample is not None:
            self._compare_burners(plc_sample, flame_sample, log_ns)
        if self.refit is not None:
            self._pump_refits()
        now = time.monotonic()
        if now - self._last_status_mono >= self.config.status_interval_s:
            self._status(self.state, self.detail)
        self.log.maybe_flush(now)
        if self.log.error != self._log_error_told:  # a full disk is news at once, journal too
            self._log_error_told = self.log.error
            print(f"log: {self.log.error or 'writing again'}", file=sys.stderr, flush=True)
            self._status(self.state, self.detail)
        self.notifier.watchdog(now)

    async def _poll_failed(self, log_ns: int, reason: str) -> None:
        self.counters.comm_errors += 1
        self._consecutive_errors += 1
        msg: dict = {s: None for s in SENSORS}
        msg["quality"] = {s: COMM_ERROR for s in SENSORS}
        msg["error"] = reason
        self._write(THERMOCOUPLES, msg, log_ns, log_ns)
        if self._consecutive_errors >= self.config.plc.max_consecutive_errors:
            await self.plc.close()
            self._lost(f"{self._consecutive_errors} failed polls in a row, last: {reason}")

    def _lost(self, why: str) -> None:
        self._connected.clear()
        self._need_dial.set()
        self._consecutive_errors = 0
        self.counters.disconnects += 1
        self._status("disconnected", why)

    # -- logging a PLC sample -------------------------------------------------------------------
    def _publish_ns(self, sample: Sample, log_ns: int) -> int:
        s = sample.plc_seconds
        if s is None:
            return log_ns
        if self._last_plc_s is not None and s < self._last_plc_s and \
                (self.config.clock is None or self.config.clock.epoch is None):
            self._write(DAQ_EVENTS, {"kind": "plc_clock_reset",
                                     "detail": f"PLC clock went back from {self._last_plc_s:g} s "
                                               f"to {s:g} s; publish time re-anchored"},
                        log_ns, log_ns)
            self._epoch_ns = None
        self._last_plc_s = s
        if self._epoch_ns is None:
            self._epoch_ns = log_ns - int(round(s * 1e9))
        return self._epoch_ns + int(round(s * 1e9))

    def _stale(self, sample: Sample) -> bool:
        if sample.heartbeat is None:
            return False
        now = time.monotonic()
        if self._heartbeat is None or sample.heartbeat != self._heartbeat[0]:
            self._heartbeat = (sample.heartbeat, now)
            return False
        return now - self._heartbeat[1] > self.config.stale_after_s

    def _log_plc(self, sample: Sample, log_ns: int) -> None:
        pub = self._publish_ns(sample, log_ns)
        stale = self._stale(sample)
        quality = {k: (STALE if stale and q == OK else q) for k, q in sample.quality.items()}
        tc: dict = {s: sample.values.get(s) for s in SENSORS}
        tc["quality"] = {s: quality.get(s, COMM_ERROR) for s in SENSORS}
        if sample.plc_seconds is not None:
            tc["plc_seconds"] = sample.plc_seconds
        if sample.errors:  # blocks the PLC refused: why some points are comm_error
            tc["error"] = "; ".join(sample.errors)
        self._write(THERMOCOUPLES, tc, log_ns, pub)
        if self.config.ambient is not None:
            amb = {"t_air": sample.values.get("t_air"), "quality": quality.get("t_air", COMM_ERROR)}
        else:
            amb = {"t_air": self.config.ambient_default_c, "quality": OK, "from_config": True}
        self._write(AMBIENT, amb, log_ns, pub)
        if sample.burners is not None:
            sample.burner_quality = STALE if stale else sample.burner_quality
            self._write(BURNERS, self._burner_message(sample, "modbus"), log_ns, pub)

    @staticmethod
    def _burner_message(sample: Sample, source: str) -> dict:
        assert sample.burners is not None
        msg: dict = {z: sample.burners[z] for z in ZONES}
        msg.update({f"count_{z}": sum(sample.burners[z]) for z in ZONES})
        msg["source"] = source
        msg["quality"] = sample.burner_quality
        return msg

    def _compare_burners(self, plc: Sample, flame: Sample, log_ns: int) -> None:
        """An event when PLC states and flame scanners disagree for `disagreement_polls`
        polls in a row, and one when they agree again: a burner commanded on whose flame
        is out (or the reverse) is what an operator must see."""
        if plc.burners is None or flame.burners is None or plc.burner_quality != OK \
                or flame.burner_quality != OK:
            return
        diff = frozenset(f"{z}[{i}]" for z in ZONES
                         for i, (a, b) in enumerate(zip(plc.burners[z], flame.burners[z],
                                                        strict=True)) if a != b)
        seen, n = self._disagree
        n = n + 1 if diff == seen else 1
        self._disagree = (diff, n)
        if diff == self._reported_disagreement or n < self.config.disagreement_polls:
            return
        self._reported_disagreement = diff
        if diff:
            self.counters.disagreements += 1
            detail = f"PLC and flame scanners disagree on {', '.join(sorted(diff))}"
            kind = "burner_disagreement"
        else:
            detail, kind = "PLC and flame scanners agree again", "burner_agreement"
        self._write(DAQ_EVENTS, {"kind": kind, "detail": detail, "burners": sorted(diff),
                                 "plc": plc.burners, "flame": flame.burners}, log_ns, log_ns)

    # -- connections ------------------------------------------------------------------------------
    async def _connector(self, source: Source) -> None:
        """Dial while disconnected, waiting longer after each failure (capped). A connection
        lost before one good poll counts as a failure too: a PLC that accepts and hangs up at
        once (its connection limit reached) must not be redialled at every tick."""
        delay = self.config.plc.reconnect.delay
        while not self._stop.is_set():
            if not self._need_dial.is_set():
                await self._need_dial.wait()
                if self._dials_since_ok:
                    await self._sleep(delay(self._dials_since_ok - 1))
                continue
            attempt = self._dials_since_ok
            self._dials_since_ok += 1
            self.counters.connect_attempts += 1
            try:
                await source.connect()
            except SourceError as exc:
                self.detail = f"{exc}; retry {attempt + 1} in {delay(attempt):g} s"
                await self._sleep(delay(attempt))
                continue
            self.counters.connects += 1
            self._consecutive_errors = 0
            self._heartbeat = None
            self._need_dial.clear()
            self._connected.set()
            self._status("connected", f"connected after {attempt + 1} attempt(s)")

    async def _open_flame(self) -> None:
        assert self.flame is not None
        attempt = 0
        while not self._stop.is_set() and not self.flame.connected:
            try:
                await self.flame.connect()
            except SourceError as exc:
                now = self.wall_ns()
                self._write(DAQ_EVENTS, {"kind": "can_unavailable", "detail": str(exc)}, now, now)
                await self._sleep(self.config.plc.reconnect.delay(attempt))
                attempt += 1

    async def _sleep(self, seconds: float) -> None:
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._stop.wait(), seconds)

    # -- status -----------------------------------------------------------------------------------
    def _status(self, state: str, detail: str) -> None:
        self.state, self.detail = state, detail
        self._last_status_mono = time.monotonic()
        now = self.wall_ns()
        msg = {"state": state, "detail": detail, **asdict(self.counters),
               "period_s": self.config.poll_period_s}
        if self.log.error:
            msg["log_error"] = self.log.error
        self._write(DAQ_STATUS, msg, now, now)
        self.notifier.status(self._status_line())

    def _status_line(self) -> str:
        c = self.counters
        line = (f"{self.state}: {c.ok_polls}/{c.polls} polls ok, {c.comm_errors} errors, "
                f"{c.skipped_ticks} skipped, {c.disconnects} drops")
        return line + (f"; LOG: {self.log.error}" if self.log.error else "")

    def _write(self, topic: str, message: dict, log_ns: int, pub_ns: int) -> None:
        self.log.write(topic, message, log_ns, pub_ns)
        if self.refit is not None and topic in FURNACE_TOPICS:
            self._guarded(self.refit.feed, topic, message, pub_ns)

    # -- refits -----------------------------------------------------------------------------------
    def _guarded(self, call: Callable, *args) -> None:
        """Online identification is a guest of the acquisition: whatever goes wrong in it is
        an event, never the end of polling."""
        try:
            call(*args)
        except Exception as exc:  # noqa: BLE001
            now = self.wall_ns()
            self.log.write(DAQ_EVENTS, {"kind": "refit_error",
                                        "detail": f"refit pipeline: {type(exc).__name__}: {exc}"},
                           now, now)

    def _pump_refits(self) -> None:
        assert self.refit is not None
        self._guarded(self.refit.pump)
        self._report_state_error()

    def _report_state_error(self) -> None:
        error = self._state_error
        if error != self._state_reported:
            self._state_reported = error
            if error is not None:
                now = self.wall_ns()
                self.log.write(DAQ_EVENTS, {"kind": "state_write_failed",
                                            "detail": f"latest model not saved: {error}"},
                               now, now)

    def _model_message(self, topic: str, message: dict, pub_ns: int) -> None:
        self.log.write(topic, message, self.wall_ns(), pub_ns)
        if topic != MODEL_PARAMETERS:
            return
        if self.on_model is not None:
            try:
                self.on_model(message)
            except Exception as exc:  # noqa: BLE001 - a consumer's bug is not ours to die of
                now = self.wall_ns()
                self.log.write(DAQ_EVENTS, {"kind": "on_model_error",
                                            "detail": f"{type(exc).__name__}: {exc}"}, now, now)
        if self._state_writer is not None and self.config.refit is not None:
            state_dir = self.config.refit.state_dir
            files = [(state_dir / MODEL_FILE, message)]
            if self.refit is not None:  # the chain has taken this window in already
                files.append((state_dir / CHAIN_FILE, self.refit.chain.state()))
            self._state_writer.submit(self._write_state, files)

    def _resume_chain(self) -> None:
        """Go on with the model in force and the drift references a previous run left, so
        that a restart neither forgets the model nor starts drift detection afresh. A state
        file that cannot be used is reported and set aside; the chain then starts empty."""
        assert self.refit is not None and self.config.refit is not None
        path = self.config.refit.state_dir / CHAIN_FILE
        now = self.wall_ns()
        try:
            self.refit.chain.restore(json.loads(path.read_text(encoding="utf-8")))
        except FileNotFoundError:
            return
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            detail = f"{path}: {getattr(exc, 'strerror', None) or exc}; refits start afresh"
            self.log.write(DAQ_EVENTS, {"kind": "state_unusable", "detail": detail}, now, now)
            return
        model = self.refit.chain.model
        detail = (f"from {path}: model of the window to {model['window_end']}"
                  if model is not None else f"from {path}: no model fitted yet")
        self.log.write(DAQ_EVENTS, {"kind": "refit_resumed", "detail": detail}, now, now)

    def _write_state(self, files: list[tuple[Path, dict]]) -> None:
        """In the writer thread; a failure is remembered and reported once per kind."""
        for path, value in files:
            try:
                write_json_atomic(path, value)
            except (OSError, ValueError, TypeError) as exc:
                self._state_error = f"{path}: {getattr(exc, 'strerror', None) or exc}"
                return
        self._state_error = None

    async def _finish_refits(self) -> None:
        """At stop: give the windows already cut their fit (bounded), then end the worker."""
        if self.refit is None:
            return
        # systemd gives a stopping unit 30 s (TimeoutStopSec): a fit in hand gets part of it
        deadline = time.monotonic() + min(self.refit.kill_after_s, STOP_WAIT_S)
        while self.refit.busy() and time.monotonic() < deadline:
            self._pump_refits()
            self.notifier.watchdog()
            await asyncio.sleep(0.01)
        left = len(self.refit.queue) + (self.refit.in_flight is not None)
        if left:
            now = self.wall_ns()
            self.log.write(DAQ_EVENTS, {"kind": "refit_abandoned", "detail":
                                        f"{left} refit window(s) not fitted at stop"}, now, now)
        self.refit.close()
        if self._state_writer is not None:
            self._state_writer.shutdown(wait=True)
        self._report_state_error()
