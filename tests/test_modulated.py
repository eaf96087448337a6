"""Furnaces fired by modulated and pulse-fired burners, with a measured disturbance: the
description, the tabular contract, the plant simulator and the fit, against the simulator's
truth (config/furnaces/modulated.yaml, config/scenarios/modulated_production.yaml)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from furnace_model.errors import ConfigError, DataError, DataWarning
from furnace_model.experiment import read_table
from furnace_model.identification.fit import fit
from furnace_model.simulation.furnacefile import load_furnace, parse_furnace
from furnace_model.simulation.plant import Plant, row_means
from furnace_model.simulation.scenario import SensorSpec, load_scenario
from furnace_model.simulation.structure import Inputs

FURNACE = "config/furnaces/modulated.yaml"
SCENARIO = "config/scenarios/modulated_production.yaml"


@pytest.fixture(scope="module")
def scenario():
    return load_scenario(SCENARIO)


@pytest.fixture(scope="module")
def record(scenario):
    return Plant.from_scenario(scenario, seed=3).run_scenario(scenario).to_experiment("prod")


def test_description_says_how_each_zone_is_fired():
    f = load_furnace(FURNACE)
    assert [h.kind for h in f.heat_inputs] == ["rate", "rate", "pulse"]
    assert f.burner_columns == ("heat_soak", "heat_heat", "burners_preheat")
    assert f.disturbance_columns == ("throughput",)
    assert f.n_inputs == 5
    assert f.model_label == "network-modulated"
    # the description round-trips through what a log's metadata record holds of it
    from furnace_model.config import Node
    from furnace_model.simulation.furnacefile import furnace_from_node
    assert furnace_from_node(Node(f.describe(), "x"), "x") == f


def test_paper_furnace_is_unchanged():
    from furnace_model.simulation.furnace import PAPER
    assert PAPER.burner_columns == ("burners_soak", "burners_heat", "burners_preheat")
    assert PAPER.n_inputs == 4 and PAPER.model_label == "paper-3zone"
    assert all("heat" not in z for z in PAPER.describe()["zones"])


@pytest.mark.parametrize("text, words", [
    ("zones: [{name: a, burners: 2, heat: {kind: rate, max: 100}}]", "unit"),
    ("zones: [{name: a, burners: 2, heat: {kind: pulse, unit: '%'}}]", "unit and max"),
    ("zones: [{name: a, burners: 2, heat: {kind: gas}}]", "gas"),
    ("zones: [{name: a, burners: 2, heat: {kind: rate, unit: '%', max: 100}}, "
     "{name: b, burners: 2}]", "different units"),
    ("zones: [{name: a, burners: 2}]\ndisturbances: [{name: t, unit: x, zones: [b]}]",
     "unknown zone 'b'"),
    ("zones: [{name: a, burners: 2}]\ndisturbances: [{name: t, unit: x, zones: [a], "
     "column: burners_x}]", "taken"),
    ("zones: [{name: a, burners: 2}]\ndisturbances: [{name: t, unit: x, zones: [a], "
     "range: [5, 1]}]", "low < high"),
])
def test_bad_descriptions_are_named(text, words):
    with pytest.raises(ConfigError, match=words):
        parse_furnace(text)


def test_table_round_trip_and_ranges(record, tmp_path):
    path = tmp_path / "prod.csv"
    frame = record.to_frame()
    assert {"heat_soak", "heat_heat", "burners_preheat", "throughput"} <= set(frame.columns)
    assert (frame["burners_preheat"] % 1 != 0).any()  # a pulse-fired zone's mean count
    frame.to_csv(path, index=False)
    back = read_table(path, furnace=record.furnace)
    assert np.allclose(back.burners, record.burners, atol=1e-6)
    assert np.allclose(back.disturbances, record.disturbances, atol=1e-6)

    over = frame.copy()
    over.loc[7, "heat_heat"] = 650.0
    over.to_csv(path, index=False)
    with pytest.raises(DataError, match=r"heat_heat.*line 9.*at most 600 Nm3/h, got 650"):
        read_table(path, furnace=record.furnace)
    out = frame.copy()
    out.loc[4, "throughput"] = 300.0
    out.to_csv(path, index=False)
    with pytest.raises(DataError, match=r"throughput.*line 6.*outside the declared range"):
        read_table(path, furnace=record.furnace)
    gone = frame.drop(columns=["throughput"])
    gone.to_csv(path, index=False)
    with pytest.raises(DataError, match="missing required column.*throughput"):
        read_table(path, furnace=record.furnace)


def test_whole_burner_zone_still_refuses_fractions(tmp_path):
    s = load_scenario("config/scenarios/paper_exp1.yaml")
    frame = Plant.from_scenario(s, seed=1).run_scenario(s).to_frame()
    frame["burners_soak"] = frame["burners_soak"].astype(float)
    frame.loc[3, "burners_soak"] = 2.5
    frame.to_csv(tmp_path / "f.csv", index=False)
    with pytest.raises(DataError, match="whole number.*heat: {kind: rate}"):
        read_table(tmp_path / "f.csv", furnace=s.furnace)


def test_missing_thermocouple_column_is_warned(tmp_path):
    s = load_scenario("config/scenarios/paper_exp1.yaml")
    frame = Plant.from_scenario(s, seed=1).run_scenario(s).to_frame()
    frame.drop(columns=["tc_heat_2"]).to_csv(tmp_path / "f.csv", index=False)
    with pytest.warns(DataWarning, match="tc_heat_2"):
        exp = read_table(tmp_path / "f.csv", furnace=s.furnace)
    assert np.isnan(exp.tc[:, 3]).all() and np.isfinite(exp.zone_temp).all()


def test_row_means_are_time_means():
    t_in = np.array([0.0, 0.25, 1.0, 1.5])
    levels = np.array([[4.0], [0.0], [2.0], [6.0]])
    got = row_means(t_in, levels, np.array([0.0, 1.0, 2.0]))[:, 0]
    assert np.allclose(got, [1.0, 4.0, 6.0])


def test_pulse_firing_holds_its_duty(scenario):
    plant_inputs = scenario.plant_inputs()
    j = 2  # the pulse-fired zone
    assert set(np.unique(plant_inputs.burners[:, j])) <= set(range(9))
    t = scenario.sample_times()
    means = row_means(plant_inputs.t, plant_inputs.burners[:, [j]], t)[:, 0]
    assert np.allclose(means[:-1], scenario.inputs().burners[
        np.searchsorted(scenario.steps_t, t[:-1], side="right") - 1, j], atol=1e-9)


def test_disturbance_enters_the_zones_it_names(scenario):
    structure = scenario.structure()
    values = scenario.values()
    inputs = scenario.inputs()
    t = scenario.sample_times()[::30]
    x0 = scenario.initial_c
    base = structure.simulate(values, inputs, t, x0).zones[0]
    more = Inputs(inputs.t, inputs.burners, inputs.t_air, inputs.disturbances + 50.0)
    moved = structure.simulate(values, more, t, x0).zones[0] - base
    assert np.all(moved[-1, 1:] < -5.0)  # throughput cools the heating and preheating zones
    assert abs(moved[-1, 0]) < abs(moved[-1, 1])  # the soaking zone only through its link


def test_fit_recovers_the_truth_disturbance_gains_included(scenario):
    """Two records of different seeds, thermocouple biases taken up by zone offsets: the 95%
    intervals hold the truth, the disturbance gains with their sign.

    The preheating zone settles within a minute, so its four rates (exchange, loss, heat per
    burner, throughput) are fixed mostly as ratios and move together (r near 1): one chance
    excursion of that direction takes all four out at once, and counts as one miss."""
    sc = load_scenario(SCENARIO)
    sc.sensors = SensorSpec(noise_sd_c=1.5, bias_sd_c=0.5)
    together = {"k_preheat_heat", "loss_preheat", "gain_preheat", "gain_throughput_preheat"}
    misses = 0
    for seed in (1, 2):
        rec = Plant.from_scenario(sc, seed=seed).run_scenario(sc).to_experiment(f"s{seed}")
        r = fit([rec], seed=seed, zone_offsets=True)
        out = {n for n, truth in sc.params.items()
               if not r.ci95[n][0] <= truth <= r.ci95[n][1]}
        misses += len(out - together) + bool(out & together)
        for name in ("gain_throughput_heat", "gain_throughput_preheat"):
            assert r.ci95[name][1] < 0, name
        ratio = r.params["k_preheat_heat"] / r.params["loss_preheat"]
        assert ratio == pytest.approx(0.8 / 0.7, rel=0.05)
    assert misses <= 1  # about a dozen independent intervals at 95%: two misses are not chance


def test_frame_of_modulated_record_is_csv_readable(record, tmp_path):
    record.to_frame().to_csv(tmp_path / "x.csv", index=False)
    frame = pd.read_csv(tmp_path / "x.csv")
    assert frame["heat_soak"].dtype == float


def test_selfcheck_cases_fire_the_furnace_as_it_is_fired():
    """The selfcheck's drawn heat-ups of the modulated furnace: rates in their units within
    their maxima, a pulse-fired zone at fractions of burners, the throughput in its range,
    and a truth that holds a disturbance gain for each zone it enters."""
    from furnace_model.diagnosis.cases import draw_case, network_truth
    f = load_furnace(FURNACE)
    truth = network_truth(f)
    assert truth["gain_throughput_heat"] < 0 and truth["gain_throughput_preheat"] < 0
    case = draw_case(None, np.random.default_rng(4), furnace=f)
    for rec in case.fit + case.holdout:
        assert np.all(rec.burners <= [h.max for h in f.heat_inputs])
        assert rec.burners[:, 0].max() > 10.0  # percent, not burners
        assert np.all((rec.disturbances >= 0) & (rec.disturbances <= 250))
        assert np.ptp(rec.disturbances) > 10.0


def test_burner_nonlinearity_reads_rates_as_the_burners_they_stand_for():
    """Half the soaking zone's rate stands for 5 of its 10 burners, 300 Nm3/h for 4 of the
    heating zone's 8, and the pulse-fired zone counts its burners: 5 + 4 + 2 = 11 firing."""
    from furnace_model.effects import EFFECTS
    f = load_furnace(FURNACE)
    effect = EFFECTS["burner_nonlinearity"](form="linear", furnace=f)
    u = np.array([[[50.0, 300.0, 2.0, 25.0, 80.0]]])
    out = effect.transform_levels({"k_nl": np.array([-0.01])}, u)
    factor = 1.0 - 0.01 * 11
    assert np.allclose(out[0, 0, :3], u[0, 0, :3] * factor)
    assert np.allclose(out[0, 0, 3:], u[0, 0, 3:])  # ambient and throughput untouched


def test_commands_take_a_shipped_description_by_name(tmp_path, capsys):
    from furnace_model.cli import main
    out = tmp_path / "m.csv"
    assert main(["simulate", "--scenario", SCENARIO, "--furnace", "modulated",
                 "--out", str(out)]) == 0
    assert main(["simulate", "--scenario", SCENARIO, "--furnace", "nosuch",
                 "--out", str(out)]) == 2
    assert "nosuch" in capsys.readouterr().err


def test_extra_numeric_columns_are_signals_but_row_numbers_are_not(tmp_path):
    s = load_scenario("config/scenarios/paper_exp1.yaml")
    frame = Plant.from_scenario(s, seed=1).run_scenario(s).to_frame()
    frame["o2_pct"] = np.linspace(2.0, 5.0, len(frame))
    frame["note"] = "ok"
    frame["row"] = np.arange(len(frame))
    frame.to_csv(tmp_path / "f.csv", index=True)  # pandas' own index: 'Unnamed: 0'
    exp = read_table(tmp_path / "f.csv", furnace=s.furnace)
    assert list(exp.signals) == ["o2_pct"]
    assert np.allclose(exp.signals["o2_pct"], frame["o2_pct"], atol=1e-3)
