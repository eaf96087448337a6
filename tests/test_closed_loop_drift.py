"""A thermocouple that drifts under control is told apart from a furnace that changed
(known truth, production records of the paper's furnace held by its PI loops): the loop
reading the drifting thermocouple moves the true zone, so the burners and the readings
both show it, and a fuel change is the other candidate the verdict has to turn down."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from furnace_model.diagnosis import diagnose
from furnace_model.diagnosis.cases import SENSORS_SPEC, draw_closed_loop_case, production_scenario
from furnace_model.diagnosis.fitting import (
    Task,
    end_task,
    moved,
    profile_told,
    run_task,
    told_interval,
    with_told,
)
from furnace_model.diagnosis.holdout import split
from furnace_model.effects import EFFECTS
from furnace_model.effects.sensor_drift import SensorDrift
from furnace_model.identification.fit import fit
from furnace_model.records import load_experiment
from furnace_model.simulation.furnacefile import load_furnace
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.structure import ModelStructure

ROOT = Path(__file__).resolve().parent.parent
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
    # the verdict's intervals are profiled: profiling them again from the kept fit moves
    # them no further than the profile's own tolerance; a time limit that leaves no time
    # for it keeps the linearised ones and says so
    task = end_task(kept, d.fit_data, [], [], 0,
                     EFFECTS["sensor_drift"].tried.search_bounds(d.fit_data))
    again = profile_told(task, kept)
    parts = {}
    for name in SensorDrift.told:
        width = kept.ci95[name][1] - kept.ci95[name][0]
        assert again.ci95[name] == pytest.approx(kept.ci95[name], abs=0.05 * width), name
        # the diagnosis profiles each told parameter in a task of its own: the same interval
        parts[name] = profile_told(dataclasses.replace(task, told=(name,)), kept)
        assert parts[name].ci95[name] == again.ci95[name], name
    late = profile_told(dataclasses.replace(task, deadline=-math.inf), kept)
    assert late.cut and late.ci95 == kept.ci95
    # a limit that cut one profile of two: the other's interval given, the cut one named
    first, second = SensorDrift.told
    merged, said = with_told(kept, [first, second], [parts[first], late])
    assert merged.ci95[first] == parts[first].ci95[first]
    assert merged.ci95[second] == kept.ci95[second]
    assert said is not None and f"({second})" in said and first not in said
    none, all_said = with_told(kept, [first, second], [late, late])
    assert none is kept and all_said == said.replace(f" ({second})", "")


STORY_WINDOW = ROOT / "tests" / "data" / "production_drift_onset_window.csv"
"""The online story's drift window 5-11 h as the daemon logged it: soak_1 drifting
-3 °C/h from minute 120 of it (tests/data/production_faults_day.yaml)."""
STORY_SEED = 1775494800  # the daemon's seed for that window
STORY_TRUTH = {"drift_rate": -0.05, "t_drift": 120.0}


def test_a_told_profile_that_finds_a_lower_valley_moves_the_verdicts_fit():
    """With the daemon's seed the drift's candidate on the story's window stops in a side
    valley (-2.1 °C/h from minute 50) that follows the records to their noise as the lowest
    does, and intervals drawn around it miss the truth. A profile's refits pass the lower
    valley: the fit moves there, the candidate is fitted and scored there anew, and its told
    intervals hold the truth (the onset's to within a sample)."""
    furnace = load_furnace(ROOT / "config" / "furnaces" / "paper-production.yaml")
    fit_data, hold, tail_of, _ = split([load_experiment(STORY_WINDOW, furnace=furnace)], None)
    base = run_task(Task((), {}, fit_data, hold, tail_of, None, STORY_SEED))
    box = EFFECTS["sensor_drift"].tried.search_bounds(fit_data)
    options = {"sensor_drift": {"sensor": "soak_1"}}
    kept = run_task(Task(("sensor_drift",), options, fit_data, hold, tail_of,
                         dict(base.params), STORY_SEED, bounds=box, baseline_sse=base.sse_fit,
                         baseline_end=base.ended))
    lo, hi = kept.ci95["drift_rate"]
    assert not lo <= STORY_TRUTH["drift_rate"] <= hi, kept.ci95  # the side valley
    structure = ModelStructure([SensorDrift(sensor="soak_1", furnace=furnace)], furnace=furnace)
    told = fit(fit_data, structure, init=kept.params, zone_offsets=True, bounds=box,
               profile=SensorDrift.told, warm=kept.ended)
    assert told.moves >= 1 and told.sse < kept.sse_fit
    part = profile_told(end_task(kept, fit_data, hold, tail_of, STORY_SEED, box), kept)
    assert moved(kept, [part]) is part and part.sse_fit == pytest.approx(told.sse)
    assert part.rmse_holdout_c != kept.rmse_holdout_c  # scored where it now lies
    lo, hi = part.ci95["drift_rate"]
    assert lo <= STORY_TRUTH["drift_rate"] <= hi, part.ci95
    lo, hi = part.ci95["t_drift"]  # the onset to within the records' one-minute sample
    assert lo - 1.0 <= STORY_TRUTH["t_drift"] <= hi + 1.0, part.ci95


@pytest.mark.slow  # half a minute of one core
def test_a_fuel_change_under_control_is_named_not_a_sensor():
    record, truth = _around_onset("fuel_change", 3)
    d = diagnose([record], None, effects=("sensor_drift", "fuel_change"))
    assert d.verdict.status == "explained", d.verdict.sentence
    assert d.verdict.effects == ["fuel_change"]
    assert d.kept.params["t_fuel"] == pytest.approx(truth["t_fuel"], abs=30.0)
    assert d.kept.params["fuel_ratio"] == pytest.approx(truth["fuel_ratio"], rel=0.05)


# --- the intervals the verdict gives ------------------------------------------------------
# The daemon diagnoses six-hour windows and fits their first 70%: a drift seen for two to
# four hours of one, its onset two hours in. Fitted from the truth with the drift's
# thermocouple known (the optimum the diagnosis finds, sooner), over a hundred draws of the
# drift, its thermocouple, how long it is seen, the noise and the slabs; under 100 a 99%
# bound cannot be checked.
BEFORE, SEEN = 120.0, (120.0, 240.0)
DRAWS = 100


def _short_drift(draw: int):
    """One production record of the paper's furnace from BEFORE minutes before a drawn
    drift's onset to SEEN (drawn) after it, with the drift and the network's truth."""
    scenario = production_scenario()
    rng = np.random.default_rng([DRAWS, draw])
    effect, values = EFFECTS["sensor_drift"].drawn.draw(rng, "candidate",
                                                        scenario.duration_min, scenario.furnace)
    onset, seen = float(values["t_drift"]), float(rng.uniform(*SEEN))
    run = dataclasses.replace(scenario, duration_min=onset + seen)
    plant = Plant(ModelStructure([*scenario.effects, effect], furnace=scenario.furnace),
                  {**scenario.values(), **values}, SENSORS_SPEC, seed=int(rng.integers(2**31)))
    record = plant.run_closed_loop(run).to_experiment("drift").between(onset - BEFORE,
                                                                       onset + seen)
    return record, effect, {**scenario.values(), **values}


@pytest.fixture(scope="module")
def drift_intervals():
    """Per draw, (truth, linearised intervals, intervals as the verdict gives them)."""
    out = []
    for k in range(DRAWS):
        record, effect, truth = _short_drift(k)
        structure = ModelStructure([effect], furnace=record.furnace)
        bounds = {"t_drift": (float(record.t_min[0]), float(record.t_min[-1])),
                  "drift_rate": (-0.2, 0.2)}
        init = {n: truth[n] for n in structure.names}
        linear = fit([record], structure, init=init, zone_offsets=True, bounds=bounds,
                     profile=False)
        profiled = fit([record], structure, init=init, zone_offsets=True, bounds=bounds,
                       profile=SensorDrift.told)
        told = {n: told_interval(linear.ci95[n], profiled.ci95[n], profiled.params[n])
                for n in SensorDrift.told}
        out.append((truth, linear.ci95, told))
    return out


def _held(intervals, which: int, name: str) -> float:
    return float(np.mean([row[which][name][0] <= row[0][name] <= row[which][name][1]
                          for row in intervals]))


@pytest.mark.slow  # two fits and a closed-loop run per draw: about three minutes of one core
def test_a_drifts_told_intervals_hold_the_truth_from_hours_of_it(drift_intervals):
    held = {n: _held(drift_intervals, 2, n) for n in SensorDrift.told}
    assert all(0.90 <= v <= 0.99 for v in held.values()), held


@pytest.mark.slow
def test_a_linearised_onset_interval_misses_the_truth_from_hours_of_drift(drift_intervals):
    """Why the verdict's are profiled: the onset trades with the rate, and the criterion
    along that valley is far from the quadratic a linearised interval assumes."""
    assert _held(drift_intervals, 1, "t_drift") < 0.90
