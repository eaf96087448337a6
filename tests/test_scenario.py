"""Scenario files: the paper's experiments as the text gives them, and checked keys."""

from __future__ import annotations

import numpy as np
import pytest

from furnace_model.errors import ConfigError
from furnace_model.simulation.parameters import PAPER_TABLE_V, ThermalRC
from furnace_model.simulation.scenario import load_scenario


def test_paper_experiment_1(scenarios):
    s = load_scenario(scenarios / "paper_exp1.yaml")
    assert s.steps_t.tolist() == [0, 510, 2670, 3170]
    assert s.steps_burners[:, 0].tolist() == [2, 4, 6, 10]
    assert np.all(s.steps_burners[:, 1:] == 0)
    assert s.duration_min == 3310
    assert s.params == pytest.approx(PAPER_TABLE_V)


def test_paper_experiment_2_fills_soaking_then_heating(scenarios):
    s = load_scenario(scenarios / "paper_exp2.yaml")
    assert s.steps_t.tolist() == [0, 1900, 3100, 3300, 3400, 3500]
    assert s.steps_burners.sum(axis=1).tolist() == [2, 5, 6, 8, 10, 18]
    assert s.steps_burners[-1].tolist() == [10, 8, 0]
    assert s.duration_min == 3800


def test_rc_view_round_trips():
    rc = ThermalRC.from_params(PAPER_TABLE_V)
    assert rc.to_params() == pytest.approx(PAPER_TABLE_V)
    assert pytest.approx(1 / PAPER_TABLE_V["f"]) == rc.C1


@pytest.mark.parametrize("text, match", [
    ("duration_min: 10\nburners: {steps: [{at_min: 0, total: 2}]}\nefects: {}",
     r"efects: unknown key"),
    ("duration_min: ten\nburners: {steps: [{at_min: 0, total: 2}]}",
     r"duration_min: expected a number, got text 'ten'"),
    ("duration_min: 10\nburners: {steps: [{at_min: 0, total: 27}]}",
     r"burners.steps\[0\].total: must be at most 26"),
    ("duration_min: 10\nburners: {steps: [{at_min: 0, total: 2}, {at_min: 0, total: 3}]}",
     r"burners.steps\[1\].at_min: steps must be in time order"),
    ("duration_min: 10\nburners: {steps: [{at_min: 0, total: 2}]}\neffects: {warp_drive: {}}",
     r"effects.warp_drive: unknown effect"),
    ("duration_min: 10\nburners: {steps: [{at_min: 0, total: 2}]}\n"
     "effects: {sensor_lag: {tau: 3}}", r"effects.sensor_lag.tau: unknown key"),
    ("duration_min: 10\nburners: {steps: [{at_min: 0, total: 2}]}\n"
     "effects: {sensor_drift: {sensor: heat_3}}", r"effects.sensor_drift.sensor: must be one of"),
    ("duration_min: 1.0e+999\nburners: {steps: [{at_min: 0, total: 2}]}", r"finite number"),
    ("!!python/object/apply:os.system ['echo hi']", r"not valid YAML"),
    ("duration_min: [1,\n", r"not valid YAML: line"),
    ("duration_min: 10\n", r"burners: required key is missing"),
])
def test_bad_scenarios_name_the_key(tmp_path, text, match):
    path = tmp_path / "s.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=match):
        load_scenario(path)


def test_effects_parse_with_options_and_switches(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("duration_min: 100\nburners: {steps: [{at_min: 0, soak: 2, heat: 1}]}\n"
                    "effects:\n  zone_losses: {g_heat: 0.004}\n"
                    "  sensor_lag: {enabled: false, tau_lag: 3}\n"
                    "  sensor_drift: {sensor: soak_2, drift_rate: 0.02}\n")
    s = load_scenario(path)
    assert [e.name for e in s.effects] == ["zone_losses", "sensor_drift"]
    assert s.effect_values == {"g_heat": 0.004, "drift_rate": 0.02, "t_drift": 0.0}
    assert s.effects[1].options["sensor"] == "soak_2"
    assert s.steps_burners.tolist() == [[2, 1, 0]]
