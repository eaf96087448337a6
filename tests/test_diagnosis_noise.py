"""The diagnosis on thermocouples as plants have them: a held-out campaign with noisier
thermocouples, and low-pass noise. A model at each record's own floor has no gap; a real
effect is still named. Cases are the selfcheck's, with their thermocouples drawn apart."""

from __future__ import annotations

import numpy as np
import pytest

from furnace_model.diagnosis import diagnose
from furnace_model.diagnosis.cases import case_rng, draw_case
from furnace_model.diagnosis.selfcheck import check
from furnace_model.simulation.furnace import PAPER

QUICK = ("zone_burners", "sensor_lag", "zone_losses", "fuel_change")


@pytest.mark.parametrize("noise", ["noisier-holdout", "low-pass"])
def test_no_effect_no_gap(noise):
    """Held-out thermocouples one to three times as noisy as the fitted ones, or low-pass
    noise (0.5-0.9 per minute, with and without white noise on top): judged against a floor
    pooled over both records, or read off first differences, these were gaps."""
    outcomes = check(["none"], 6, seed=0, noise=noise, furnace=PAPER)
    wrong = [(o.draw, o.status, o.description) for o in outcomes if not o.correct]
    assert not wrong, wrong


@pytest.mark.parametrize("noise", [pytest.param("noisier-holdout", marks=pytest.mark.slow),
                                   "low-pass"])
def test_a_real_effect_is_still_named(noise):
    outcomes = check(["zone_burners"], 1, seed=0, noise=noise, candidates=QUICK, furnace=PAPER)
    o = outcomes[0]
    assert o.correct and o.named == ["zone_burners"], (o.status, o.named, o.reason)


@pytest.mark.slow
@pytest.mark.timeout(3600)  # 21 diagnoses, some of minutes each
@pytest.mark.parametrize("noise", ["noisier-holdout", "low-pass"])
def test_every_effect_is_named_on_such_thermocouples(noise):
    labels = ["none", "zone_burners", "zone_losses", "sensor_lag", "dead_time",
              "fuel_change", "sensor_drift"]
    outcomes = check(labels, 3, seed=1, noise=noise, furnace=PAPER)
    wrong = [(o.label, o.draw, o.status, o.named, o.reason) for o in outcomes
             if not (o.correct or o.absorbed)]
    assert len(wrong) <= 1, wrong


def test_a_zone_with_one_thermocouple_says_how_its_floor_was_estimated():
    """A held-out campaign whose soaking zone lost a thermocouple: its floor is borrowed from
    the record's pairs (one sensor's noise, not a pair mean's), the JSON says so, and a model
    at that floor still has no gap."""
    case = draw_case(None, case_rng(0, "none", 0), furnace=PAPER)
    case.holdout[0].tc[:, 1] = np.nan  # soak_2 gone
    d = diagnose(case.fit, case.holdout, seed=0)
    assert d.verdict.status == "no_gap", d.verdict.sentence
    held = d.to_json()["noise_floors"][1]["zones"]
    assert held["soak"]["how"] == "borrowed" and held["heat"]["how"] == "pair"
    # one thermocouple of sd 1.5 against the mean of two
    assert held["soak"]["floor_c"] == pytest.approx(np.sqrt(2) * held["heat"]["floor_c"],
                                                    rel=0.1)
