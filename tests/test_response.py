"""What a simulation returns: the zone outputs, the states, each thermocouple's reading and
the zone means a fit compares with the data, for a batch of parameter sets."""

from __future__ import annotations

import numpy as np
import pytest

from furnace_model.effects import SensorDrift, SensorLag, WallStorage
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.parameters import PAPER_TABLE_V
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.response import Response
from furnace_model.simulation.scenario import SensorSpec
from furnace_model.simulation.structure import Inputs, ModelStructure

INPUTS = Inputs(np.array([0.0, 60.0, 200.0]), np.array([[4, 0, 0], [9, 3, 0], [2, 0, 0.0]]),
                np.full(3, 30.0))
T = np.linspace(0.0, 400.0, 201)
X0 = np.array([500.0, 400.0, 200.0])


def test_zones_are_the_sensed_states_whether_the_states_are_asked_for_or_not():
    ms = ModelStructure([SensorLag(furnace=PAPER), WallStorage(furnace=PAPER)], furnace=PAPER)
    values = {**ms.defaults(), **PAPER_TABLE_V}
    lazy = ms.simulate(values, INPUTS, T, X0)
    eager = ms.simulate(values, INPUTS, T, X0, states=True)
    assert isinstance(lazy, Response) and len(lazy) == 1
    assert lazy.states.shape == (1, T.size, ms.n_states)
    np.testing.assert_allclose(lazy.states, eager.states, rtol=1e-12, atol=1e-9)
    C = ms.system(ms.theta(values)).C[0]
    np.testing.assert_allclose(eager.zones[0], eager.states[0] @ C.T, rtol=1e-12)
    np.testing.assert_allclose(lazy.zones, eager.zones, rtol=1e-10, atol=1e-8)
    # the lagged sensors read behind the gas: the zones are not the first three states
    assert np.abs(lazy.zones[0] - lazy.states[0, :, :3]).max() > 1.0
    np.testing.assert_array_equal(lazy.zone("heat"), lazy.zones[:, :, 1])
    np.testing.assert_array_equal(lazy.final_state, lazy.states[:, -1])
    np.testing.assert_array_equal(lazy.state_at(101.0), lazy.states[:, 51])  # T[51] = 102


def test_a_drifting_thermocouple_reads_its_zone_plus_the_drift():
    ms = ModelStructure([SensorDrift(sensor="heat_2", furnace=PAPER)], furnace=PAPER)
    values = {**PAPER_TABLE_V, "drift_rate": 0.05, "t_drift": 100.0}
    run = ms.simulate(values, INPUTS, T, X0)
    ramp = 0.05 * np.maximum(T - 100.0, 0.0)
    assert run.sensors.shape == (1, T.size, len(PAPER.sensors))
    np.testing.assert_allclose(run.sensor("heat_2")[0] - run.zone("heat")[0], ramp, atol=1e-12)
    for name in PAPER.sensors:
        if name != "heat_2":
            np.testing.assert_array_equal(run.sensor(name), run.zone(name.rsplit("_", 1)[0]))
    # as the zone mean reads it: half the drift, all of it where its partner gave nothing,
    # none where it gave nothing itself
    good = np.ones((T.size, 6), dtype=bool)
    good[:50, PAPER.sensors.index("heat_1")] = False
    good[150:, PAPER.sensors.index("heat_2")] = False
    heat = run.readings(good)[0, :, 1] - run.zone("heat")[0]
    np.testing.assert_allclose(heat[:50], ramp[:50], atol=1e-12)
    np.testing.assert_allclose(heat[50:150], ramp[50:150] / 2, atol=1e-12)
    np.testing.assert_allclose(heat[150:], 0.0, atol=1e-12)
    np.testing.assert_allclose(run.readings()[0, :, 1] - run.zone("heat")[0], ramp / 2,
                               atol=1e-12)
    run = ModelStructure(furnace=PAPER).simulate(PAPER_TABLE_V, INPUTS, T, X0)
    assert run.readings(good) is not None


def test_the_baseline_reads_its_zones():
    run = ModelStructure(furnace=PAPER).simulate(PAPER_TABLE_V, INPUTS, T, X0)
    assert run.readings() is run.zones
    np.testing.assert_array_equal(run.sensors, run.zones[:, :, [0, 0, 1, 1, 2, 2]])


def test_a_noiseless_plant_reads_what_the_response_says_its_thermocouples_read():
    ms = ModelStructure([SensorDrift(sensor="soak_1", furnace=PAPER), SensorLag(furnace=PAPER)],
                        furnace=PAPER)
    values = {**ms.defaults(), **PAPER_TABLE_V, "drift_rate": -0.02, "t_drift": 50.0}
    plant = Plant(ms, values, SensorSpec(noise_sd_c=0.0, bias_sd_c=0.0))
    run = plant.run(INPUTS, T, X0)
    response = ms.simulate(values, INPUTS, T, X0)
    np.testing.assert_allclose(run.tc, response.sensors[0], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(run.zone_true, response.states[0, :, :3], rtol=1e-12, atol=1e-9)


def test_one_set_of_a_batch_is_that_set_simulated_alone():
    ms = ModelStructure([SensorDrift(furnace=PAPER)], furnace=PAPER)
    values = {**PAPER_TABLE_V, "f": np.array([0.2, 0.25, 0.3]), "drift_rate": 0.01,
              "t_drift": 0.0}
    batch = ms.simulate(values, INPUTS, T, X0)
    one = batch[1]
    alone = ms.simulate({**values, "f": 0.25}, INPUTS, T, X0)
    assert len(batch) == 3 and len(one) == 1
    np.testing.assert_allclose(one.zones, alone.zones, rtol=1e-12)
    np.testing.assert_allclose(one.sensors, alone.sensors, rtol=1e-12)
    np.testing.assert_allclose(one.states, alone.states, rtol=1e-12)
    frame = batch.to_pandas(2)
    assert list(frame.columns) == ["t_min", *PAPER.zones, *(f"tc_{s}" for s in PAPER.sensors)]
    np.testing.assert_array_equal(frame["heat"], batch.zones[2, :, 1])
    with pytest.raises(ValueError):
        batch.sensor("nowhere")
