"""Offsets that are thermocouple biases and initial states where the furnace was: bounded by
what is physical, flagged on the bound, carried from the fit to every score (known truth:
the plant simulator with an effect the model lacks)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from furnace_model.config import ConfigError
from furnace_model.diagnosis.selfcheck import carried_limit, judge_case, selfcheck_case
from furnace_model.identification.fit import fit
from furnace_model.identification.plausible import (
    AMBIENT_MARGIN_C,
    sensor_bias_bounds,
    start_band,
    zone_bias_bounds,
)
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.furnacefile import load_furnace, parse_furnace
from furnace_model.simulation.structure import ModelStructure

ROOT = Path(__file__).resolve().parent.parent
SIX = load_furnace(ROOT / "config/furnaces/six-zone.yaml")


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "furnace_model.cli", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


def test_the_default_bias_is_the_class_2_tolerance_at_the_hottest_reading():
    tc = np.array([[20.0, 20.0, 20.0, 20.0, 20.0, 20.0],
                   [1300.0, 800.0, 20.0, np.nan, 400.0, 330.0]])
    b = sensor_bias_bounds(PAPER, tc)
    assert b == pytest.approx([9.75, 6.0, 2.5, 2.5, 3.0, 2.5])
    assert zone_bias_bounds(PAPER, tc) == pytest.approx([7.875, 2.5, 2.75])


def test_a_description_sets_its_own_bias_per_furnace_zone_or_thermocouple():
    text = """
max_bias_c: 5
zones:
  - {name: a, burners: 2, thermocouples: 2, max_bias_c: 1}
  - {name: b, burners: 2, thermocouples: 2, max_bias_c: [1, 3]}
  - {name: c, burners: 2, thermocouples: 1}
"""
    f = parse_furnace(text)
    assert f.max_bias_c == (1.0, 1.0, 1.0, 3.0, 5.0)
    assert sensor_bias_bounds(f, np.full((3, 5), 1300.0)) == pytest.approx([1, 1, 1, 3, 5])
    assert zone_bias_bounds(f, np.full((3, 5), 1300.0)) == pytest.approx([1, 2, 5])
    assert f.describe()["max_bias_c"] == [1.0, 1.0, 1.0, 3.0, 5.0]
    assert "max_bias_c" not in PAPER.describe()  # logs of the paper's furnace unchanged


@pytest.mark.parametrize("zone, where", [
    ("max_bias_c: [1, 2, 3]", "zones[0].max_bias_c"),
    ("max_bias_c: -1", "zones[0].max_bias_c"),
    ("max_bias_c: hot", "zones[0].max_bias_c"),
])
def test_a_bad_bias_names_its_key(zone, where):
    with pytest.raises(ConfigError, match=re.escape(where)):
        parse_furnace(f"zones:\n  - {{name: a, burners: 2, thermocouples: 2, {zone}}}\n")


def test_a_start_stays_near_the_first_reading_and_above_ambient():
    y = np.column_stack([np.full(50, 25.0), np.r_[np.nan, np.full(49, 300.0)]])
    lo, hi = start_band(y, np.full(50, 20.0), np.array([2.5, 2.5]))
    assert lo[0] == pytest.approx(22.5) and hi[0] == pytest.approx(27.5)
    assert lo[1] == 20.0 - AMBIENT_MARGIN_C and hi[1] == np.inf  # no first reading: ambient


@pytest.fixture(scope="module")
def nonlinear():
    """A heat-up whose burners lose heat per burner as more fire: the model lacks it."""
    return selfcheck_case("burner_nonlinearity", 0, furnace=PAPER)


def test_offsets_cannot_absorb_a_missing_effect_and_are_flagged(nonlinear):
    exp = nonlinear.fit[0]
    res = fit([exp], ModelStructure(furnace=PAPER), zone_offsets=True, profile=False)
    bounds = zone_bias_bounds(PAPER, exp.tc)
    off = res.offsets(0)
    assert np.all(np.abs(off) <= bounds + 1e-9)
    assert np.all(res.x0[0] >= exp.t_air.min() - AMBIENT_MARGIN_C - 1e-9)
    flagged = {(f.kind, f.zone) for f in res.flags}
    assert ("offset", "soak") in flagged, res.flags
    assert any("is not a thermocouple bias" in w for w in res.warnings)
    # the model's error shows: the soaking zone misses by more than its noise floor
    assert res.per_zone["soak"]["rmse_c"] > 2 * 1.5 / np.sqrt(2)
    doc = res.to_json(["x"])
    assert {(f["kind"], f["zone"]) for f in doc["flags"]} == flagged
    assert doc["zone_offsets_ci95_c"][0]["soak"] is None  # on the bound: no interval
    assert doc["bounds_c"][0]["offset"]["soak"] == pytest.approx([-bounds[0], bounds[0]])


def test_a_model_true_to_the_plant_is_not_flagged_and_its_offsets_hold_the_bias():
    case = selfcheck_case("none", 0, furnace=PAPER)
    res = fit(case.fit, ModelStructure(furnace=PAPER), zone_offsets=True, profile=False)
    assert res.flags == []
    for zone, ci in res.zone_offsets_ci95_c[0].items():
        assert ci is not None and ci[0] < res.zone_offsets_c[0][zone] < ci[1]
        assert ci[1] - ci[0] < 2.0  # a bias of sd 0.5 °C is resolved, not merely bounded


@pytest.mark.parametrize("furnace, scenario", [
    ("config/furnaces/paper.yaml", "config/scenarios/paper_exp1.yaml"),
    ("config/furnaces/six-zone.yaml", "config/scenarios/six_zone_heatup.yaml"),
])
def test_validate_on_the_fitted_record_reproduces_the_fit(tmp_path, furnace, scenario):
    data = tmp_path / "run.csv"
    r = cli("simulate", "--scenario", scenario, "--out", str(data), "--seed", "3")
    assert r.returncode == 0, r.stderr
    r = cli("fit", str(data), "--furnace", furnace, "--json", str(tmp_path / "fit.json"))
    assert r.returncode == 0, r.stderr
    r = cli("validate", "--params", str(tmp_path / "fit.json"), str(data), "--furnace", furnace,
            "--json", str(tmp_path / "val.json"))
    assert r.returncode == 0, r.stderr
    fitted = json.loads((tmp_path / "fit.json").read_text())
    scored = json.loads((tmp_path / "val.json").read_text())
    for zone, m in fitted["per_zone"].items():
        assert scored["per_zone"][zone]["rmse_c"] == pytest.approx(m["rmse_c"], rel=1e-6)
    off = scored["zone_offsets_c"]["run"]
    for zone, v in fitted["zone_offsets_c"][0].items():
        assert off[zone] == pytest.approx(v, abs=1e-4)
        assert abs(scored["offset_corrections_c"]["run"][zone]) < 1e-4
    assert "Zone offsets carried by the fit" in r.stdout


def test_validate_applies_the_carried_offsets_of_a_biased_record(tmp_path):
    """A record whose soaking thermocouples read 4 °C high: the fit's offset takes the bias,
    validate applies it and reproduces the fit; dropped, the bias shows in the score."""
    data = tmp_path / "run.csv"
    assert cli("simulate", "--scenario", "config/scenarios/paper_exp1.yaml", "--out",
               str(data), "--seed", "4").returncode == 0
    table = pd.read_csv(data)
    table[["tc_soak_1", "tc_soak_2"]] += 4.0  # both soaking thermocouples read 4 °C high
    table.to_csv(data, index=False)
    assert cli("fit", str(data), "--json", str(tmp_path / "fit.json")).returncode == 0
    fitted = json.loads((tmp_path / "fit.json").read_text())
    assert fitted["offsets_c"]["soak"] == pytest.approx(4.0, abs=0.8)
    assert fitted["flags"] == []
    kept = cli("validate", "--params", str(tmp_path / "fit.json"), str(data),
               "--json", str(tmp_path / "kept.json"))
    dropped = cli("validate", "--params", str(tmp_path / "fit.json"), str(data),
                  "--no-zone-offsets", "--json", str(tmp_path / "dropped.json"))
    assert kept.returncode == 0 and dropped.returncode == 0, kept.stderr
    k = json.loads((tmp_path / "kept.json").read_text())["per_zone"]["soak"]["rmse_c"]
    d = json.loads((tmp_path / "dropped.json").read_text())["per_zone"]["soak"]["rmse_c"]
    assert k == pytest.approx(fitted["per_zone"]["soak"]["rmse_c"], rel=1e-6)
    assert d > k + 1.0


def test_the_selfcheck_refuses_a_no_gap_that_the_carried_offsets_contradict():
    """A no_gap on a draw with an effect is a failure, not an absorbed draw, when the
    baseline's held-out error with the offsets it carries is above the gap limit and what a
    change of the thermocouples' bias between the records can add."""
    from furnace_model.diagnosis import diagnose

    case = selfcheck_case("zone_losses", 0, furnace=PAPER)
    d = diagnose(case.fit, case.holdout, effects=())
    assert d.verdict.status == "no_gap"
    held = d.baseline.rmse_holdout_carried_c
    assert held is not None and set(held) == set(PAPER.zones)
    assert judge_case(case, d)[1]  # absorbed: the error is within the limit either way
    d.baseline.rmse_holdout_carried_c = {z: 1.01 * v
                                         for z, v in carried_limit(case, d).items()}
    correct, absorbed, reason = judge_case(case, d)
    assert not correct and not absorbed and "offsets the fit carries" in reason
