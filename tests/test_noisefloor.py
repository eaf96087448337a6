"""The noise floor of each record, against the noise the plant simulator actually drew: white
and low-pass thermocouples, a noisier campaign, a loose junction, a drift, a lone sensor."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from furnace_model.identification.noisefloor import limits, pooled_floor, record_floor
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.parameters import PAPER_TABLE_V
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import SensorSpec
from furnace_model.simulation.structure import Inputs, ModelStructure

ROOT = Path(__file__).resolve().parents[1]


def _record(seed: int, n: int = 1500, **sensors) -> tuple:
    """A heat-up of n minutes and the noise its zone temperatures carry (bias removed)."""
    rng = np.random.default_rng(seed)
    times = np.array([0.0, n / 3, 2 * n / 3])
    counts = np.array([[6, 0, 0], [10, 3, 2], [8, 6, 4]], dtype=float)
    inputs = Inputs(times, counts, np.full(3, 25.0))
    spec = SensorSpec(**{"noise_sd_c": 1.5, "bias_sd_c": 0.5, **sensors})
    plant = Plant(ModelStructure(furnace=PAPER), PAPER_TABLE_V, spec, seed=int(rng.integers(2**31)))
    run = plant.run(inputs, np.arange(0.0, n), np.full(3, 25.0))
    exp = run.to_experiment(f"run{seed}")
    noise = exp.zone_temp - run.zone_true
    return exp, noise - noise.mean(axis=0)


@pytest.mark.parametrize("ar, white, n", [(0.0, 0.0, 1500), (0.5, 0.0, 1500), (0.7, 0.0, 1500),
                                          (0.9, 0.0, 1500), (0.9, 0.7, 1500), (0.5, 1.0, 1500),
                                          (0.0, 0.0, 240), (0.7, 0.0, 240), (0.5, 1.0, 240)])
def test_floor_is_the_noise_the_zone_temperature_carries(ar, white, n):
    """White or low-pass (first-order autoregression per minute, with or without white noise
    on top), over a heat-up or a gateway's four-hour window: over 25 records the floor is
    unbiased against the drawn noise, and the uncertainty it states is the scatter it
    shows."""
    ratios, claimed = [], []
    for seed in range(25):
        exp, noise = _record(seed, n=n, noise_ar_per_min=ar, white_sd_c=white)
        f = record_floor(exp)
        for w, z in enumerate(PAPER.zones):
            ratios.append(f.zones[z].floor_c / np.std(noise[:, w]))
            claimed.append(f.zones[z].rel_sd)
            assert f.zones[z].how == "pair"
    ratios = np.array(ratios)
    # a white estimate of the same data (first differences) reads 0.32 at 0.9 per minute
    assert abs(ratios.mean() - 1.0) < 0.04, ratios.mean()
    # the ratio's scatter holds the floor's and the drawn noise's sample errors alike
    scatter = ratios.std() / np.sqrt(2.0)
    assert 0.6 < scatter / np.mean(claimed) < 1.6, (scatter, np.mean(claimed))


def test_each_record_has_its_own_floor():
    """A campaign whose thermocouples are three times as noisy has three times the floor;
    pooled, the floors weigh as a pooled RMSE weighs the records."""
    quiet, _ = _record(1, noise_sd_c=1.0)
    noisy, _ = _record(2, noise_sd_c=3.0, n=3000)
    fq, fn = record_floor(quiet), record_floor(noisy)
    for z in PAPER.zones:
        assert fq.zones[z].floor_c == pytest.approx(1.0 / np.sqrt(2), rel=0.1)
        assert fn.zones[z].floor_c == pytest.approx(3.0 / np.sqrt(2), rel=0.1)
        pooled = pooled_floor([fq, fn])[z]
        expected = np.sqrt((1500 * fq.zones[z].floor_c ** 2 + 3000 * fn.zones[z].floor_c ** 2)
                           / 4500)
        assert pooled == pytest.approx(expected, rel=1e-9)


def test_a_gap_needs_more_with_few_independent_samples():
    """The gap limit is 1.25 floors for white noise over a long record, and wider for
    low-pass noise, whose samples are not independent."""
    white = record_floor(_record(3)[0])
    coloured = record_floor(_record(3, n=1000, noise_ar_per_min=0.9)[0])
    for z in PAPER.zones:
        assert limits([white], 1.25, 3.0)[z] == pytest.approx(1.25 * white.zones[z].floor_c)
        assert limits([coloured], 1.25, 3.0)[z] > 1.3 * coloured.zones[z].floor_c


def test_faults_and_drifts_do_not_raise_the_floor():
    exp, noise = _record(4)
    exp.tc[300:340, 2] -= 40.0  # heat_1: a loose junction reads low for 40 minutes
    exp.tc[:, 5] += 0.02 * np.maximum(exp.t_min - 500.0, 0.0)  # preheat_2 drifts 20 degC
    f = record_floor(exp)
    for w, z in enumerate(PAPER.zones):
        assert f.zones[z].floor_c == pytest.approx(np.std(noise[:, w]), rel=0.1), z


@pytest.mark.parametrize("n", [240, 700, 1500])
def test_a_drift_is_not_read_as_noise_however_long_the_record(n):
    """A thermocouple drifting 3 degC an hour from a third of the record on: the pair's
    difference grows by 12 to 60 degC, none of it noise. Over a window shorter than the
    trend's median, or in the last hours of a long record, a trend that does not follow the
    drift to its end reads it as noise."""
    ratios = []
    for seed in range(8):
        exp, noise = _record(seed, n=n)
        exp.tc[:, 0] -= 0.05 * np.maximum(exp.t_min - 0.3 * n, 0.0)  # soak_1
        f = record_floor(exp)
        ratios.append(f.zones["soak"].floor_c / np.std(noise[:, 0]))
    assert abs(np.mean(ratios) - 1.0) < 0.04, ratios


def test_a_lone_thermocouple_borrows_the_floor_of_the_pairs_and_says_so():
    exp, _ = _record(5, noise_ar_per_min=0.8)
    exp.tc[:, 1] = np.nan  # soak_2 removed: the soaking zone has one thermocouple
    f = record_floor(exp)
    soak = f.zones["soak"]
    assert soak.how == "borrowed" and "borrowed" in soak.words()
    assert soak.floor_c == pytest.approx(1.5, rel=0.15)  # one sensor: its own sd
    assert f.zones["heat"].floor_c == pytest.approx(1.5 / np.sqrt(2), rel=0.15)


def test_with_no_pair_at_all_the_floor_says_it_assumes_white_noise():
    exp, _ = _record(6)
    exp.tc[:, 1::2] = np.nan  # one thermocouple per zone
    f = record_floor(exp)
    for z in PAPER.zones:
        assert f.zones[z].how in ("equation_error", "second_difference")
        assert "white" in f.zones[z].words() and not np.isfinite(f.zones[z].rel_sd)
        assert f.zones[z].floor_c == pytest.approx(1.5, rel=0.15)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_lone_reading_whose_inputs_move_every_sample_has_its_noise_for_a_floor(seed):
    """Hourly rows of a room heated by an input modulated every hour: the reading bends at
    every row, and its second differences read that curvature as noise (2.7 times the
    thermocouple's 0.05 °C). The one-step error of a first-order fit follows it."""
    from furnace_model.diagnosis.hourlyroom import hourly_room

    zone = record_floor(hourly_room(seed)).zones["room"]
    assert zone.how == "equation_error" and "first-order fit" in zone.words()
    assert zone.floor_c == pytest.approx(0.05, rel=0.2)


def test_a_lone_reading_of_a_zone_held_by_its_loop_has_its_noise_for_a_floor():
    """A day of production: the loops step the burners nearly every minute, each step a
    bend of the reading that second differences read as noise (up to 2.6 times the
    thermocouples' 1.5 °C here)."""
    from furnace_model.simulation.scenario import load_scenario

    scenario = load_scenario(ROOT / "config" / "scenarios" / "paper_production.yaml")
    exp = Plant.from_scenario(scenario, seed=1).run_scenario(scenario).to_experiment("p")
    exp.tc[:, 1::2] = np.nan  # one thermocouple per zone
    for zone in record_floor(exp).zones.values():
        assert zone.floor_c == pytest.approx(1.5, rel=0.15)
    exp.tc[:, 4] = np.nan  # the preheating zone's thermocouple dead: no neighbour to read
    floors = record_floor(exp).zones
    assert floors["preheat"].how == "none"
    for z in ("soak", "heat"):
        assert floors[z].how == "equation_error"
        assert floors[z].floor_c == pytest.approx(1.5, rel=0.15)


@pytest.mark.parametrize("pairs", [True, False])
def test_readings_logged_to_a_coarse_step_keep_the_rounding_in_their_floor(pairs):
    """Rounded to 5 °C, the thermocouples (1.5 °C of noise) hold still for most minutes: a
    pair's difference and a lone reading's differences read no noise at all. A perfect
    model still misses each reading by the rounding, 5 / sqrt(12) = 1.44 °C, and more."""
    exp, _ = _record(4)
    if not pairs:
        exp.tc[:, 1::2] = np.nan
    exp.tc[:] = np.round(exp.tc / 5.0) * 5.0
    for zone in record_floor(exp).zones.values():
        assert zone.tc_sd_c >= 5.0 / np.sqrt(12.0) - 1e-9
