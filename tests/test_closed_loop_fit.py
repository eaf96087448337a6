"""Fitting records of a furnace held at its setpoints: the loops' burners follow the zones'
noise and the temperatures barely move, so what starts a fit on a heat-up may not start one
here (furnace_model.identification.equationerror)."""

from __future__ import annotations

import numpy as np
import pytest

from furnace_model.diagnosis.cases import draw_closed_loop_case, production_scenario
from furnace_model.identification.fit import fit


@pytest.mark.parametrize(("start", "end"), [(1500.0, 2900.0), (720.0, 2880.0)])
def test_a_window_held_at_setpoint_is_fitted_to_the_truth(start, end):
    """A day of production past the start-up (the first from a stop of the mill): every
    parameter within twice its 95% interval's half-width of the plant's (about four sds:
    one draw, ten parameters; coverage is test_coverage's), the fit at the noise."""
    case = draw_closed_loop_case(None, np.random.default_rng(3))
    window = case.fit[0].between(start, end)
    result = fit([window], zone_offsets=True, seed=1)
    truth = production_scenario().values()
    missed = {k: (truth[k], v, result.ci95[k]) for k, v in result.params.items()
              if abs(v - truth[k]) > result.ci95[k][1] - result.ci95[k][0]}
    assert not missed, missed
    noise = case.truth.get("noise_sd_c", 1.5) / np.sqrt(2)  # a zone's mean of two
    rmse = {z: result.per_zone[z]["rmse_c"] for z in result.per_zone}
    assert max(rmse.values()) < 1.15 * noise, rmse
    assert result.runs[0]["stop_reason"] == "converged", result.runs[0]


def test_offsets_a_window_at_setpoint_cannot_tell_from_the_level_are_said_to_be_so():
    """Held at its setpoints the furnace's level and its thermocouples' offsets trade
    (the rates take up a shift of a few degrees in a thousand): the diagnosis does not
    call such an offset a bias. A heat-up from cold pins them."""
    from furnace_model.diagnosis.fitting import undetermined_offsets

    case = draw_closed_loop_case(None, np.random.default_rng(3))
    held = fit([case.fit[0].between(720.0, 2880.0)], zone_offsets=True, seed=1, profile=False)
    assert set(undetermined_offsets(held)) >= {"soak", "heat"}, held.zone_offsets_ci95_c
    heat_up = fit([case.fit[0].between(0.0, 1500.0)], zone_offsets=True, seed=1, profile=False)
    assert undetermined_offsets(heat_up) == (), heat_up.zone_offsets_ci95_c


def test_the_sampled_start_keeps_the_scale_of_a_zone_that_settles_within_a_sample():
    """Held at setpoint, the preheating zone (a time constant under the minute a sample
    spans) shows its balance but not its rates' scale to the integrated equations, which
    shrink it; the equations over one sample keep it."""
    from furnace_model.identification.equationerror import equation_error, sampled_start
    from furnace_model.simulation.structure import ModelStructure

    case = draw_closed_loop_case(None, np.random.default_rng(3))
    window = case.fit[0].between(720.0, 2880.0)
    structure = ModelStructure(furnace=window.furnace)
    truth = production_scenario().values()
    fast = ("k_preheat_heat", "loss_preheat", "gain_preheat")
    sampled = sampled_start(structure, [window])
    integrated = equation_error(structure, [window])
    assert all(0.7 < sampled[k] / truth[k] < 1.4 for k in fast), sampled
    assert all(integrated[k] / truth[k] < 0.6 for k in fast), integrated
