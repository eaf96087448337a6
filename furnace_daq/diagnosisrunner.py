"""Online diagnoses in a process of their own, below the refit and the poll loop.

A diagnosis fits many candidate models for minutes. It must never delay a poll or a refit:
it runs in a child process ('spawn': no inherited event loop, sockets or locks) whose
priority the daemon lowers (`NICE`) as soon as it exists, and its candidate pool
(furnace_model.diagnosis.pool) inherits that priority. Lowered by the child itself it would
come too late: a spawned child imports the daemon's main module and unpickles its job, a
second or two of CPU, before its target runs, and on two cores beside a refit that starves
the poll loop. The daemon's side only looks at a pipe once per tick.

At most one diagnosis is in flight; requests that arrive meanwhile wait in order (the
trigger asks for one per episode, so they are few). Each answers within its
`time_limit_s` (diagnose's own limit); one that raises is published with status `failed`,
and one still running `KILL_FACTOR` x its limit (+ `KILL_MARGIN_S`) later is killed and
published as `failed` too. The child dies with the daemon (the parent-death signal) and its
pool's workers die with it, so a killed diagnosis leaves no process behind.

Replay. A verdict reached under a time limit depends on how many fits the host managed.
The message records which fits the limit cut (`cut`); given those (`recorded`), the runner
diagnoses again without the clock, cutting exactly them, and reaches the same verdict.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection

from furnace_model.log.messages import ModelDiagnosis, ModelEvent, ModelEventKind
from furnace_model.log.read import iso_time
from furnace_model.log.schema import MODEL_DIAGNOSIS, MODEL_EVENTS

from .daqconfig import DiagnosisConfig
from .diagnosistrigger import DiagnosisRequest

NICE = 10
"""How much lower than the daemon a diagnosis runs (os.nice)."""
KILL_FACTOR = 2.0
KILL_MARGIN_S = 60.0
"""Beyond its own limit a diagnosis gets time to import, fit the baseline (which no limit
cuts) and answer."""

Emit = Callable[[str, ModelDiagnosis | ModelEvent, int], None]
Verdict = Callable[[DiagnosisRequest, ModelDiagnosis], None]


@dataclass(frozen=True)
class DiagnosisJob:
    """What the child needs: picklable."""

    request: DiagnosisRequest
    effects: tuple[str, ...] | None
    time_limit_s: float | None
    cut: tuple[str, ...] | None = None


def run_diagnosis(job: DiagnosisJob) -> dict:
    """The diagnosis of a request as the message's fields. The window that raised it is
    fitted on its first part and judged on the rest, the diagnosis's own split of one
    record: an effect that began inside it (a drift's onset, a fuel switch) can only be
    fitted on data that hold it. A window too short to split is judged against the
    reference window instead, fitted there."""
    from furnace_model.diagnosis import diagnose
    from furnace_model.errors import FurnaceError

    req = job.request
    kwargs = {"effects": job.effects, "seed": req.seed, "time_limit_s": job.time_limit_s,
              "cut": job.cut}
    try:
        d = diagnose([req.recent], None, **kwargs)
    except FurnaceError:
        d = diagnose([req.reference], [req.recent], **kwargs)
    return summary(d)


def summary(d) -> dict:
    """A Diagnosis as the fields of /model/diagnosis."""
    from furnace_model.diagnosis.fitting import structure_of
    from furnace_model.effects.base import pinned
    from furnace_model.simulation.structure import ModelStructure

    v, kept = d.verdict, d.kept
    furnace = d.fit_data[0].furnace
    base = set(ModelStructure(furnace=furnace).names)
    effects = []
    for name in v.effects:
        opts = {} if kept is None else dict(kept.options.get(name, {}))
        names = structure_of((name,), {name: opts}, furnace).names
        params = {} if kept is None else {k: float(kept.params[k]) for k in names
                                          if k not in base and k in kept.params}
        effects.append({"effect": name, "options": _plain(opts), "params": params})
    sensor = None
    drift = next((e for e in effects if e["effect"] == "sensor_drift"), None)
    if drift is not None and {"t_drift", "drift_rate"} <= set(drift["params"]):
        first = d.fit_data[0]

        def at(minute: float) -> str | None:
            return (None if first.start_time is None else
                    iso_time(first.start_time.value + int(minute * 60e9)))

        rate = 60.0 * drift["params"]["drift_rate"]
        ci = {} if kept is None else kept.ci95
        sensor = {"thermocouple": drift["options"].get("sensor"),
                  "onset": at(drift["params"]["t_drift"]), "rate_c_per_h": rate}
        if "drift_rate" in ci:
            rate_ci = [60.0 * float(ci["drift_rate"][0]), 60.0 * float(ci["drift_rate"][1])]
            sensor["rate_c_per_h_ci95"] = rate_ci
            sensor["rate_pinned"] = pinned(rate, tuple(rate_ci))
        if "t_drift" in ci and first.start_time is not None:
            sensor["onset_ci95"] = [at(float(ci["t_drift"][0])), at(float(ci["t_drift"][1]))]
    return {
        "status": v.status, "detail": _sentence(v.sentence, sensor),
        "effects": effects, "sensor": sensor,
        "where": [_present({"zone": w.zone, "sensor": w.sensor, "start": w.start,
                            "end": w.end, "share_of_error": _number(w.share_of_error),
                            "regime": w.regime, "kind": w.kind}) for w in d.where],
        "shrink_pct": _number(v.shrink_pct), "gap_closed_pct": _number(v.gap_closed_pct),
        "rmse_holdout_c": {z: _number(x) for z, x in d.baseline.rmse_holdout_c.items()},
        "noise_floor_c": {z: _number(x) for z, x in d.noise_floor_c.items()},
        "fitted": [_span(e) for e in d.fit_data], "held_out": [_span(e) for e in d.holdout],
        "untried": list(d.untried), "cut": list(d.cut), "elapsed_s": float(d.elapsed_s),
    }


def _sentence(sentence: str, sensor: dict | None) -> str:
    if sensor is None:
        return sentence
    if sensor.get("rate_pinned", True):
        how = f"{sensor['rate_c_per_h']:+.2f} °C/h since {sensor['onset']}"
    else:
        lo, hi = sensor["rate_c_per_h_ci95"]
        how = (f"since {sensor['onset']}, at a rate the record does not pin down: "
               f"{sensor['rate_c_per_h']:+.2f} °C/h, 95% interval {lo:+.2f} to {hi:+.2f}")
    return (f"thermocouple {sensor['thermocouple']} drifts ({how}): the sensor changed, not "
            f"the furnace. {sentence}")


def _span(e) -> dict:
    t0 = e.start_time.value if e.start_time is not None else 0
    return {"start": iso_time(t0 + int(round(float(e.t_min[0]) * 60e9))),
            "end": iso_time(t0 + int(round(float(e.t_min[-1]) * 60e9)))}


def _number(x) -> float | None:
    x = float(x)
    return x if x == x and abs(x) != float("inf") else None


def _present(d: dict) -> dict:
    """Inside an array a missing value is left out too (the schema has no null)."""
    return {k: v for k, v in d.items() if v is not None}


def _plain(opts: dict) -> dict:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in opts.items()}


def _serve(conn: Connection, jobs: Connection, parent: int, niceness: int) -> None:
    """The child: below the refit, dying with the daemon; one diagnosis, one reply.
    `niceness`: its priority, which the daemon set already unless the child was quicker."""
    from furnace_model.diagnosis.pool import die_with_parent

    die_with_parent(parent)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the daemon's to handle
    _lower(0, niceness)
    try:
        job = jobs.recv()
    except (EOFError, OSError):  # the daemon stopped it before handing it over
        return
    jobs.close()
    try:
        reply = ("ok", run_diagnosis(job))
    except Exception as exc:  # noqa: BLE001 - published as a failed diagnosis
        reply = ("error", f"{type(exc).__name__}: {exc}")
    with contextlib.suppress(OSError):  # the daemon is gone
        conn.send(reply)


def _hand_over(conn: Connection, job: DiagnosisJob) -> None:
    with contextlib.suppress(OSError):  # the child is gone: `receive` reports it
        conn.send(job)
    conn.close()


def _lower(pid: int, niceness: int) -> None:
    """Process pid (0: this one) at `niceness` or lower priority, never higher."""
    with contextlib.suppress(OSError):  # already gone
        if os.getpriority(os.PRIO_PROCESS, pid) < niceness:
            os.setpriority(os.PRIO_PROCESS, pid, min(niceness, 19))


class DiagnosisProcess:
    """One diagnosis in a child process."""

    def __init__(self, job: DiagnosisJob):
        ctx = mp.get_context("spawn")
        parent, child = ctx.Pipe(duplex=False)
        job_out, job_in = ctx.Pipe(duplex=False)
        # Not daemonic: a daemonic process may not start the candidates' pool. It still
        # ends with the daemon, by the parent-death signal or by `stop`.
        niceness = os.getpriority(os.PRIO_PROCESS, 0) + NICE
        self.proc = ctx.Process(target=_serve, args=(child, job_out, os.getpid(), niceness),
                                name="furnace-diagnosis", daemon=False)
        self.proc.start()
        assert self.proc.pid is not None
        _lower(self.proc.pid, niceness)
        child.close()
        job_out.close()
        # The job (two windows of data, often more than a pipe holds) is written by a
        # thread: the child reads it only once it has imported its modules, and a write
        # that waited for that here would hold the poll loop for a second or more.
        self.handing = threading.Thread(target=_hand_over, args=(job_in, job),
                                        name="diagnosis-job", daemon=True)
        self.handing.start()
        self.conn: Connection | None = parent
        self.started = time.monotonic()

    def receive(self, timeout: float = 0.0) -> tuple[str, object] | None:
        """('ok', fields), ('error', text), ('died', exit code) or None while it runs."""
        assert self.conn is not None
        try:
            if self.conn.poll(timeout):
                return self.conn.recv()
        except (EOFError, OSError):
            return "died", self.proc.exitcode
        if not self.proc.is_alive():
            return "died", self.proc.exitcode
        return None

    def stop(self) -> None:
        """Kill it (its pool's workers die with it) and reap it."""
        if self.conn is not None:
            self.conn.close()
            self.conn = None
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join(5.0)


class DiagnosisRunner:
    """Requests in, /model/diagnosis and /model/events out; see the module docstring. Not
    thread-safe: call it from the refit runner's thread."""

    def __init__(self, config: DiagnosisConfig, emit: Emit,
                 recorded: dict[int, ModelDiagnosis] | None = None,
                 on_verdict: Verdict | None = None):
        """`on_verdict`: told each published verdict (replay: the logged one, which a
        diagnosis that failed live may not reproduce)."""
        self.config = config
        self.emit = emit
        self.on_verdict = on_verdict
        self.recorded = recorded
        """Replay: the logged diagnoses by publish time (`DiagnosisRequest.key`); their `cut`
        replaces the clock."""
        self.queue: deque[DiagnosisRequest] = deque()
        self.in_flight: tuple[DiagnosisRequest, DiagnosisJob, DiagnosisProcess] | None = None
        self.kill_after_s = KILL_FACTOR * config.time_limit_s + KILL_MARGIN_S
        self.done = 0

    def request(self, request: DiagnosisRequest) -> None:
        self.queue.append(request)
        self.pump()

    def busy(self) -> bool:
        return self.in_flight is not None or bool(self.queue)

    def in_flight_since(self) -> float:
        """When the diagnosis in flight started (monotonic seconds; now when none is)."""
        return self.in_flight[2].started if self.in_flight is not None else time.monotonic()

    def unanswered(self) -> DiagnosisRequest | None:
        """The oldest request not yet answered."""
        requests = [*self.queue, *([self.in_flight[0]] if self.in_flight is not None else [])]
        return min(requests, key=lambda r: r.key, default=None)

    def waiting_since(self) -> int | None:
        """The key of the oldest request not yet answered (ns on the data clock)."""
        oldest = self.unanswered()
        return None if oldest is None else oldest.key

    def job(self, request: DiagnosisRequest) -> DiagnosisJob:
        logged = None if self.recorded is None else self.recorded.get(request.key)
        if logged is not None and logged.status != "failed":
            return DiagnosisJob(request, self.config.effects, None, tuple(logged.cut))
        return DiagnosisJob(request, self.config.effects, self.config.time_limit_s)

    def pump(self, timeout: float = 0.0) -> None:
        """Collect a finished diagnosis, kill one past its time, start the next."""
        if self.in_flight is not None:
            request, job, proc = self.in_flight
            reply = proc.receive(timeout)
            if reply is None and time.monotonic() - proc.started > self.kill_after_s:
                reply = ("error", f"still running {self.kill_after_s:g} s after it started "
                                  f"(time limit {self.config.time_limit_s:g} s); killed")
            if reply is not None:
                proc.stop()
                self.in_flight = None
                kind, value = reply
                if kind == "ok":
                    self._publish(request, job, dict(value))  # type: ignore[call-overload]
                else:
                    why = (f"the diagnosis process died (exit code {value})" if kind == "died"
                           else str(value))
                    self._publish(request, job, {"status": "failed", "detail": why})
        if self.in_flight is None and self.queue:
            request = self.queue.popleft()
            job = self.job(request)
            self.in_flight = (request, job, DiagnosisProcess(job))

    def _publish(self, request: DiagnosisRequest, job: DiagnosisJob, fields: dict) -> None:
        self.done += 1
        end_ns = request.recent_span[1]
        ref = request.reference_span
        msg = ModelDiagnosis(**{
            "trigger": request.trigger, "trigger_detail": request.trigger_detail,
            "reference_window": {"start": iso_time(ref[0]), "end": iso_time(ref[1])},
            "effects_tried": None if job.effects is None else list(job.effects),
            "seed": request.seed, "time_limit_s": self.config.time_limit_s, **fields})
        if not msg.held_out:  # failed: the window it was to judge
            msg.held_out = [{"start": iso_time(request.recent_span[0]), "end": iso_time(end_ns)}]
        self.emit(MODEL_DIAGNOSIS, msg, end_ns)
        failed = msg.status == "failed"
        self.emit(MODEL_EVENTS, ModelEvent(
            ModelEventKind.DIAGNOSIS_FAILED if failed else ModelEventKind.DIAGNOSIS,
            f"diagnosis of the window to {iso_time(end_ns)} ({request.trigger}): "
            + (f"failed: {msg.detail}" if failed else f"{msg.status}: {msg.detail}"),
            window_start=iso_time(request.recent_span[0]), window_end=iso_time(end_ns)),
            end_ns)
        if self.on_verdict is not None:
            logged = None if self.recorded is None else self.recorded.get(request.key)
            self.on_verdict(request, msg if logged is None else logged)

    def close(self) -> None:
        if self.in_flight is not None:
            self.in_flight[2].stop()
            self.in_flight = None
