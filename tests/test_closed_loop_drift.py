"""A thermocouple that drifts under control is told apart from a furnace that changed
(known truth, production records of the paper's furnace held by its PI loops): the loop
reading the drifting thermocouple moves the true zone, so the burners and the readings
both show it, and a fuel change is the other candidate the verdict has to turn down."""

from __future__ import annotations

import numpy as np
import pytest

from furnace_model.diagnosis import diagnose
from furnace_model.diagnosis.cases import draw_closed_loop_case

ONSET_BEFORE, AFTER = 600.0, 900.0  # minutes of the record before and after the onset


def _around_onset(effect: str, draw: int):
    case = draw_closed_loop_case(effect, np.random.default_rng(draw))
    truth = case.truth[effect]
    onset = next(v for k, v in truth.items() if k.startswith("t_"))
    return case.fit[0].between(max(0.0, onset - ONSET_BEFORE), onset + AFTER), truth


@pytest.mark.parametrize("draw", [pytest.param(5, marks=pytest.mark.slow), 6])
# 6: the partner of the drifting one looks high
def test_a_drifting_thermocouple_under_control_is_named_with_its_onset(draw):
    record, truth = _around_onset("sensor_drift", draw)
    d = diagnose([record], None, effects=("sensor_drift", "fuel_change"))
    assert d.verdict.status == "explained", d.verdict.sentence
    assert d.verdict.effects == ["sensor_drift"]
    kept = d.kept
    assert kept.options["sensor_drift"]["sensor"] == truth["sensor"], kept.options
    assert kept.params["t_drift"] == pytest.approx(truth["t_drift"], abs=90.0)
    assert kept.params["drift_rate"] == pytest.approx(truth["drift_rate"], rel=0.15)
    assert f"thermocouple {truth['sensor']} drifts" in d.verdict.sentence


@pytest.mark.slow  # half a minute of one core
def test_a_fuel_change_under_control_is_named_not_a_sensor():
    record, truth = _around_onset("fuel_change", 3)
    d = diagnose([record], None, effects=("sensor_drift", "fuel_change"))
    assert d.verdict.status == "explained", d.verdict.sentence
    assert d.verdict.effects == ["fuel_change"]
    assert d.kept.params["t_fuel"] == pytest.approx(truth["t_fuel"], abs=30.0)
    assert d.kept.params["fuel_ratio"] == pytest.approx(truth["fuel_ratio"], rel=0.05)
