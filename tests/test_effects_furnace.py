"""Effects on any furnace: each effect made for a furnace description reads its zones,
thermocouples and input channels; scenarios switch them on by the furnace's names; an
effect that cannot apply is refused by name with the reason; the diagnosis names an effect
on the six-zone furnace."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from furnace_model.effects import EFFECTS
from furnace_model.errors import ConfigError, FurnaceError
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.furnacefile import load_furnace
from furnace_model.simulation.network import parameters
from furnace_model.simulation.scenario import load_scenario
from furnace_model.simulation.structure import Inputs, ModelStructure

ROOT = Path(__file__).resolve().parent.parent
SIX = load_furnace(ROOT / "config/furnaces/six-zone.yaml")
FIRST = dataclasses.replace(SIX, burner_heat="first_zone")


def _heatup(furnace):
    nz = furnace.n_zones
    rng = np.random.default_rng(3)
    counts = rng.integers(0, 4, (6, nz)).astype(float)
    return Inputs(np.arange(6) * 150.0, counts, np.full(6, 30.0)), np.arange(0.0, 901.0, 5.0)


def _values(structure):
    """The selfcheck's network for the furnace (a heat-up to some hundreds of °C), the
    effects at their defaults."""
    from furnace_model.diagnosis.cases import network_truth

    return {**{p.name: p.default for p in structure.params},
            **network_truth(structure.furnace)}


@pytest.mark.parametrize("name", [n for n in EFFECTS if n != "zone_burners"])
def test_every_effect_runs_on_the_six_zone_furnace_and_changes_it(name):
    base = ModelStructure(furnace=SIX)
    effect = EFFECTS[name](furnace=SIX)
    ext = ModelStructure([effect], furnace=SIX)
    inputs, t = _heatup(SIX)
    x0 = np.full(6, 30.0)
    y0 = base.simulate(_values(base), inputs, t, x0).sensors[0]
    values = _values(ext)
    values.update({k: v for k, v in {"t_drift": 100.0, "t_fuel": 400.0}.items() if k in values})
    y1 = ext.simulate(values, inputs, t, x0).sensors[0]
    assert y1.shape == (t.size, len(SIX.sensors)) and np.all(np.isfinite(y1))
    assert np.max(np.abs(y1 - y0)) > 0.5, name


def test_zone_burners_on_the_first_zone_reading_is_the_own_zone_network():
    """The six-zone description read the paper's way, plus own-zone burners, is the
    description itself: the effect's gains are the own-zone network's."""
    own = ModelStructure(furnace=SIX)
    truth = {**_values(own), **{f"gain_{z}": 0.3 + 0.1 * i for i, z in enumerate(SIX.zones)}}
    first = ModelStructure([EFFECTS["zone_burners"](furnace=FIRST)], furnace=FIRST)
    assert [p.name for p in first.effects[0].params] == [f"f_{z}" for z in SIX.zones[1:]]
    values = {**{k: v for k, v in truth.items() if k in first.names},
              **{f"f_{z}": truth[f"gain_{z}"] for z in SIX.zones[1:]}}
    inputs, t = _heatup(SIX)
    a = own.simulate(truth, inputs, t, np.full(6, 30.0)).zones[0]
    b = first.simulate(values, inputs, t, np.full(6, 30.0)).zones[0]
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9)


def test_zone_options_range_over_the_furnace():
    lag = EFFECTS["sensor_lag"](furnace=SIX, zones=("soak_bottom",))
    assert lag.state_zones == (1,)
    wall = EFFECTS["wall_storage"](furnace=SIX, zones=("heat_top", "preheat_bottom"))
    assert wall.state_zones == (2, 5)
    losses = EFFECTS["zone_losses"](furnace=SIX)
    assert losses.options["zones"] == ("soak_top", "soak_bottom", "heat_top", "heat_bottom")
    assert [p.name for p in losses.params] == ["g_soak_top", "g_soak_bottom", "g_heat_top",
                                              "g_heat_bottom"]
    drift = EFFECTS["sensor_drift"](furnace=SIX, sensor="heat_top_3")
    off = drift.sensor_offsets({"drift_rate": np.array([0.1]), "t_drift": np.array([10.0])},
                               np.array([0.0, 20.0]))
    assert off.shape == (1, 2, 11) and off[0, 1, SIX.sensors.index("heat_top_3")] == 1.0
    assert np.count_nonzero(off) == 1
    with pytest.raises(ValueError, match="applies to soak_top and soak_bottom and heat_top and "
                                         "heat_bottom, not"):
        EFFECTS["zone_losses"](furnace=SIX, zones=("preheat_top",))
    with pytest.raises(ValueError, match="zone_burners does not apply to furnace 'six-zone': "
                                         ".*own_zone"):
        EFFECTS["zone_burners"](furnace=SIX)
    # the paper's furnace: options, parameters and defaults as they always were
    assert EFFECTS["sensor_lag"](furnace=PAPER).options == {"order": 1}
    assert EFFECTS["zone_losses"](furnace=PAPER).options == {"zones": ("soak", "heat")}
    assert EFFECTS["sensor_drift"](furnace=PAPER).options == {"sensor": "heat_2"}


def test_on_a_network_the_further_laws_place_an_effect_in_one_place_at_a_time():
    """A zone's wall, loss or lag, or a lone thermocouple's drift: each place alone is a law
    of its own, fitted whatever the effect everywhere at once does; the paper's furnace keeps
    its laws."""
    def places(name, furnace):
        tried = EFFECTS[name].tried
        return tried.laws_always(furnace), [next(iter(o.values()))
                                            for o in tried.laws_for(furnace)]

    every = [(z,) for z in SIX.zones]
    assert places("wall_storage", SIX) == (True, every)
    assert places("sensor_lag", SIX) == (True, every)
    assert places("zone_losses", SIX) == (True, [(z,) for z in SIX.zones[:4]])
    assert places("sensor_drift", SIX) == (True, ["soak_bottom_1", "preheat_bottom_1"])
    assert places("dead_time", SIX) == (False, [])
    assert places("wall_storage", PAPER) == (False, [(z,) for z in PAPER.zones])
    for name in ("sensor_lag", "zone_losses", "sensor_drift"):
        assert places(name, PAPER) == (False, [])
    assert EFFECTS["wall_storage"](furnace=PAPER).options["zones"] == PAPER.zones


SCENARIO = """
name: six_effects
furnace: {furnace}
duration_min: 600
t_air_c: 30
burners:
  steps:
    - {{at_min: 0, soak_top: 3, heat_top: 2, preheat_bottom: 1}}
    - {{at_min: 300, soak_top: 5, soak_bottom: 2, heat_bottom: 3}}
effects:
{effects}
"""


def _scenario(tmp_path, effects: str, furnace: str = "six-zone"):
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO.format(furnace=furnace, effects=effects))
    return path


def test_a_six_zone_scenario_switches_effects_on_by_the_furnaces_names(tmp_path):
    sc = load_scenario(_scenario(tmp_path, """\
  wall_storage: {zones: [heat_top], k_gw: 0.1, k_wg: 0.005}
  zone_losses: {g_heat_bottom: 0.008}
  sensor_lag: {zones: [preheat_bottom], tau_lag: 8}
  sensor_drift: {sensor: soak_bottom_1, drift_rate: 0.05, t_drift: 200}
  dead_time: {theta_dead: 10}"""))
    structure = sc.structure()
    assert structure.furnace == SIX and structure.n_states == 6 + 1 + 1
    assert sc.effect_values["g_heat_bottom"] == 0.008
    y = structure.simulate(sc.values(), sc.inputs(), sc.sample_times(), sc.initial_c)
    assert np.all(np.isfinite(y.sensors))
    k = SIX.sensors.index("soak_bottom_1")
    assert y.sensor_offsets[0, -1, k] == pytest.approx(0.05 * 400)
    shipped = load_scenario(ROOT / "config/scenarios/six_zone_effects.yaml")
    assert [e.name for e in shipped.effects] == ["wall_storage", "sensor_drift"]
    assert shipped.structure().n_states == 7


@pytest.mark.parametrize(("effects", "path", "words"), [
    ("  zone_burners: {}", "effects.zone_burners", "own_zone"),
    ("  sensor_drift: {sensor: heat_2}", "effects.sensor_drift.sensor", "soak_top_1"),
    ("  zone_losses: {g_preheat_top: 0.01}", "effects.zone_losses", "not ['preheat_top']"),
    ("  wall_storage: {zones: [soak]}", "effects.wall_storage.zones[0]", "heat_top"),
])
def test_an_effect_that_cannot_apply_is_refused_on_its_key(tmp_path, effects, path, words):
    with pytest.raises(ConfigError) as err:
        load_scenario(_scenario(tmp_path, effects))
    assert err.value.path == path and words in str(err.value), str(err.value)


def test_a_furnace_with_every_zone_losing_heat_refuses_zone_losses():
    every = dataclasses.replace(SIX, ambient=tuple(range(6)))
    with pytest.raises(ValueError, match="every zone of it already loses heat"):
        EFFECTS["zone_losses"](furnace=every)
    assert ModelStructure(furnace=every).names == [p.name for p in parameters(every)]


def test_diagnose_refuses_an_effect_that_cannot_apply_by_name():
    from furnace_model.diagnosis import diagnose
    from furnace_model.diagnosis.cases import case_rng, draw_case

    case = draw_case(None, case_rng(0, "none", 0), furnace=SIX)
    with pytest.raises(FurnaceError, match="zone_burners does not apply to furnace 'six-zone'"):
        diagnose(case.fit, case.holdout, effects=("zone_burners",))


def test_the_equations_least_squares_find_a_zone_affine_effect_with_the_network():
    """A loss from one zone of six: the integrated equations put the loss in that zone,
    with the network's parameters, where the fit of a candidate from scratch starts; an
    effect that adds states keeps its defaults."""
    from furnace_model.diagnosis.cases import case_rng, draw_case, network_truth
    from furnace_model.diagnosis.fitting import structure_of
    from furnace_model.identification.equationerror import equation_error

    case = draw_case("zone_losses", case_rng(0, "zone_losses", 0), furnace=SIX)
    g = case.truth["zone_losses"]["g_heat_bottom"]
    start = equation_error(structure_of(("zone_losses",), {}, SIX), case.fit)
    assert start["g_heat_bottom"] == pytest.approx(g, rel=0.05)
    assert max(start[f"g_{z}"] for z in ("soak_top", "soak_bottom", "heat_top")) < 0.2 * g
    truth = network_truth(SIX)
    assert all(start[k] == pytest.approx(v, rel=0.1) for k, v in truth.items()
               if k.startswith("gain_"))
    wall = structure_of(("wall_storage",), {}, SIX)
    assert {k: v for k, v in equation_error(wall, case.fit).items()
            if k not in truth} == {}


def test_a_six_zone_diagnosis_names_a_drifting_thermocouple_of_three(tmp_path):
    """Known truth: heat_top_3, one of the three thermocouples of its zone, drifts
    -0.0126 °C/min from minute 1562 of each heat-up; its pairs show it, the diagnosis names
    it, the report and the JSON name the furnace's zones."""
    from furnace_model.diagnosis import diagnose
    from furnace_model.diagnosis.cases import case_rng, draw_case
    from furnace_model.diagnosis.selfcheck import judge_case
    from furnace_model.report import write_report

    case = draw_case("sensor_drift", case_rng(0, "sensor_drift", 0), furnace=SIX)
    assert case.truth["sensor_drift"]["sensor"] == "heat_top_3"
    d = diagnose(case.fit, case.holdout, effects=("sensor_drift",))
    assert judge_case(case, d)[0], d.verdict.sentence
    assert any(w.sensor == "heat_top_3" and w.kind == "sensor" for w in d.where)
    best = d.best()
    assert best.params["drift_rate"] == pytest.approx(case.truth["sensor_drift"]["drift_rate"],
                                                      rel=0.1)
    doc = d.to_json()
    assert list(doc["baseline"]["rmse_holdout_c"]) == list(SIX.zones)
    assert set(doc["noise_floors"][0]["zones"]) == set(SIX.zones)
    write_report(d, tmp_path / "r.html")
    html = (tmp_path / "r.html").read_text()
    assert "heat top" in html and "heat_top_3" in html


def test_a_lone_thermocouples_drift_is_started_across_the_record():
    """Known truth (the six-zone selfcheck's drift row, draw 9): soak_bottom_1, alone in its
    zone, drifts +0.0094 °C/min from minute 1115. The baseline bends to absorb it; from the
    baseline the drift's fit found a side valley (onset at minute 2576, a tenth of the
    held-out gap closed). Started across the record, it finds the drift."""
    from furnace_model.diagnosis.fitting import Task, run_task
    from furnace_model.diagnosis.holdout import split
    from furnace_model.diagnosis.selfcheck import selfcheck_case

    case = selfcheck_case("sensor_drift", 9, furnace=SIX)
    truth = case.truth["sensor_drift"]
    assert truth["sensor"] == "soak_bottom_1"
    fit_data, hold, tail_of, _ = split(case.fit, case.holdout)
    box = EFFECTS["sensor_drift"].tried.search_bounds(fit_data)
    drift = EFFECTS["sensor_drift"](sensor="soak_bottom_1", furnace=SIX)
    onsets = [s["t_drift"] for s in drift.tried.starts(drift, {}, box)]
    assert len(onsets) == 8 and box["t_drift"][0] < min(onsets) < max(onsets) < box["t_drift"][1]
    base = run_task(Task((), {}, fit_data, hold, tail_of, None, 0))
    drift = run_task(Task(("sensor_drift",), {"sensor_drift": {"sensor": "soak_bottom_1"}},
                          fit_data, hold, tail_of, dict(base.params), 0,
                          bounds=box))
    assert drift.params["t_drift"] == pytest.approx(truth["t_drift"], abs=60)
    assert drift.params["drift_rate"] == pytest.approx(truth["drift_rate"], rel=0.1)
    assert drift.rmse_holdout_c["soak_bottom"] < 0.2 * base.rmse_holdout_c["soak_bottom"]


def test_a_large_drift_of_one_of_a_pair_is_found_whichever_its_partner_blamed():
    """Known truth (the six-zone selfcheck's drift row, draw 7): soak_top_1 drifts
    -0.0224 °C/min from minute 663, 57 °C by the end. Their difference cannot say which of
    the pair drifts; the trial may start the partner, soak_top_2, with a rising drift. With
    the drift taken off the readings for the network's start, and either sign tried, the
    fit finds the drift on the thermocouple that has it."""
    from furnace_model.diagnosis.fitting import Task, run_task
    from furnace_model.diagnosis.holdout import split
    from furnace_model.diagnosis.selfcheck import selfcheck_case

    case = selfcheck_case("sensor_drift", 7, furnace=SIX)
    truth = case.truth["sensor_drift"]
    assert truth["sensor"] == "soak_top_1"
    fit_data, hold, tail_of, _ = split(case.fit, case.holdout)
    base = run_task(Task((), {}, fit_data, hold, tail_of, None, 0))
    assert max(base.rmse_fit_c, key=base.rmse_fit_c.get) == "soak_top"  # the drift's zone
    assert base.rmse_fit_c["soak_top"] > 3.0
    rising = {"t_drift": 668.0, "drift_rate": 57.3 / (3216.0 - 668.0)}  # as the trial has it
    drift = run_task(Task(("sensor_drift",), {"sensor_drift": {"sensor": "soak_top_2"}},
                          fit_data, hold, tail_of, {**base.params, **rising}, 0,
                          bounds=EFFECTS["sensor_drift"].tried.search_bounds(fit_data)))
    assert drift.params["t_drift"] == pytest.approx(truth["t_drift"], abs=60)
    assert drift.params["drift_rate"] == pytest.approx(truth["drift_rate"], rel=0.1)
    assert max(drift.rmse_holdout_c.values()) < 2.0


def test_a_fuel_switch_on_a_network_is_fitted_from_the_rates_its_inputs_give():
    """Known truth (the six-zone selfcheck's fuel row, draw 0): each burner gives 28% less
    heat from minute 2322 of 3068. From a start of the spread across the record (minute
    2109) with the network the equations' least squares put on the inputs that start makes,
    the polish reaches the switch and the noise."""
    from furnace_model.diagnosis.fitting import _networks_for
    from furnace_model.diagnosis.selfcheck import selfcheck_case
    from furnace_model.identification.fit import fit
    from furnace_model.identification.noisefloor import record_floor

    case = selfcheck_case("fuel_change", 0, furnace=SIX)
    truth = case.truth["fuel_change"]
    effect = EFFECTS["fuel_change"](furnace=SIX)
    box = effect.tried.search_bounds(case.fit)
    starts = effect.tried.starts(effect, {}, box)
    assert len(starts) == 8 and box["t_fuel"][0] < starts[0]["t_fuel"] < starts[-1]["t_fuel"] \
        < box["t_fuel"][1]
    assert EFFECTS["fuel_change"].tried.starts(EFFECTS["fuel_change"](furnace=PAPER), {}, box) \
        == []  # eq. 11's search finds it from the one start
    structure = ModelStructure([effect], furnace=SIX)
    start = {**structure.defaults(), **starts[5]}
    assert start["t_fuel"] == pytest.approx(2109.25)
    fr = fit(case.fit, structure, init={**start, **_networks_for(structure, start, case.fit)[0]},
             zone_offsets=True, profile=False, bounds=box)
    assert fr.params["t_fuel"] == pytest.approx(truth["t_fuel"], abs=15)
    assert fr.params["fuel_ratio"] == pytest.approx(truth["fuel_ratio"], rel=0.03)
    floor = record_floor(case.fit[0]).floor_c
    for z in SIX.zones:
        assert fr.per_zone[z]["rmse_c"] < 1.1 * floor[z], (z, fr.per_zone[z], floor[z])


def _fuel_window():
    """6 hours of the paper's furnace in production as the daemon logged them in the online
    story test (soak_1 set aside), each burner 25% weaker from minute 210."""
    from furnace_model.records import load_experiment

    furnace = load_furnace(ROOT / "config/furnaces/paper-production.yaml")
    return load_experiment(ROOT / "tests/data/production_fuel_window.csv", furnace=furnace)


def test_a_fuel_switch_under_control_reaches_the_floor_from_a_further_network_start():
    """The integrated equations put the preheating zone, which settles within a sample, on
    its rates' lower bounds: from their rates, at every start of the switch, the polish finds
    the switch (minute 210, x0.75) with the zone collapsed, 2 °C off its floor, or misses
    the switch. Among the rates of every distinct start a fit from scratch has, the same
    starts of the switch reach the floor in every zone."""
    from furnace_model.diagnosis.fitting import Task, _networks_for, run_task
    from furnace_model.diagnosis.holdout import split
    from furnace_model.identification.fit import fit
    from furnace_model.identification.noisefloor import GAP_RATIO, GAP_Z, limits, record_floor

    record = _fuel_window()
    furnace = record.furnace
    fit_data, hold, tail_of, _ = split([record], None)  # as the diagnosis splits it
    base = run_task(Task((), {}, fit_data, hold, tail_of, None, 0))
    effect = EFFECTS["fuel_change"](furnace=furnace)
    box = effect.tried.search_bounds(fit_data)
    structure = ModelStructure([effect], furnace=furnace)
    limit = limits([record_floor(fit_data[0])], GAP_RATIO, GAP_Z)
    first, every = [], []
    for onset in effect.tried.starts(effect, {}, box):
        start = {**structure.defaults(), **base.params, **onset}
        for k, net in enumerate(_networks_for(structure, start, fit_data)):
            fr = fit(fit_data, structure, init={**start, **net}, zone_offsets=True,
                     profile=False, bounds=box)
            (first if k == 0 else every).append(fr)
    every += first
    assert len(every) > len(first)
    assert all(fr.per_zone["preheat"]["rmse_c"] > 2.0 * limit["preheat"] for fr in first)
    best = min(every, key=lambda fr: fr.sse)
    assert best.params["t_fuel"] == pytest.approx(210.0, abs=2.0)
    assert best.params["fuel_ratio"] == pytest.approx(0.75, abs=0.01)
    for z in furnace.zones:
        assert best.per_zone[z]["rmse_c"] < limit[z], (z, best.per_zone[z], limit[z])


def test_a_candidate_at_its_null_starts_where_the_baseline_ended():
    """A candidate is the baseline at its effect's null, so its fit cannot end above the
    baseline's if it starts where the baseline's ended. On the online story's drift window
    (6 hours of the paper's furnace in production, soak_1 drifting from about minute 80,
    no dead time), a dead time polished again from its null with the baseline's rates alone,
    its offsets and initial states started anew from the readings, ends in a valley several
    times the baseline's criterion; started where the baseline ended, it ends at or below."""
    from furnace_model.diagnosis.fitting import Task, _from_null, _start_of, run_task
    from furnace_model.diagnosis.holdout import split
    from furnace_model.identification.fit import fit
    from furnace_model.records import load_experiment

    furnace = load_furnace(ROOT / "config/furnaces/paper-production.yaml")
    record = load_experiment(ROOT / "tests/data/production_drift_window.csv", furnace=furnace)
    fit_data, hold, tail_of, _ = split([record], None)
    base = run_task(Task((), {}, fit_data, hold, tail_of, None, 0))
    task = Task(("dead_time",), {}, fit_data, hold, tail_of, dict(base.params), 0,
                baseline_sse=base.sse_fit, baseline_end=base.ended)
    structure = ModelStructure([EFFECTS["dead_time"](furnace=furnace)], furnace=furnace)
    init, bounds = _start_of(task, structure)
    anew = fit(fit_data, structure, init={**init, "theta_dead": 0.0}, zone_offsets=True,
               profile=False, bounds=bounds)
    assert anew.sse > 2.0 * base.sse_fit, (anew.sse, base.sse_fit)
    stuck = dataclasses.replace(anew, sse=np.inf)  # a fit that ended anywhere above
    again = _from_null(stuck, task, structure, init, bounds)
    assert again.sse <= base.sse_fit * (1 + 1e-9), (again.sse, base.sse_fit)
    assert run_task(task).sse_fit <= base.sse_fit * (1 + 1e-9)


def test_no_further_start_is_polished_once_a_fit_follows_its_records_to_the_noise(
        monkeypatch):
    """The switch's starts on the same window (its instants, and each on the equations'
    networks) are one fit, polished in the scouts' order until one follows every zone to
    its noise (within AT_FLOOR_Z standard errors of the floor): what the others could still
    take off is the noise's own scatter. The fit that stops them is the first at the floor,
    and the switch it found is the one of the record."""
    from furnace_model.diagnosis import fitting
    from furnace_model.diagnosis.holdout import split
    from furnace_model.identification.noisefloor import limits, record_floor

    record = _fuel_window()
    fit_data, hold, tail_of, _ = split([record], None)
    base = fitting.run_task(fitting.Task((), {}, fit_data, hold, tail_of, None, 0))
    at_floor = limits([record_floor(e) for e in fit_data], 1.0, fitting.AT_FLOOR_Z)
    ends, real = [], fitting.fit

    def counted(*args, **kwargs):
        fr = real(*args, **kwargs)
        ends.append(all(fr.per_zone[z]["rmse_c"] <= at_floor[z] for z in at_floor))
        return fr
    monkeypatch.setattr(fitting, "fit", counted)
    box = EFFECTS["fuel_change"].tried.search_bounds(fit_data)
    fuel = fitting.run_task(fitting.Task(("fuel_change",), {}, fit_data, hold, tail_of,
                                         dict(base.params), 0, bounds=box))
    structure = ModelStructure([EFFECTS["fuel_change"](furnace=record.furnace)],
                               furnace=record.furnace)
    starts = sum(map(len, fitting._starts(structure, dict(base.params), box)))
    assert ends[-1] and not any(ends[:-1]), ends
    assert len(ends) < starts, (len(ends), starts)  # stopped with starts left
    assert fuel.params["t_fuel"] == pytest.approx(210.0, abs=2.0)
    assert fuel.params["fuel_ratio"] == pytest.approx(0.75, abs=0.01)


@pytest.mark.slow  # every start of the switch polished: half a minute of one core
def test_a_switch_is_polished_from_every_start_where_no_scout_reaches_the_floor():
    """Ten steps do not rank where the starts end: on a drawn production window around a
    fuel switch (x0.71 at minute 210 of the window), the start lowest after its scout
    ends 1.3-1.8 °C off in every zone, three times the lowest end's criterion. No end comes
    within a standard error of the floor (1.1-1.2 °C), so every start is polished on and the
    lowest end kept: the switch of the record, within the gap limit in every zone."""
    from furnace_model.diagnosis import fitting
    from furnace_model.diagnosis.cases import draw_closed_loop_case
    from furnace_model.diagnosis.holdout import split
    from furnace_model.identification.noisefloor import GAP_RATIO, GAP_Z, limits, record_floor

    case = draw_closed_loop_case("fuel_change", np.random.default_rng(3))
    t = case.truth["fuel_change"]["t_fuel"]
    fit_data, hold, tail_of, _ = split([case.fit[0].between(t - 210.0, t + 150.0)], None)
    base = fitting.run_task(fitting.Task((), {}, fit_data, hold, tail_of, None, 0))
    box = EFFECTS["fuel_change"].tried.search_bounds(fit_data)
    fuel = fitting.run_task(fitting.Task(("fuel_change",), {}, fit_data, hold, tail_of,
                                         dict(base.params), 0, bounds=box))
    limit = limits([record_floor(e) for e in fit_data], GAP_RATIO, GAP_Z)
    assert all(fuel.rmse_fit_c[z] <= limit[z] for z in limit), (fuel.rmse_fit_c, limit)
    assert fuel.params["t_fuel"] == pytest.approx(t, abs=2.0)
    assert fuel.params["fuel_ratio"] == pytest.approx(case.truth["fuel_change"]["fuel_ratio"],
                                                      abs=0.01)


def test_a_combinations_kept_effects_are_not_started_again():
    """A combination starts from the kept effects' fit, which placed them (a switch's
    instant, a drift's sign) and left the network unbent by them: only the added effect's
    starts, and its networks, are tried again."""
    from furnace_model.diagnosis.fitting import _starts

    furnace = load_furnace(ROOT / "config/furnaces/paper-production.yaml")
    fuel, lag = EFFECTS["fuel_change"](furnace=furnace), EFFECTS["sensor_lag"](furnace=furnace)
    box = {"t_fuel": (0.0, 240.0)}
    pair = ModelStructure([fuel, lag], furnace=furnace)
    own, networks = _starts(pair, {}, box)
    assert len(own) == len(fuel.tried.starts(fuel, {}, box)) > 1 and len(networks) > len(own)
    assert _starts(pair, {}, box, settled=("fuel_change",)) == ([], [])
    assert _starts(pair, {}, box, settled=("fuel_change", "sensor_lag")) == ([], [])
    own, networks = _starts(pair, {}, box, settled=("sensor_lag",))
    assert len(own) > 1 and networks


@pytest.mark.slow  # the candidate's every start: half a minute of one core
def test_a_fuel_switch_under_control_is_named_alone():
    """The same window diagnosed with the switch and a lag as the candidates: the switch
    fitted alone reaches the floor held out, and nothing is added to it."""
    from furnace_model.diagnosis import diagnose

    d = diagnose([_fuel_window()], None, effects=("fuel_change", "sensor_lag"))
    assert d.verdict.status == "explained" and d.verdict.effects == ["fuel_change"], \
        d.verdict.sentence
    single = next(c for c in d.candidates if c.effects == ("fuel_change",))
    assert "refitted" not in single.note  # reached alone, not from a combination


@pytest.mark.slow  # the candidate's every start: a minute of one core
def test_a_fuel_switch_on_a_network_is_found_from_the_rates_its_inputs_give():
    """Known truth (the six-zone selfcheck's fuel row, draw 0): each burner gives 28% less
    heat from minute 2322 of 3068. The baseline bends by 11-16 °C to absorb it; from its
    rates the switch's fit stopped at minute 1088 and closed three quarters of the held-out
    gap. Started across the record, each start's network re-solved from the inputs the
    switch makes, the fit finds the switch and reaches the noise held out."""
    from furnace_model.diagnosis.fitting import Task, run_task
    from furnace_model.diagnosis.holdout import split
    from furnace_model.diagnosis.selfcheck import selfcheck_case
    from furnace_model.identification.noisefloor import record_floor

    case = selfcheck_case("fuel_change", 0, furnace=SIX)
    truth = case.truth["fuel_change"]
    fit_data, hold, tail_of, _ = split(case.fit, case.holdout)
    base = run_task(Task((), {}, fit_data, hold, tail_of, None, 0))
    assert max(base.rmse_fit_c.values()) > 10.0  # bent
    fuel = run_task(Task(("fuel_change",), {}, fit_data, hold, tail_of, dict(base.params), 0,
                         bounds=EFFECTS["fuel_change"].tried.search_bounds(fit_data)))
    assert fuel.params["t_fuel"] == pytest.approx(truth["t_fuel"], abs=15)
    assert fuel.params["fuel_ratio"] == pytest.approx(truth["fuel_ratio"], rel=0.03)
    floor = record_floor(hold[0]).floor_c
    for z in SIX.zones:
        assert fuel.rmse_holdout_c[z] < 1.3 * floor[z], (z, fuel.rmse_holdout_c[z], floor[z])


@pytest.mark.slow  # the candidate's fits: a minute of one core
def test_radiation_on_a_network_never_ends_worse_than_the_baseline_it_nests():
    """Known truth (the six-zone selfcheck's dead-time row, draw 0): no radiation. Started
    at half a share from the bent baseline's rates, the radiation fit can stop worse than
    the baseline it nests; polished again from its null (the baseline's parameters, offsets
    and initial states where its fit ended, as the search hands them over), it is at least
    the baseline."""
    from furnace_model.diagnosis.fitting import Task, run_task
    from furnace_model.diagnosis.holdout import split
    from furnace_model.diagnosis.selfcheck import selfcheck_case

    case = selfcheck_case("dead_time", 0, furnace=SIX)
    fit_data, hold, tail_of, _ = split(case.fit, case.holdout)
    base = run_task(Task((), {}, fit_data, hold, tail_of, None, 0))
    rad = run_task(Task(("radiation",), {}, fit_data, hold, tail_of, dict(base.params), 0,
                        baseline_sse=base.sse_fit, baseline_end=base.ended))
    assert rad.sse_fit <= base.sse_fit * (1 + 1e-6)
    for z in SIX.zones:
        assert rad.rmse_holdout_c[z] < base.rmse_holdout_c[z] + 0.5, z


@pytest.mark.slow  # a whole six-zone diagnosis: a minute of one core
def test_a_lag_whose_fit_has_side_valleys_is_named():
    """Known truth (the six-zone selfcheck's lag row, draw 2): soak_top's thermocouples lag
    14.4 minutes. With its offsets boxed from the start the lag's fit can stop in a side
    valley with its offsets on their bounds; from the free optimum, which is physical here,
    it reaches the floor, and the gap is explained by the lag at its true time constant."""
    from furnace_model.diagnosis import diagnose
    from furnace_model.diagnosis.selfcheck import judge_case, selfcheck_case

    case = selfcheck_case("sensor_lag", 2, furnace=SIX)
    d = diagnose(case.fit, case.holdout, effects=("sensor_lag", "dead_time"))
    assert judge_case(case, d)[0], d.verdict.sentence
    kept = d.best()
    assert kept.effects == ("sensor_lag",)
    assert kept.params["tau_lag"] == pytest.approx(14.4, rel=0.05)
    assert not [f for f in kept.flags if "offset" in f]


@pytest.mark.slow
def test_a_six_zone_diagnosis_names_a_drifting_thermocouple_of_a_zone_of_one():
    """Known truth: preheat_bottom_1, the only thermocouple of its zone, drifts 0.021 °C/min
    from minute 1675 of each heat-up. No partner shows it; the baseline bends and leaves a
    gap in every zone; the drift fitted on that thermocouple closes it, and the JSON names
    the furnace's zones."""
    from furnace_model.diagnosis import diagnose
    from furnace_model.diagnosis.cases import case_rng, draw_case
    from furnace_model.diagnosis.selfcheck import judge_case

    case = draw_case("sensor_drift", case_rng(0, "sensor_drift", 4), furnace=SIX)
    assert case.truth["sensor_drift"]["sensor"] == "preheat_bottom_1"
    d = diagnose(case.fit, case.holdout, effects=("sensor_drift",))
    assert judge_case(case, d)[0], d.verdict.sentence
    best = d.best()
    assert best.options["sensor_drift"]["sensor"] == "preheat_bottom_1"
    assert best.params["drift_rate"] == pytest.approx(case.truth["sensor_drift"]["drift_rate"],
                                                      rel=0.1)
    assert d.to_json()["verdict"]["effects"] == ["sensor_drift"]


def test_a_wall_of_one_zone_found_warm_spares_the_other_zones_searches(monkeypatch):
    """Known truth: the six-zone selfcheck's wall draw 0, a wall behind one zone. On the
    bent baseline the wall behind every zone misses the floor, and the wall's law of its
    own zone, warm from it, explains the gap: no zone's law is then searched from scratch
    (each such search is an evolutionary search and several polishes, for a zone the wall
    is not behind)."""
    from furnace_model.diagnosis import diagnose, fitting, pool
    from furnace_model.diagnosis.selfcheck import judge_case, selfcheck_case

    monkeypatch.setattr(pool, "WORKERS", 1)  # the fits in this process, where they are seen
    fit, cold = fitting.fit, []

    def seen(data, structure, **kwargs):
        if kwargs.get("init") is None:
            wall = [e for e in structure.effects if e.name == "wall_storage"]
            cold.extend(len(e.options["zones"]) for e in wall)
        return fit(data, structure, **kwargs)

    monkeypatch.setattr(fitting, "fit", seen)
    case = selfcheck_case("wall_storage", 0, furnace=SIX)
    d = diagnose(case.fit, case.holdout, effects=("wall_storage",))
    assert judge_case(case, d)[0], d.verdict.sentence
    assert list(d.best().options["wall_storage"]["zones"]) == case.truth["wall_storage"]["zones"]
    assert cold == [6]  # the wall behind every zone alone


@pytest.mark.slow
@pytest.mark.parametrize(("label", "draws"), [
    ("none", (0, 1)), ("wall_storage", (0, 1)), ("zone_losses", (0, 2)),
    ("zone_burners", (0, 1)), ("sensor_lag", (0, 1)), ("sensor_drift", (0, 1))])
def test_six_zone_selfcheck_rows(label, draws):
    """Issue 19's acceptance on the six-zone furnace, two draws a row (docs/diagnosis.md
    has ten): controls no_gap, a wall in one zone, losses in one zone, own-zone burners, a
    lagging and a drifting thermocouple named. The loss row's draws 1 and 4 name the wall
    of the loss's zone instead (the table's misses: over two heat-ups the two drain a zone
    alike), so its second draw here is draw 2."""
    from furnace_model.diagnosis.selfcheck import check

    outcomes = [o for d in draws for o in check([label], 1, first=d, furnace=SIX)]
    assert [o.draw for o in outcomes] == list(draws)
    wrong = [f"{o.draw}: {o.reason}; {o.description}" for o in outcomes if not o.correct]
    assert not wrong, wrong


def test_diagnose_cli_reads_the_records_as_the_furnace_named(tmp_path):
    """`simulate` then `diagnose --furnace`: the six-zone heat-up without effects has no
    gap; without --furnace its columns are refused as not the paper's."""
    import json
    import subprocess
    import sys

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "furnace_model.cli", *args],
                              capture_output=True, text=True, timeout=240)

    csv = tmp_path / "six.csv"
    r = cli("simulate", "--scenario", str(ROOT / "config/scenarios/six_zone_heatup.yaml"),
            "--out", str(csv))
    assert r.returncode == 0, r.stderr
    out = tmp_path / "d.json"
    r = cli("diagnose", str(csv), "--furnace", str(ROOT / "config/furnaces/six-zone.yaml"),
            "--json", str(out))
    assert r.returncode == 0, r.stderr
    doc = json.loads(out.read_text())
    assert doc["verdict"]["status"] == "no_gap" and list(doc["baseline"]["gap_limit_c"]) == \
        list(SIX.zones)
    assert "thermal network of furnace 'six-zone'" in r.stdout
    r = cli("diagnose", str(csv))
    assert r.returncode != 0 and "Traceback" not in r.stderr and "soak" in r.stderr
