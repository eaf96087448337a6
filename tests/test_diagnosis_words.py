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
