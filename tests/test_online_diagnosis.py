"""The gateway's online diagnosis: its config, the trigger's rule, the /model/diagnosis
message, and a diagnosis in its own process that fails without taking the refit along."""

from __future__ import annotations

import contextlib
import os
import signal
import time
from pathlib import Path

import jsonschema
import numpy as np
import pytest
import yaml

from furnace_daq.daqconfig import DaqConfig, DiagnosisConfig, RefitConfig, parse_config
from furnace_daq.diagnosisrunner import NICE, DiagnosisRunner
from furnace_daq.diagnosistrigger import DiagnosisTrigger
from furnace_daq.logmeta import plain, refit_config
from furnace_daq.refit import Window
from furnace_model.config import Node
from furnace_model.errors import ConfigError
from furnace_model.experiment import Experiment
from furnace_model.log.messages import (
    ModelDiagnosis,
    ModelEvent,
    ModelEventKind,
    ModelParameters,
)
from furnace_model.log.schema import MODEL_DIAGNOSIS, MODEL_EVENTS, topics
from furnace_model.simulation.furnace import PAPER

ROOT = Path(__file__).resolve().parents[1]
HOUR_NS = 3600 * 10**9


def parse(diagnosis: object) -> DaqConfig:
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["refit"]["diagnosis"] = diagnosis
    return parse_config(Node(doc, "daq.yaml"))


def test_the_diagnosis_block_and_its_mistakes_by_key_path():
    d = parse({"after_windows": 2, "time_limit_s": 90, "effects": ["sensor_drift"]}).refit.diagnosis
    assert d == DiagnosisConfig(after_windows=2, time_limit_s=90.0, effects=("sensor_drift",))
    assert parse({"enabled": False}).refit.diagnosis is None
    assert parse({}).refit.diagnosis == DiagnosisConfig()
    for bad, words in [({"effects": ["sensor_drift", "fuel_swap"]},
                        "refit.diagnosis.effects[1]: must be one of"),
                       ({"effects": ["dead_time", "dead_time"]},
                        "refit.diagnosis.effects[1]: 'dead_time' is listed twice"),
                       ({"after_windows": 0}, "refit.diagnosis.after_windows"),
                       ({"time_limit_s": "soon"}, "refit.diagnosis.time_limit_s"),
                       ({"every": 3}, "refit.diagnosis")]:
        with pytest.raises(ConfigError, match=words.replace("[", r"\[").replace("]", r"\]")):
            parse(bad)


def test_the_recorded_settings_give_the_diagnosis_back():
    refit = RefitConfig(diagnosis=DiagnosisConfig(after_windows=4, effects=("dead_time",)))
    assert refit_config(plain(refit)) == refit
    assert refit_config(plain(RefitConfig())).diagnosis is None


def window(k: int, n: int = 20) -> Window:
    """The k-th hour-long window of a flat record (the trigger looks at its span only)."""
    t = np.arange(n, dtype=float) * 3.0
    tc = np.full((n, 6), 900.0)
    exp = Experiment(f"w{k}", t, tc, np.ones((n, 3)), np.full(n, 30.0), furnace=PAPER)
    return Window(k * HOUR_NS, (k + 1) * HOUR_NS, exp, n, n, 1)


def model(k: int, soak_rmse: float, status: str = "ok") -> ModelParameters:
    msg = ModelParameters(status, "", f"w{k}", f"w{k + 1}")
    msg.rmse_c = {"soak": soak_rmse, "heat": 1.0, "preheat": 1.0}
    msg.misfit_limit_c = {"soak": 2.0, "heat": 2.0, "preheat": 2.0}
    return msg


DRIFT = ModelEvent(ModelEventKind.DRIFT, "f fell 20%", parameter="f")


def test_the_trigger_asks_once_per_episode_after_misfits_or_at_a_drift():
    trigger = DiagnosisTrigger(DiagnosisConfig(after_windows=2))
    # nothing before a window fitted to its floor: there is no reference yet
    assert trigger.observe(window(0), model(0, 5.0), [DRIFT]) is None
    assert trigger.observe(window(1), model(1, 1.0), []) is None  # the reference
    assert trigger.observe(window(2), model(2, 5.0), []) is None  # one misfit
    assert trigger.observe(window(3), model(3, 0.0, "failed"), []) is None  # not counted
    asked = trigger.observe(window(4), model(4, 5.0), [])
    assert asked is not None and asked.trigger == "misfit" and "soak" in asked.trigger_detail
    assert asked.reference_span == (HOUR_NS, 2 * HOUR_NS)
    assert asked.recent_span == (4 * HOUR_NS, 5 * HOUR_NS) and asked.key == 5 * HOUR_NS
    assert asked.seed == 5 * 3600  # the window's end in seconds: the same in replay
    # the same episode: no second diagnosis, however long it lasts ...
    assert all(trigger.observe(window(k), model(k, 5.0), []) is None for k in (5, 6, 7))
    # ... unless a drift event fires: a new episode
    drift = trigger.observe(window(8), model(8, 5.0), [DRIFT])
    assert drift is not None and drift.trigger == "drift" and "f fell" in drift.trigger_detail
    assert drift.reference_span == (HOUR_NS, 2 * HOUR_NS)
    # the model fits again: the episode is over, and the next run of misfits asks again
    assert trigger.observe(window(9), model(9, 1.0), []) is None
    assert trigger.observe(window(10), model(10, 5.0), []) is None
    again = trigger.observe(window(11), model(11, 5.0), [])
    assert again is not None and again.reference_span == (9 * HOUR_NS, 10 * HOUR_NS)


def test_a_diagnosis_message_validates_against_its_schema_and_reads_back():
    msg = ModelDiagnosis(
        "explained", "thermocouple soak_1 drifts", "misfit", "2 windows above the floor",
        effects=[{"effect": "sensor_drift", "options": {"sensor": "soak_1"},
                  "params": {"t_drift": 120.0, "drift_rate": -0.05}}],
        sensor={"thermocouple": "soak_1", "onset": "2026-03-02T08:00:00.000Z",
                "rate_c_per_h": -3.0},
        where=[{"zone": "soak", "sensor": "soak_1", "kind": "sensor", "share_of_error": 0.8,
                "regime": "all", "start": "a", "end": "b"}],
        shrink_pct=60.0, rmse_holdout_c={"soak": 3.0, "heat": None, "preheat": 1.0},
        fitted=[{"start": "a", "end": "b"}], held_out=[{"start": "b", "end": "c"}],
        reference_window={"start": "x", "end": "y"}, effects_tried=["sensor_drift"],
        untried=["dead_time"], cut=["0.1"], seed=5, time_limit_s=60.0, elapsed_s=12.0,
        plc_time=5 * HOUR_NS)
    data = msg.to_json()
    jsonschema.validate(data, topics(PAPER)[MODEL_DIAGNOSIS].schema)
    back = ModelDiagnosis.from_json(data)
    assert back.to_json() == data and back.cut == ["0.1"] and back.plc_time == 5 * HOUR_NS
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({**data, "status": "maybe"}, topics(PAPER)[MODEL_DIAGNOSIS].schema)


def blind_request(rows: int = 20) -> tuple[DiagnosisRunner, list[tuple[str, object, int]]]:
    """A runner diagnosing a window of `rows` rows whose soaking zone reads nothing, which
    no diagnosis can take: it fails quickly. Returns the runner and what it publishes."""
    got: list[tuple[str, object, int]] = []
    runner = DiagnosisRunner(DiagnosisConfig(time_limit_s=30.0),
                             lambda topic, msg, ns: got.append((topic, msg, ns)))
    trigger = DiagnosisTrigger(DiagnosisConfig(after_windows=1))
    blind = window(2, n=rows)
    assert blind.experiment is not None
    blind.experiment.tc[:, :2] = np.nan
    trigger.observe(window(1), model(1, 1.0), [])
    request = trigger.observe(blind, model(2, 5.0), [])
    assert request is not None
    runner.request(request)
    return runner, got


def answered(runner: DiagnosisRunner) -> None:
    """Pumped until the runner has answered all (within two minutes), then closed."""
    try:
        deadline = time.monotonic() + 120
        while runner.busy() and time.monotonic() < deadline:
            runner.pump(0.1)
        assert not runner.busy(), "the diagnosis process did not answer"
    finally:
        runner.close()


def test_a_diagnosis_that_raises_is_published_as_failed_with_its_event():
    """A request whose records no diagnosis can take (a zone without readings): the child
    process reports the error, the runner publishes `failed` and goes on."""
    runner, got = blind_request()
    answered(runner)
    (t1, diag, ns1), (t2, event, ns2) = got
    assert (t1, t2) == (MODEL_DIAGNOSIS, MODEL_EVENTS) and ns1 == ns2 == 3 * HOUR_NS
    assert diag.status == "failed" and "soak" in diag.detail
    assert diag.held_out == [{"start": "1970-01-01T02:00:00.000Z",
                              "end": "1970-01-01T03:00:00.000Z"}]
    assert event.kind == ModelEventKind.DIAGNOSIS_FAILED and "failed" in event.detail
    jsonschema.validate(diag.to_json(), topics(PAPER)[MODEL_DIAGNOSIS].schema)


def test_starting_a_diagnosis_does_not_wait_for_the_child_to_take_its_job():
    """The poll loop starts a diagnosis: the call returns at once even when the job (two
    windows of data) is more than a pipe holds and the child has not read it yet. The child
    is stopped as soon as the call returns, before its imports are done, so the job can
    only be on its way; once it goes on, the job arrives whole and is answered."""
    runner, got = blind_request(rows=40_000)  # a few MB pickled, a pipe holds 64 kB
    assert runner.in_flight is not None
    proc = runner.in_flight[2]
    os.kill(proc.proc.pid, signal.SIGSTOP)
    try:
        time.sleep(0.5)
        assert proc.handing.is_alive(), "the job was taken before the child could read it"
    finally:
        os.kill(proc.proc.pid, signal.SIGCONT)
    answered(runner)
    assert not proc.handing.is_alive()
    (_, diag, _), _ = got
    assert diag.status == "failed" and "soak" in diag.detail  # the child read the whole job


def test_refits_go_on_while_a_diagnosis_computes():
    """A fuel switch raises a drift event, which starts a diagnosis in its own process at a
    lower priority; the windows after it are fitted and published while it computes, and
    its verdict arrives as a /model/diagnosis message with its event."""
    from refit_helpers import scenario, simulate

    from furnace_daq.plantlog import run_messages
    from furnace_daq.refitworker import RefitRunner
    from furnace_model.log.schema import MODEL_PARAMETERS

    s = scenario("fuel_switch", duration_min=4 * 1440)
    cfg = RefitConfig(period_s=6 * 3600.0, window_s=6 * 3600.0, diagnosis=DiagnosisConfig(
        after_windows=2, time_limit_s=60.0, effects=("fuel_change", "dead_time")))
    log: list[tuple[str, object, bool]] = []
    runner: RefitRunner | None = None

    def emit(topic: str, msg, ns: int) -> None:
        assert runner is not None
        log.append((topic, msg, runner.diagnosing()))

    runner = RefitRunner(cfg, emit, max_queue=None, furnace=PAPER)
    runner.start()
    niceness = None
    try:
        for topic, msg, t in run_messages(simulate(s)):
            runner.feed(topic, msg, t)
            if runner.diagnoses is not None and runner.diagnoses.in_flight and niceness is None:
                proc = runner.diagnoses.in_flight[2].proc
                with contextlib.suppress(OSError):
                    niceness = os.getpriority(os.PRIO_PROCESS, proc.pid) \
                        - os.getpriority(os.PRIO_PROCESS, 0)
            if len(runner.queue) > 2:
                runner.pump(1.0)
        assert runner.drain(240), "refits and the diagnosis did not finish in time"
    finally:
        runner.close()
    topics_ = [t for t, _m, _d in log]
    assert topics_.count(MODEL_DIAGNOSIS) == 1, [m.detail for t, m, _ in log if t == MODEL_EVENTS]
    diag = next(m for t, m, _ in log if t == MODEL_DIAGNOSIS)
    assert diag.trigger == "drift" and diag.status != "failed", diag.detail
    start = next(i for i, (t, m, _) in enumerate(log)
                 if t == MODEL_EVENTS and m.kind == ModelEventKind.DRIFT)
    after = [d for t, _m, d in log[start:] if t == MODEL_PARAMETERS]
    assert any(after), "no window was published while the diagnosis was in flight"
    assert niceness == NICE  # set by the daemon as it started the child, before its imports
    jsonschema.validate(diag.to_json(), topics(PAPER)[MODEL_DIAGNOSIS].schema)


def long_window(k: int, hours: int = 10, aside: tuple[str, ...] = ()) -> Window:
    """The window of `hours` ending at hour k + hours: one every hour, as the daemon cuts
    them (each holds the hours of the one before but the first)."""
    w = window(0, n=hours * 20)
    return Window(k * HOUR_NS, (k + hours) * HOUR_NS, w.experiment, w.expected_bins,
                  w.complete_bins, 1, aside)


def test_the_request_waits_for_a_window_whose_fitted_part_holds_the_change():
    """Windows of 10 h every hour: the reference ends at 10 h, so the change came later,
    and a diagnosis fitting a window's first 7 h must reach 11 h (a tenth of a window past
    it) to fit it: the window from 4 h. Before it the misfit is counted, not diagnosed."""
    trigger = DiagnosisTrigger(DiagnosisConfig(after_windows=2))
    assert trigger.observe(long_window(0), model(0, 1.0), []) is None  # the reference
    assert [trigger.observe(long_window(k), model(k, 5.0), []) for k in (1, 2, 3)] \
        == [None] * 3
    asked = trigger.observe(long_window(4), model(4, 5.0), [])
    assert asked is not None and asked.trigger == "misfit"
    assert asked.reference_span == (0, 10 * HOUR_NS)
    assert asked.recent_span == (4 * HOUR_NS, 14 * HOUR_NS)
    # a drift event waits the same way, from the reference before it
    trigger = DiagnosisTrigger(DiagnosisConfig(after_windows=2))
    trigger.observe(long_window(0), model(0, 1.0), [])
    assert trigger.observe(long_window(1), model(1, 1.0), [DRIFT]) is None
    assert [trigger.observe(long_window(k), model(k, 1.0), []) for k in (2, 3)] == [None] * 2
    drift = trigger.observe(long_window(4), model(4, 1.0), [])
    assert drift is not None and drift.trigger == "drift" and "f fell" in drift.trigger_detail
    # a misfit that ends before its window comes is no episode
    trigger = DiagnosisTrigger(DiagnosisConfig(after_windows=2))
    trigger.observe(long_window(0), model(0, 1.0), [])
    for k, rmse in ((1, 5.0), (2, 5.0), (3, 1.0), (4, 5.0)):
        assert trigger.observe(long_window(k), model(k, rmse), []) is None, k


def test_a_thermocouple_set_aside_opens_a_new_episode():
    """The drift's episode never ends while the drifting reading is fitted; once it is left
    out, a misfit that stays is another fault and is diagnosed on its own, once the fitted
    part holds what came after the window the drift's verdict explained."""
    trigger = DiagnosisTrigger(DiagnosisConfig(after_windows=1))
    trigger.observe(long_window(0), model(0, 1.0), [])
    first = trigger.observe(long_window(4), model(4, 5.0), [])
    assert first is not None and first.key == 14 * HOUR_NS
    assert trigger.observe(long_window(5), model(5, 5.0), []) is None  # the same episode
    def aside(k: int) -> Window:
        w = long_window(k, aside=("soak_1",))
        return Window(w.start_ns, w.end_ns, w.experiment, w.expected_bins, w.complete_bins,
                      1, w.set_aside, explained_until=first.key)
    # a new episode, its change after 14 h: the fitted part must reach 15 h
    assert [trigger.observe(aside(k), model(k, 5.0), []) for k in (6, 7)] == [None] * 2
    again = trigger.observe(aside(8), model(8, 5.0), [])
    assert again is not None and again.recent_span == (8 * HOUR_NS, 18 * HOUR_NS)


def test_a_restarted_daemon_goes_on_with_the_episode_and_asks_again_what_had_no_verdict():
    """The trigger's state goes to refit_chain.json with the chain's: after a restart the
    episode neither starts afresh (no second diagnosis of it) nor loses its reference, and
    a request the stopped daemon never answered is asked of the next misfit window."""
    import json

    from furnace_daq.refitworker import RefitRunner

    config = RefitConfig(diagnosis=DiagnosisConfig(after_windows=2))

    def runner() -> RefitRunner:
        return RefitRunner(config, lambda *a: None, furnace=PAPER)

    def saved(r: RefitRunner) -> dict:
        return json.loads(json.dumps(r.state(), allow_nan=False))  # as the state file holds it

    first = runner()
    assert first.trigger.observe(window(1), model(1, 1.0), []) is None  # the reference
    reference = first.trigger.reference
    reference.experiment.tc[3, 2] = np.nan  # a missing reading travels too
    assert first.trigger.observe(window(2), model(2, 5.0), []) is None  # one misfit
    after_one = saved(first)
    asked = first.trigger.observe(window(3), model(3, 5.0), [])
    assert asked is not None
    answered = saved(first)  # the request was answered before the stop

    again = runner()
    again.restore(answered)
    ref = again.trigger.reference
    assert (ref.start_ns, ref.end_ns) == (reference.start_ns, reference.end_ns)
    np.testing.assert_array_equal(ref.experiment.tc, reference.experiment.tc)
    np.testing.assert_array_equal(ref.experiment.t_min, reference.experiment.t_min)
    assert again.trigger.observe(window(4), model(4, 5.0), []) is None  # the same episode
    assert again.chain.model is None and again.state()["trigger"]["fired"] is True

    counting = runner()
    counting.restore(after_one)  # one misfit counted: the next one asks
    asked = counting.trigger.observe(window(3), model(3, 5.0), [])
    assert asked is not None and asked.reference_span == (HOUR_NS, 2 * HOUR_NS)

    unanswered = runner()
    unanswered.diagnoses.queue.append(asked)  # requested, no verdict yet
    unanswered.trigger = counting.trigger
    state = saved(unanswered)
    assert state["trigger"]["fired"] is False and state["trigger"]["pending"][0] == "misfit"
    later = runner()
    later.restore(state)
    redo = later.trigger.observe(window(6), model(6, 5.0), [])
    assert redo is not None and redo.trigger == "misfit"
    assert redo.reference_span == (HOUR_NS, 2 * HOUR_NS)

    # a state that is not one is refused whole, and the runner stays as it was
    broken = {**answered, "trigger": {**answered["trigger"], "misfits": "many"}}
    with pytest.raises(ValueError, match="malformed diagnosis trigger state"):
        later.restore(broken)
    assert later.trigger.fired is True and later.trigger.reference is not None
    without = {k: v for k, v in answered.items() if k != "trigger"}  # an older daemon's
    fresh = runner()
    fresh.restore(without)
    assert fresh.trigger.reference is None
