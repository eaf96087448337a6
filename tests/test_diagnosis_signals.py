"""The diagnosis asks whether the model's error follows a logged signal the model does not
use: known truth from the plant simulator, where a door switch (logged, undeclared) takes
heat from the preheating zone, and where a logged signal that does nothing sits beside a
real effect."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from furnace_model.diagnosis import diagnose
from furnace_model.diagnosis.cases import draw_case
from furnace_model.diagnosis.signals import unused_signals
from furnace_model.experiment import Experiment
from furnace_model.simulation.furnace import PAPER, Disturbance
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario
from furnace_model.simulation.structure import Inputs, ModelStructure

DOOR_GAIN = -6.0  # °C/min in the preheating zone while the door is open


def _door_record(scenario: str, seed: int) -> Experiment:
    """A heat-up of the paper's furnace whose preheating door opens for 10-30 minutes every
    one to three hours; read back as the paper's furnace, the door is a signal only."""
    s = load_scenario(f"config/scenarios/{scenario}.yaml")
    with_door = dataclasses.replace(PAPER, disturbances=(
        Disturbance("door", "open", (2,), "door", (0.0, 1.0)),))
    rng = np.random.default_rng(seed)
    t = s.sample_times()
    door = np.zeros(t.size)
    k = 60
    while k < t.size:
        d = int(rng.integers(10, 30))
        door[k:k + d] = 1.0
        k += d + int(rng.integers(60, 180))
    j = np.searchsorted(s.steps_t, t, side="right") - 1
    inputs = Inputs.from_samples(t, s.steps_burners[j], np.full(t.size, s.t_air_c),
                                 disturbances=door[:, None])
    plant = Plant(ModelStructure(furnace=with_door),
                  {**s.params, "gain_door_preheat": DOOR_GAIN}, s.sensors, seed)
    run = plant.run(inputs, t, s.initial_c, s.start_time).to_experiment(scenario)
    return Experiment(run.name, run.t_min, run.tc, run.burners, run.t_air, run.start_time,
                      scenario, furnace=PAPER, signals={"door": run.disturbances[:, 0]})


@pytest.fixture(scope="module")
def door_diagnosis():
    fit, hold = _door_record("paper_exp1", 1), _door_record("paper_exp2", 2)
    return diagnose([fit], [hold], effects=("wall_storage", "sensor_lag"))


def test_unused_signals_are_those_every_record_has_and_that_move():
    a = _door_record("paper_exp1", 1)
    flat = dataclasses.replace(a, signals={**a.signals, "flat": np.full(len(a), 3.0)})
    assert unused_signals([flat]) == ("door",)
    moving = np.linspace(900.0, 1200.0, len(a))
    references = {name: moving for name in ("setpoint_soak", "heat_sp", "SP preheat")}
    controlled = dataclasses.replace(a, signals={**a.signals, **references, "spare": moving})
    assert unused_signals([controlled]) == ("door", "spare")
    assert unused_signals([flat, dataclasses.replace(a, signals={})]) == ()


def test_an_undeclared_door_is_named_as_an_unmodelled_input(door_diagnosis):
    d = door_diagnosis
    door = next(c for c in d.candidates if c.signal == "door")
    assert d.candidates[0] is door
    lo, hi = door.ci95["gain_door_preheat"]
    assert lo <= DOOR_GAIN <= hi
    assert door.gap_closed_pct > 80.0
    assert d.verdict.status == "explained"
    assert d.verdict.unmodelled_inputs == ["door"]
    assert d.verdict.effects == []
    assert "door" in d.verdict.sentence and "disturbance" in d.verdict.sentence
    out = d.to_json()
    first = out["candidates"][0]
    assert first["effect"] == "unmodelled_input" and first["signal"] == "door"
    assert out["verdict"]["unmodelled_inputs"] == ["door"]


def test_a_signal_that_does_nothing_earns_no_credit_beside_a_real_effect():
    case = draw_case("wall_storage", np.random.default_rng(5), furnace=PAPER)
    rng = np.random.default_rng(9)

    def noise_signal(e: Experiment) -> Experiment:
        o2 = np.repeat(rng.uniform(1.0, 6.0, len(e) // 60 + 1), 60)[:len(e)]
        return dataclasses.replace(e, signals={"o2_pct": o2})

    d = diagnose([noise_signal(e) for e in case.fit], [noise_signal(e) for e in case.holdout],
                 effects=("wall_storage", "sensor_lag"))
    o2 = next(c for c in d.candidates if c.signal == "o2_pct")
    from furnace_model.diagnosis import credited
    assert not credited(o2)
    assert d.verdict.effects == ["wall_storage"]
    assert d.verdict.unmodelled_inputs == []
