"""Refits in a separate process, so that the poll loop never waits on a fit, and a fit that
hangs, crashes or eats memory can be killed without touching acquisition.

`RefitWorker` is one child process (started with 'spawn': no inherited event loop, sockets
or locks) reading jobs from a pipe and sending back results. `RefitRunner` is what the daemon
and replay hold: it cuts windows (refit.WindowCutter), keeps them in a FIFO, hands them one
at a time to the worker, feeds the outcomes to the chain (refit.RefitChain) and emits the
messages. One window in flight at a time: with `method: polish` window k + 1 starts from
window k.

Failures. A worker that dies, or runs past `KILL_FACTOR` x budget (+ `KILL_MARGIN_S`) of wall
time, is killed and started anew; that window is published with status `failed` and the
model in force is kept. When windows arrive faster than they are fitted, the queue holds
`max_queue` of them; beyond that the oldest is dropped with a /model/events message
(kind `window_dropped`). Replay passes `max_queue=None` and waits instead, since it can.
"""

from __future__ import annotations

import multiprocessing as mp
import signal
import time
from collections import deque
from collections.abc import Callable
from multiprocessing.connection import Connection

from furnace_model.diagnosis.verdict import NAMING
from furnace_model.log.messages import (
    FurnaceMessage,
    ModelDiagnosis,
    ModelEvent,
    ModelEventKind,
    ModelParameters,
)
from furnace_model.log.read import iso_time
from furnace_model.log.schema import MODEL_EVENTS, MODEL_PARAMETERS
from furnace_model.simulation.furnace import Furnace

from .daqconfig import DiagnosisConfig, RefitConfig
from .diagnosisrunner import DiagnosisRunner
from .diagnosistrigger import DiagnosisRequest, DiagnosisTrigger
from .refit import FitJob, RefitChain, Window, WindowCutter, run_fit

KILL_FACTOR = 3.0
KILL_MARGIN_S = 5.0
START_TIMEOUT_S = 120.0
"""A worker that has not imported numpy and scipy after this long is declared dead."""

Emit = Callable[[str, ModelParameters | ModelEvent | ModelDiagnosis, int], None]
"""emit(topic, message, publish time ns on the data clock)"""


def _serve(conn: Connection) -> None:
    """The worker process: import once, then fit jobs until the pipe closes. SIGTERM and
    SIGINT (systemd stopping the unit's whole group, Ctrl-C in a terminal) are the parent's
    to handle: it lets the fit in hand finish, then ends the worker; a parent that dies
    closes the pipe, which ends the worker too."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    import furnace_model.identification.fit  # noqa: F401 - paid once at start, not by the first window

    conn.send(("ready", None))
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return
        try:
            reply = ("ok", run_fit(job))
        except Exception as exc:  # noqa: BLE001 - reported as a failed refit
            reply = ("error", f"{type(exc).__name__}: {exc}")
        try:
            conn.send(reply)
        except OSError:  # the parent is gone
            return


class RefitWorker:
    """One fitting process behind a pipe."""

    def __init__(self) -> None:
        self._ctx = mp.get_context("spawn")
        self.proc: mp.process.BaseProcess | None = None
        self.conn: Connection | None = None
        self.ready = False
        self.started_at = 0.0

    def start(self) -> None:
        parent, child = self._ctx.Pipe(duplex=True)
        self.proc = self._ctx.Process(target=_serve, args=(child,), name="furnace-refit",
                                      daemon=True)
        self.proc.start()
        child.close()
        self.conn = parent
        self.ready = False
        self.started_at = time.monotonic()

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.is_alive()

    def send(self, job: FitJob) -> None:
        assert self.conn is not None and self.ready
        self.conn.send(job)

    def receive(self, timeout: float = 0.0) -> tuple[str, object] | None:
        """The next reply, or None when there is none within `timeout`; ('died', exit code)
        when the process is gone."""
        if self.conn is None:
            return None
        try:
            if not self.conn.poll(timeout):
                if self.proc is not None and not self.proc.is_alive():
                    return "died", self.proc.exitcode
                return None
            kind, value = self.conn.recv()
        except (EOFError, OSError):
            self.stop(kill=True)
            return "died", None if self.proc is None else self.proc.exitcode
        if kind == "ready":
            self.ready = True
        return kind, value

    def stop(self, kill: bool = False) -> None:
        if self.conn is not None:
            self.conn.close()
            self.conn = None
        if self.proc is not None:
            if kill:
                self.proc.kill()
            self.proc.join(5.0)
            if self.proc.is_alive():
                self.proc.kill()
                self.proc.join(5.0)
            self.proc = None
        self.ready = False


class RefitRunner:
    """Windows in, /model messages out, fits in a worker process; see the module docstring.
    Not thread-safe: call everything from one thread (the event loop, or replay's loop)."""

    def __init__(self, config: RefitConfig, emit: Emit, *, t_air_default: float = 30.0,
                 max_queue: int | None = None, furnace: Furnace,
                 recorded_diagnoses: dict[int, ModelDiagnosis] | None = None):
        """`recorded_diagnoses`: replay's logged diagnoses (diagnosisrunner)."""
        self.config = config
        self.emit = emit
        self.max_queue = max_queue
        self.cutter = WindowCutter(config, t_air_default, furnace=furnace)
        self.chain = RefitChain(config, t_air_default, furnace=furnace)
        self.queue: deque[Window] = deque()
        self.in_flight: tuple[Window, float] | None = None
        self.worker = RefitWorker()
        self.kill_after_s = KILL_FACTOR * config.budget_s + KILL_MARGIN_S
        self.windows = 0
        self.dropped = 0
        self.failures = 0
        self._restart_delay = 0.0
        self._start_at = 0.0  # monotonic time of the next worker start while there is none
        diagnosis = config.diagnosis
        self.trigger = None if diagnosis is None else DiagnosisTrigger(diagnosis)
        self.diagnoses = None if diagnosis is None else \
            DiagnosisRunner(diagnosis, emit, recorded_diagnoses, self._verdict)
        self.verdict_lag_ns = None if self.diagnoses is None or not _sets_aside(diagnosis) \
            else int(round((self.kill_after_s + self.diagnoses.kill_after_s) * 1e9))
        """A verdict applies to the windows that end this long after the window it judged:
        by then, on the live clock, its refit and its diagnosis have answered or been
        killed, so the refit never waits for it; a replay, or a plant clock run faster,
        waits (`_awaits_verdict`) and so meets the same windows. None: no verdict can set a
        thermocouple aside, and nothing waits."""

    def start(self) -> None:
        self.worker.start()

    def state(self) -> dict:
        """The chain's state (RefitChain.state) and the diagnosis trigger's episode: what a
        restarted daemon goes on from."""
        out = self.chain.state()
        if self.trigger is not None and self.diagnoses is not None:
            out["trigger"] = self.trigger.state(self.diagnoses.unanswered())
        return out

    def restore(self, state: object) -> None:
        """Take over a saved `state()` (a chain state without a trigger's starts the
        episode afresh); ValueError, naming what is wrong, leaving everything as it was."""
        trigger = self.trigger
        if trigger is not None and isinstance(state, dict) and state.get("trigger") is not None:
            trigger = DiagnosisTrigger.from_state(trigger.config, state["trigger"],
                                                  self.chain.furnace)
        self.chain.restore(state)
        self.trigger = trigger

    def feed(self, topic: str, msg: FurnaceMessage | dict, pub_ns: int) -> None:
        """One logged message; cuts and queues the windows that became due (and hands the
        first to the worker at once when it is idle)."""
        windows = self.cutter.feed(topic, msg, pub_ns)
        if not windows:
            return
        for window in windows:
            self.windows += 1
            self.queue.append(window)
            if self.max_queue is not None and len(self.queue) > self.max_queue:
                old = self.queue.popleft()
                self.dropped += 1
                self.emit(MODEL_EVENTS, ModelEvent(
                    ModelEventKind.WINDOW_DROPPED,
                    f"refits fall behind: window to {iso_time(old.end_ns)} dropped "
                    f"unfitted ({self.max_queue} windows queued)",
                    window_end=iso_time(old.end_ns)), old.end_ns)
        self.pump()

    def busy(self) -> bool:
        return self.in_flight is not None or bool(self.queue)

    def pump(self, timeout: float = 0.0) -> None:
        """Collect a finished fit (waiting up to `timeout`), check the one in flight, hand
        out the next window. Cheap when nothing happened: call it on every poll tick."""
        if self.diagnoses is not None:
            self.diagnoses.pump()
        now = time.monotonic()
        if self.worker.proc is None:
            if now < self._start_at:
                time.sleep(min(timeout, self._start_at - now))  # a waiting caller waits here
                return
            self.worker.start()
        reply = self.worker.receive(timeout) if (self.in_flight or not self.worker.ready) \
            else None
        if reply is not None:
            kind, value = reply
            if kind == "died":
                self._restart(f"the refit worker process died (exit code {value})")
            elif kind in ("ok", "error") and self.in_flight is not None:
                window, _ = self.in_flight
                self.in_flight = None
                if kind == "ok":
                    self._restart_delay = 0.0
                    msg, events = self.chain.accept(window, value)
                else:
                    msg, events = self.chain.kept(window, "failed", f"fit raised {value}"), []
                self._publish(window, msg, events)
        now = time.monotonic()
        if self.in_flight is not None and now - self.in_flight[1] > self.kill_after_s:
            self._restart(f"the fit ran past {self.kill_after_s:g} s of wall time "
                          f"(budget {self.config.budget_s:g} s); worker killed")
        elif self.worker.proc is not None and not self.worker.ready \
                and now - self.worker.started_at > START_TIMEOUT_S:
            self._restart(f"the refit worker did not start within {START_TIMEOUT_S:g} s")
        while self.in_flight is None and self.queue:
            if self._awaits_verdict(self.queue[0]):
                return
            window = self.chain.without_set_aside(self.queue[0])
            reason = self.chain.check(window)
            if reason is not None:
                self.queue.popleft()
                self._publish(window, self.chain.kept(window, "insufficient_excitation", reason),
                              [])
                continue
            if not self.worker.ready:
                return
            self.queue.popleft()
            self.worker.send(self.chain.job(window))
            self.in_flight = (window, time.monotonic())

    def _awaits_verdict(self, window: Window) -> bool:
        """Whether a verdict still to come may set a thermocouple aside for this window."""
        if self.diagnoses is None or self.verdict_lag_ns is None:
            return False
        since = self.diagnoses.waiting_since()
        return since is not None and window.end_ns >= since + self.verdict_lag_ns

    def _verdict(self, request: DiagnosisRequest, msg: ModelDiagnosis) -> None:
        """A verdict that credits a drifting thermocouple sets it aside (RefitChain)."""
        sensor = (msg.sensor or {}).get("thermocouple")
        if self.verdict_lag_ns is None or sensor is None or msg.status not in NAMING:
            return
        from_ns = request.key + self.verdict_lag_ns
        if self.chain.set_aside_from(sensor, from_ns, request.key):
            self.emit(MODEL_EVENTS, ModelEvent(
                ModelEventKind.SENSOR_SET_ASIDE,
                f"thermocouple {sensor} set aside: it drifts "
                f"({msg.sensor.get('rate_c_per_h', float('nan')):+.2f} °C/h since "
                f"{msg.sensor.get('onset')}); the refit's windows that end at or after "
                f"{iso_time(from_ns)} leave it out. Once it is replaced, list it under "
                "refit.diagnosis.trusted and restart.",
                window_end=iso_time(from_ns)), request.key)

    def _restart(self, why: str) -> None:
        """Kill the worker; a new one starts at the next pump, later after each failure in a
        row (a worker that cannot start must not cost a process start per poll tick)."""
        self.worker.stop(kill=True)
        if self.in_flight is not None:
            window, _ = self.in_flight
            self.in_flight = None
            self._publish(window, self.chain.kept(window, "failed", why), [])
        self._start_at = time.monotonic() + self._restart_delay
        self._restart_delay = min(60.0, max(1.0, 2 * self._restart_delay))

    def _publish(self, window: Window, msg: ModelParameters, events: list[ModelEvent]
                 ) -> None:
        if msg.status == "failed":
            self.failures += 1
        self.emit(MODEL_PARAMETERS, msg, window.end_ns)
        for event in events:
            self.emit(MODEL_EVENTS, event, window.end_ns)
        if self.trigger is not None and self.diagnoses is not None:
            request = self.trigger.observe(window, msg, events)
            if request is not None:
                self.diagnoses.request(request)

    def diagnosing(self) -> bool:
        return self.diagnoses is not None and self.diagnoses.busy()

    def drain(self, timeout: float) -> bool:
        """Fit what is queued and finish the diagnoses it asks for, waiting at most
        `timeout` seconds; True when all is done."""
        deadline = time.monotonic() + timeout
        while self.busy() or self.diagnosing():
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            if self.busy():
                self.pump(min(left, 0.05))
            else:
                self.pump()
                time.sleep(min(left, 0.05))
        return True

    def close(self) -> None:
        """End the worker and any diagnosis in flight (a diagnosis is not waited for)."""
        self.worker.stop(kill=True)
        if self.diagnoses is not None:
            self.diagnoses.close()


def _sets_aside(config: DiagnosisConfig) -> bool:
    """Whether a verdict may set a thermocouple aside: one that can name a drift."""
    return config.set_aside and (config.effects is None or "sensor_drift" in config.effects)
