"""A thermocouple an online diagnosis finds drifting is left out of the refit's later windows:
which windows, which zones may lose one, the state that carries it over a restart, and the
config that trusts one again."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from furnace_daq.daqconfig import DiagnosisConfig, RefitConfig, parse_config
from furnace_daq.logmeta import plain, refit_config
from furnace_daq.refit import RefitChain, Window
from furnace_model.config import Node
from furnace_model.errors import ConfigError
from furnace_model.experiment import Experiment
from furnace_model.simulation.furnace import PAPER

ROOT = Path(__file__).resolve().parents[1]
HOUR_NS = 3600 * 10**9


def window(k: int, n: int = 30) -> Window:
    """The k-th hour: soak_1 reads 10 °C above soak_2, the other pairs agree."""
    rng = np.random.default_rng(k)
    tc = np.tile([905.0, 895.0, 800.0, 800.0, 600.0, 600.0], (n, 1)) + rng.normal(0, 1, (n, 6))
    exp = Experiment(f"w{k}", np.arange(n, dtype=float) * 2.0, tc, np.ones((n, 3)),
                     np.full(n, 30.0), furnace=PAPER)
    return Window(k * HOUR_NS, (k + 1) * HOUR_NS, exp, n, n, 1)


def chain(**diagnosis) -> RefitChain:
    return RefitChain(RefitConfig(diagnosis=DiagnosisConfig(**diagnosis)), furnace=PAPER)


def test_windows_that_end_from_the_instant_on_leave_the_thermocouple_out():
    c = chain()
    assert c.set_aside_from("soak_1", 3 * HOUR_NS, 0)
    early, late = window(1), window(2)  # ending at 2 h and at 3 h
    assert c.without_set_aside(early) is early
    at = c.without_set_aside(late)
    assert at.set_aside == ("soak_1",) and at.explained_until == 0
    raw = late.experiment
    assert np.allclose(at.experiment.zone_temp[:, 0], raw.tc[:, 1])  # soak_2 alone
    assert np.allclose(at.experiment.zone_temp[:, 1:], raw.zone_temp[:, 1:])
    assert np.isfinite(raw.tc[:, 0]).all()  # the window as cut is left as it was


def test_a_zones_last_thermocouple_and_a_trusted_one_are_never_set_aside():
    c = chain(trusted=("heat_2",))
    assert c.set_aside_from("soak_1", 0, 0)
    assert not c.set_aside_from("soak_2", 0, 0)  # the soaking zone would read nothing
    assert not c.set_aside_from("soak_1", 0, 0)  # already
    assert not c.set_aside_from("heat_2", 0, 0)  # trusted
    assert not c.set_aside_from("roof_9", 0, 0)  # not a thermocouple of the furnace
    assert c.set_aside == {"soak_1": (0, 0)}


def test_the_state_carries_it_over_a_restart_unless_the_config_trusts_it_again():
    c = chain()
    c.set_aside_from("soak_1", 5 * HOUR_NS, 0)
    state = c.state()
    again = chain()
    again.restore(state)
    assert again.set_aside == {"soak_1": (5 * HOUR_NS, 0)}
    replaced = chain(trusted=("soak_1",))
    replaced.restore(state)
    assert replaced.set_aside == {}
    older = {k: v for k, v in state.items() if k != "set_aside"}  # a state from before
    again.restore(older)
    assert again.set_aside == {}


def parse(diagnosis: object):
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["refit"]["diagnosis"] = diagnosis
    return parse_config(Node(doc, "daq.yaml")).refit.diagnosis


def test_the_config_names_trusted_thermocouples_of_its_furnace():
    d = parse({"set_aside": False, "trusted": ["soak_1"]})
    assert d == DiagnosisConfig(set_aside=False, trusted=("soak_1",))
    with pytest.raises(ConfigError, match=r"refit\.diagnosis\.trusted\[0\]: must be one of"):
        parse({"trusted": ["soak_9"]})
    # the recorded settings give it back; a log from before the setting was refitted with
    # every thermocouple, and its replay is too
    assert refit_config(plain(RefitConfig(diagnosis=d))).diagnosis == d
    old = plain(RefitConfig(diagnosis=DiagnosisConfig()))
    del old["diagnosis"]["set_aside"], old["diagnosis"]["trusted"]
    assert refit_config(old).diagnosis.set_aside is False


def test_a_window_waits_for_a_verdict_that_may_set_a_thermocouple_aside_for_it():
    """Replay's path: the diagnosis of a window is still running; a later window that ends
    before the verdict's instant goes on, one that ends after it waits for the verdict; the
    logged verdict (here it named soak_1 drifting, while this run's diagnosis cannot even
    start) sets soak_1 aside, announced before the waiting window is published."""
    import time

    from furnace_daq import diagnosisrunner, refitworker
    from furnace_daq.diagnosistrigger import DiagnosisRequest
    from furnace_daq.refitworker import RefitRunner
    from furnace_model.log.messages import ModelDiagnosis, ModelEventKind
    from furnace_model.log.schema import MODEL_DIAGNOSIS, MODEL_EVENTS, MODEL_PARAMETERS

    blind = window(2)
    blind.experiment.tc[:, :2] = np.nan  # the soaking zone reads nothing: it fails at once
    request = DiagnosisRequest("misfit", "two windows above the floor", blind.experiment,
                               (2 * HOUR_NS, 3 * HOUR_NS), blind.experiment,
                               (HOUR_NS, 2 * HOUR_NS), 3 * 3600)
    logged = ModelDiagnosis(
        "explained", "thermocouple soak_1 drifts", "misfit", "two windows above the floor",
        sensor={"thermocouple": "soak_1", "onset": "1970-01-01T02:10:00.000Z",
                "rate_c_per_h": -1.5})
    got: list[tuple[str, object, int]] = []
    cfg = RefitConfig(period_s=3600.0, window_s=3600.0,
                      diagnosis=DiagnosisConfig(after_windows=1, time_limit_s=30.0))
    runner = RefitRunner(cfg, lambda topic, msg, ns: got.append((topic, msg, ns)),
                         furnace=PAPER, recorded_diagnoses={request.key: logged})
    lag = runner.verdict_lag_ns
    refit_kill = refitworker.KILL_FACTOR * 30.0 + refitworker.KILL_MARGIN_S
    diagnosis_kill = diagnosisrunner.KILL_FACTOR * 30.0 + diagnosisrunner.KILL_MARGIN_S
    assert lag == int((refit_kill + diagnosis_kill) * 1e9)  # both answered or killed by then

    def still(end_ns: int) -> Window:  # no burner change: published without a fit
        w = window(0)
        return Window(end_ns - HOUR_NS, end_ns, w.experiment, w.expected_bins,
                      w.complete_bins, 0)

    before, after = still(request.key + lag - 10**9), still(request.key + lag)
    try:
        assert runner.diagnoses is not None
        runner.diagnoses.request(request)
        runner.queue.extend([before, after])
        runner.pump()
        published = [ns for t, _, ns in got if t == MODEL_PARAMETERS]
        assert published == [before.end_ns] and list(runner.queue) == [after]
        deadline = time.monotonic() + 120
        while runner.queue and time.monotonic() < deadline:
            runner.pump(0.1)
        assert not runner.queue, "the window did not go on after the verdict"
    finally:
        runner.close()
    order = [(t, getattr(m, "kind", None)) for t, m, _ in got]
    assert order == [(MODEL_PARAMETERS, None), (MODEL_DIAGNOSIS, None),
                     (MODEL_EVENTS, ModelEventKind.DIAGNOSIS_FAILED),
                     (MODEL_EVENTS, ModelEventKind.SENSOR_SET_ASIDE), (MODEL_PARAMETERS, None)]
    aside = got[3][1]
    assert "soak_1" in aside.detail and aside.window_end == "1970-01-01T03:03:35.000Z"
    assert runner.chain.set_aside == {"soak_1": (request.key + lag, request.key)}
