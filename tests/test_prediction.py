"""K-step-ahead prediction against data with a known truth: the simulator is the furnace."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from heatups import ZONE_SD, heat_up

from furnace_model.effects import DeadTime, Radiation, SensorLag, WallStorage
from furnace_model.errors import FurnaceError
from furnace_model.identification.model import Model
from furnace_model.identification.prediction import (
    _by_free_response,
    _by_windows,
    predict_ahead,
    score_ahead,
)
from furnace_model.identification.scores import zone_metrics
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.parameters import PAPER_TABLE_V
from furnace_model.simulation.scenario import SensorSpec
from furnace_model.simulation.structure import Inputs, ModelStructure

SCENARIOS = Path(__file__).resolve().parent.parent / "config" / "scenarios"
EXACT = SensorSpec(noise_sd_c=0.0, bias_sd_c=0.0)


@pytest.fixture(scope="module")
def noisy():
    return heat_up(SCENARIOS, PAPER_TABLE_V, 1.0, seed=3)


def test_on_exact_data_the_prediction_is_the_data_whatever_the_start():
    """Every state of the paper's model is a zone temperature: restarted from exact readings,
    the model predicts the next ones exactly, even from a simulation started 40 °C off."""
    exp = heat_up(SCENARIOS, PAPER_TABLE_V, 1.0, sensors=EXACT)
    x0 = exp.zone_temp[0] + np.array([40.0, -25.0, 10.0])
    sim = Model(ModelStructure(furnace=PAPER), PAPER_TABLE_V).predict(exp, x0)
    assert np.abs(sim - exp.zone_temp).max() > 5  # the simulation itself is off
    for k in (1, 7):
        ahead = predict_ahead(PAPER_TABLE_V, exp, k, x0=x0)
        assert np.abs(ahead[k:] - exp.zone_temp[k:]).max() < 1e-9
        assert np.array_equal(ahead[:k], sim[:k])  # nothing measured K samples before these


def test_hidden_states_restart_from_the_simulation(scenarios):
    """With a wall, a lagged sensor and a dead time the decayed restart of a linear model
    equals simulating each window from its restarted state."""
    structure = ModelStructure([WallStorage(furnace=PAPER), SensorLag(furnace=PAPER),
                                DeadTime(furnace=PAPER)], furnace=PAPER)
    values = {**structure.defaults(), **PAPER_TABLE_V}
    exp = heat_up(scenarios, values, 1.0, structure=structure).between(0, 700)
    x0 = exp.zone_temp[0] + np.array([20.0, -10.0, 5.0])  # a simulation the readings correct
    sim = Model(structure, values).predict(exp, x0)
    states = structure.simulate(values, Inputs.of(exp), exp.t_min, x0[None], states=True).states[0]
    C = structure.system(structure.theta(values)).C[0]
    miss = np.nan_to_num(exp.zone_temp - sim) @ np.linalg.pinv(C).T
    for k in (1, 6):
        fast = _by_free_response(values, exp, k, structure, sim, states, miss)
        slow = _by_windows(values, exp, k, structure, sim, states, miss)
        assert np.abs(fast - slow).max() < 1e-8
        assert np.abs(fast - sim).max() > 0.5  # the readings did move the prediction


def test_a_nonlinear_model_is_restarted_window_by_window(scenarios):
    structure = ModelStructure([Radiation(furnace=PAPER)], furnace=PAPER)
    values = {**structure.defaults(), **PAPER_TABLE_V}
    exp = heat_up(scenarios, values, 1.0, structure=structure, sensors=EXACT).between(0, 400)
    x0 = exp.zone_temp[0] + np.array([30.0, 0.0, -20.0])
    ahead = predict_ahead(values, exp, 2, structure, x0=x0)
    assert np.abs(ahead[2:] - exp.zone_temp[2:]).max() < 1e-3  # the integrator's accuracy


def test_one_step_error_is_about_the_noise_of_two_readings(noisy):
    """The start carries one sample's noise and the predicted sample its own: on data from
    the model the 1-step RMSE lies between the noise and sqrt(2) times it."""
    m = zone_metrics(noisy.zone_temp, predict_ahead(PAPER_TABLE_V, noisy, 1), PAPER.zones)
    for zone, v in m.items():
        assert 0.95 * ZONE_SD < v["rmse_c"] < 1.1 * np.sqrt(2) * ZONE_SD, (zone, v)


def test_a_biased_model_is_trusted_less_the_further_it_predicts(noisy):
    """f 10% high: the simulation drifts tens of degrees away, a short prediction does not;
    the fit falls with the horizon and reaches the simulation's when K spans the record."""
    wrong = {**PAPER_TABLE_V, "f": PAPER_TABLE_V["f"] * 1.1}
    sim = zone_metrics(noisy.zone_temp, Model(ModelStructure(furnace=PAPER), wrong).predict(noisy),
                       PAPER.zones)
    fits = {k: zone_metrics(noisy.zone_temp, predict_ahead(wrong, noisy, k), PAPER.zones)
            for k in (1, 5, 30, 300, len(noisy))}
    for zone in sim:
        seq = [fits[k][zone]["fit_pct"] for k in sorted(fits)]
        assert seq == sorted(seq, reverse=True), (zone, seq)
        assert seq[0] > 98.5 > 95 > sim[zone]["fit_pct"], (zone, seq, sim[zone])
        assert seq[-1] == sim[zone]["fit_pct"]


def test_score_ahead_per_experiment_and_pooled(noisy, scenarios):
    other = heat_up(scenarios, PAPER_TABLE_V, 1.0, seed=4, name="other")
    per, pooled = score_ahead(PAPER_TABLE_V, [noisy, other], 3)
    assert set(per) == {noisy.name, "other"}
    for zone in pooled:
        n = per[noisy.name][zone]["n"] + per["other"][zone]["n"]
        assert pooled[zone]["n"] == n
        ms = [per[e][zone]["rmse_c"] ** 2 * per[e][zone]["n"] for e in per]
        assert pooled[zone]["rmse_c"] == pytest.approx(np.sqrt(sum(ms) / n))


@pytest.mark.parametrize("k", [0, -3, 1.5])
def test_a_horizon_must_be_a_whole_number_of_samples(noisy, k):
    with pytest.raises(FurnaceError, match="whole number of samples"):
        predict_ahead(PAPER_TABLE_V, noisy, k)
