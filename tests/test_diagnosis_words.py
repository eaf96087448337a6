"""The diagnosis's words: temperatures with the digits their size needs, and the model and
its thermocouples named as the records' furnace has them."""

from __future__ import annotations

import dataclasses

import pytest

from furnace_model.diagnosis.words import baseline_label, model_words, paper_like, temp_c
from furnace_model.simulation.furnace import PAPER


@pytest.mark.parametrize(("x", "text"), [
    (0.03, "0.030"), (0.031, "0.031"), (0.0049, "0.0049"), (0.31, "0.31"), (0.55, "0.55"),
    (0.996, "1.0"), (1.0, "1.0"), (1.04, "1.0"), (7.24, "7.2"), (120.38, "120.4"),
    (-0.03, "-0.030"), (0.0, "0.0"), (float("nan"), "-"), (float("inf"), "-"),
])
def test_a_temperature_keeps_two_significant_digits_below_one_degree(x, text):
    assert temp_c(x) == text


def test_a_temperature_in_a_table_keeps_two_decimals_and_a_sign_when_asked():
    assert temp_c(1.054, 2) == "1.05" and temp_c(0.03, 2) == "0.030"
    assert temp_c(0.0031, 2) == "0.0031" and temp_c(12.345, 2) == "12.35"
    assert temp_c(8.0, 0, sign=True) == "+8" and temp_c(-29.4, 0, sign=True) == "-29"
    assert temp_c(0.4, 0) == "0.40" and temp_c(0.2, 1, sign=True) == "+0.20"


def test_the_model_is_the_papers_only_on_the_papers_furnace():
    assert paper_like(PAPER) and model_words(PAPER) == "the paper's model"
    assert baseline_label(PAPER) == "baseline (paper's model)"
    one = dataclasses.replace(PAPER, name="plant7", thermocouples=(1, 1, 1))
    assert one.paper_structure and not paper_like(one)
    assert model_words(one) == "the model of furnace 'plant7'"
    assert baseline_label(one) == "baseline"
    three = dataclasses.replace(PAPER, name="plant8", thermocouples=(2, 3, 1))
    assert model_words(three) == "the model of furnace 'plant8'"


def test_a_drift_says_its_interval_and_when_the_record_does_not_pin_its_rate():
    """A thermocouple named with its rate and onset and their 95% intervals; from a record
    that holds little of the drift the rate trades with the onset, and the words say the
    rate is loose instead of giving it as found."""
    from furnace_model.effects import SensorDrift

    params, options = {"drift_rate": -0.0233, "t_drift": 120.0}, {"sensor": "soak_1"}
    tight = SensorDrift.found_within(params, options, {"drift_rate": (-0.026, -0.021),
                                                       "t_drift": (110.0, 131.0)})
    assert tight == ("thermocouple soak_1 drifts -1.40 °C/h (95% interval -1.56 to -1.26) "
                     "from minute 120 (95% interval 110 to 131)")
    loose = SensorDrift.found_within(params, options, {"drift_rate": (-0.06, -0.005),
                                                       "t_drift": (60.0, 190.0)})
    assert loose == ("thermocouple soak_1 drifts from minute 120 (95% interval 60 to 190), "
                     "at a rate the record does not pin down: -1.40 °C/h (95% interval -3.60 "
                     "to -0.30)")
    assert SensorDrift.found_within(params, options, {}) == \
        "thermocouple soak_1 drifts -1.40 °C/h from minute 120"


def test_a_fuel_change_is_judged_pinned_on_its_change_not_its_ratio():
    from furnace_model.effects import FuelChange

    params = {"fuel_ratio": 0.8, "t_fuel": 1028.0}
    assert FuelChange.found_within(params, {}, {"fuel_ratio": (0.77, 0.83)}) == \
        "each burner gives -20% heat (x0.80, 95% interval x0.77 to x0.83) from minute 1028"
    assert "does not pin down: x0.80 (95% interval x0.55 to x1.05)" in \
        FuelChange.found_within(params, {}, {"fuel_ratio": (0.55, 1.05)})
