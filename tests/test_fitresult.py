"""A fit's result predicts its own records and new ones, and re-estimates chosen parameters
on other data with the rest held: known-truth data from the simulator."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SCENARIOS
from heatups import heat_up

from furnace_model.effects import SensorDrift
from furnace_model.errors import FurnaceError
from furnace_model.identification.fit import fit
from furnace_model.identification.model import Model, Refinement
from furnace_model.identification.scores import zone_metrics
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.parameters import PAPER_TABLE_V
from furnace_model.simulation.scenario import SensorSpec
from furnace_model.simulation.structure import Inputs, ModelStructure

BIAS = [3.0, 1.0, -2.0, -4.0, 0.5, 1.5]  # per thermocouple: zone offsets 2, -3, 1


@pytest.fixture(scope="module")
def biased():
    """Two heat-ups, thermocouple biases of their own, fitted with zone offsets."""
    a = heat_up(SCENARIOS, PAPER_TABLE_V, 2.0, seed=1, name="a",
                sensors=SensorSpec(noise_sd_c=1.5, bias_c=BIAS))
    b = heat_up(SCENARIOS, PAPER_TABLE_V, 2.0, seed=2, name="b",
                sensors=SensorSpec(noise_sd_c=1.5, bias_c=[-x for x in BIAS]))
    return a, b, fit([a, b], zone_offsets=True, seed=0, profile=False)


def test_own_records_are_predicted_as_the_fit_scored_them(biased):
    a, b, res = biased
    for j, exp in enumerate((a, b)):
        run = ModelStructure(furnace=PAPER).simulate(res.params, Inputs.of(exp), exp.t_min,
                                                     res.x0[j][None])
        np.testing.assert_allclose(res.predict(j), run.zones[0] + res.offsets(j), rtol=1e-12)
        # x0 given, offsets not: the furnace as unbiased thermocouples would read it
        np.testing.assert_allclose(res.predict(exp, res.x0[j]), run.zones[0], rtol=1e-12)
    both = np.concatenate([res.predict(0), res.predict(1)])
    assert zone_metrics(np.concatenate([a.zone_temp, b.zone_temp]), both,
                        PAPER.zones) == res.per_zone
    np.testing.assert_allclose(res.offsets(0), [2.0, -3.0, 1.0], atol=0.3)
    np.testing.assert_allclose(res.response(1).states[0, 0], res.x0[1], rtol=1e-12)
    with pytest.raises(IndexError, match="2 record"):
        res.predict(2)


def test_own_records_with_a_sensor_effect_are_what_the_fit_scored(scenarios):
    ms = ModelStructure([SensorDrift(sensor="heat_2", furnace=PAPER)], furnace=PAPER)
    truth = {**PAPER_TABLE_V, "drift_rate": 0.004, "t_drift": 1000.0}
    exp = heat_up(scenarios, truth, 2.0, structure=ms)
    exp.tc[100:400, 3] = np.nan  # the drifting one gives nothing for a while
    res = fit([exp], ms, init=truth, fixed={"t_drift": 1000.0}, profile=False)
    assert zone_metrics(exp.zone_temp, res.predict(0), PAPER.zones) == res.per_zone
    assert res.per_zone["heat"]["rmse_c"] < 1.5


def test_a_new_record_gets_its_own_start_and_offsets(biased):
    a, b, res = biased
    new = a.between(1000.0, 2500.0)  # a window cut from a running furnace: not at rest
    pred = res.predict(new)
    refined = res.refine([new])
    assert isinstance(refined, Refinement) and refined.free == ()
    np.testing.assert_array_equal(pred, refined.predict(0))
    np.testing.assert_allclose(refined.offsets(0), res.offsets(0), atol=0.5)
    rmse = np.sqrt(np.nanmean((new.zone_temp - pred) ** 2, axis=0))
    assert np.all(rmse < 1.5), rmse
    unbiased = Model(res.structure, res.params).predict(new)  # no offsets estimated
    assert np.sqrt(np.nanmean((new.zone_temp - unbiased) ** 2, axis=0)).max() > 2.0


def test_records_refined_with_nothing_shared_are_estimated_alone(biased):
    a, b, res = biased
    both = res.refine([a, b])
    alone = res.refine([b])
    np.testing.assert_array_equal(both.x0[1], alone.x0[0])
    assert both.zone_offsets_c[1] == alone.zone_offsets_c[0]
    assert both.params == res.params and both.std == {}


def test_refine_recovers_a_changed_parameter_with_the_others_held(scenarios):
    """The furnace's heat per burner fell by 20% (a fuel switch); the model fitted before
    it, refined on new data with f free, finds the new f within its interval."""
    truth = {**PAPER_TABLE_V, "f": 0.8 * PAPER_TABLE_V["f"]}
    after = heat_up(scenarios, truth, 2.0, seed=5, name="after")
    before = Model(ModelStructure(furnace=PAPER), PAPER_TABLE_V)
    refined = before.refine([after], free=("f",))
    f, se = refined.params["f"], refined.std["f"]
    assert abs(f - truth["f"]) < 3 * se and se < 0.005 * truth["f"], (f, se)
    assert {k: v for k, v in refined.params.items() if k != "f"} == \
        {k: v for k, v in PAPER_TABLE_V.items() if k != "f"}
    assert refined.cov.shape == (1, 1) and refined.cov[0, 0] == pytest.approx(se ** 2)
    assert refined.stop_reason == "converged"
    assert refined.per_zone["soak"]["rmse_c"] < 1.5
    # held at the old value the same data are far off: the refinement did the work
    stale = before.refine([after])
    assert stale.per_zone["soak"]["rmse_c"] > 5 * refined.per_zone["soak"]["rmse_c"]
    # a noise level given for the covariance scales the standard error, not the estimate
    scaled = before.refine([after], free=("f",), sigma=3.0)
    assert scaled.params["f"] == f
    assert scaled.std["f"] / se == pytest.approx(3.0 / np.sqrt(refined.sse / (
        refined.n_obs - 4)), rel=1e-6)


def test_held_offsets_are_kept_and_read(biased):
    a, b, res = biased
    span = a.between(2000.0, 2600.0)
    held = res.refine([span], free=("f",), offsets=[res.offsets(0)])
    np.testing.assert_array_equal(held.offsets(0), res.offsets(0))
    run = ModelStructure(furnace=PAPER).simulate(held.params, Inputs.of(span), span.t_min,
                                                 held.x0[0][None])
    np.testing.assert_allclose(held.predict(0), run.zones[0] + res.offsets(0), rtol=1e-12)


def test_refine_names_what_it_cannot_do(biased):
    a, b, res = biased
    with pytest.raises(FurnaceError, match="unknown parameter"):
        res.refine([a], free=("g",))
    with pytest.raises(FurnaceError, match="no data"):
        res.refine([], free=("f",))
    with pytest.raises(FurnaceError, match="missing"):
        Model(ModelStructure([SensorDrift(furnace=PAPER)], furnace=PAPER), PAPER_TABLE_V)
