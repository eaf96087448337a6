"""The selfcheck's known-truth cases: what the plant simulator draws, and (further down) the
diagnosis run on them with the effect withheld."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from furnace_model.diagnosis.cases import OUT_OF_LIBRARY, draw_case, parse_label
from furnace_model.diagnosis.selfcheck import ABSORBED_REASON, Outcome, check, summarize, table
from furnace_model.effects import EFFECTS
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.parameters import PAPER_TABLE_V
from furnace_model.simulation.structure import Inputs, ModelStructure


def _rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def test_case_shape_and_sensors_like_the_paper():
    case = draw_case(None, _rng(1), furnace=PAPER)
    assert case.truth == {} and case.expected_status == "no_gap"
    assert len(case.fit) == 1 and len(case.holdout) == 1
    for exp in case.fit + case.holdout:
        assert 3000 <= exp.t_min[-1] <= 3500
        np.testing.assert_allclose(np.diff(exp.t_min), 1.0)
        assert exp.burner_steps >= 3
        assert exp.start_time is not None
        # the pair difference of a zone is noise (sd 1.5 each) plus the two fixed biases
        pairs = exp.tc.reshape(-1, 3, 2)
        diff = pairs[:, :, 0] - pairs[:, :, 1]
        assert np.all(np.abs(diff.std(axis=0) - 1.5 * np.sqrt(2)) < 0.15)
    # heating- and preheating-zone burners fire together in the fitted experiment
    b = case.fit[0].burners
    assert np.any((b[:, 1] > 0) & (b[:, 2] > 0))
    assert case.holdout[0].start_time > case.fit[0].start_time


def test_same_seed_same_case_and_different_seeds_differ():
    a, b, c = draw_case("dead_time", _rng(5), furnace=PAPER), draw_case("dead_time", _rng(5),
                                                                        furnace=PAPER), \
        draw_case("dead_time", _rng(6), furnace=PAPER)
    np.testing.assert_array_equal(a.fit[0].tc, b.fit[0].tc)
    assert a.truth == b.truth
    assert a.truth != c.truth


def test_control_is_the_paper_model_plus_sensor_noise():
    exp = draw_case(None, _rng(2), furnace=PAPER).fit[0]
    model = ModelStructure(furnace=PAPER).simulate(PAPER_TABLE_V, Inputs.of(exp), exp.t_min,
                                      np.full(3, exp.t_air[0])).zones[0]
    resid = exp.zone_temp - model
    # zone mean of two thermocouples: noise 1.5/sqrt(2), plus a bias of sd 0.5/sqrt(2)
    assert np.all(np.abs(resid.std(axis=0) - 1.5 / np.sqrt(2)) < 0.1)
    assert np.all(np.abs(resid.mean(axis=0)) < 2.0)


@pytest.mark.parametrize("name", list(EFFECTS))
@pytest.mark.parametrize("form", ["candidate", "other"])
def test_every_effect_changes_the_furnace_and_records_its_truth(name, form):
    case = draw_case(name, _rng(3), form=form, furnace=PAPER)
    assert set(case.truth) == {name} and case.expected_status == "explained"
    # the recorded truth rebuilds the furnace: the data are it plus sensor noise and bias
    cls = EFFECTS[name]
    truth = case.truth[name]
    effect = cls(**{k: tuple(v) if isinstance(v, list) else v
                    for k, v in truth.items() if k in cls.specs(PAPER)}, furnace=PAPER)
    structure = ModelStructure([effect], furnace=PAPER)
    values = {**PAPER_TABLE_V, **{p.name: truth[p.name] for p in effect.params}}
    exp = case.fit[0]
    x0 = np.full(3, exp.t_air[0])
    model = structure.simulate(values, Inputs.of(exp), exp.t_min, x0).zones[0]
    drift = structure.sensor_offsets(values, exp.t_min)[0].reshape(-1, 3, 2).mean(axis=2)
    resid = exp.zone_temp - model - drift
    assert np.all(np.abs(resid.std(axis=0) - 1.5 / np.sqrt(2)) < 0.1)
    base = ModelStructure(furnace=PAPER).simulate(PAPER_TABLE_V, Inputs.of(exp), exp.t_min,
                                                  x0).zones[0]
    assert np.max(np.abs(model + drift - base)) > 3.0
    assert np.nanmax(exp.tc) < 1400.0


def test_other_forms_differ_from_the_candidate():
    lag = draw_case("sensor_lag", _rng(4), form="other", furnace=PAPER).truth["sensor_lag"]
    assert lag["order"] in (2, 3)
    rad = draw_case("radiation", _rng(4), form="other", furnace=PAPER).truth["radiation"]
    assert abs(rad["emissivity_slope"]) >= 0.4  # no power law: the candidate fits exponents
    nl = draw_case("burner_nonlinearity", _rng(4), form="other",
                   furnace=PAPER).truth["burner_nonlinearity"]
    assert nl["form"] not in ("linear", "power", "exponential")
    wall = draw_case("wall_storage", _rng(4), form="other", furnace=PAPER).truth["wall_storage"]
    assert wall["layers"] == 2  # the candidate's walls, behind any zones, have one


def test_door_open_cools_its_zone_for_an_hour():
    case = draw_case("door_open", _rng(7), furnace=PAPER)
    door = case.truth["door_open"]
    assert case.expected_status == "unexplained"
    z = PAPER.zones.index(door["zone"])
    for j, exp in enumerate(case.fit + case.holdout):
        clean = ModelStructure(furnace=PAPER).simulate(PAPER_TABLE_V, Inputs.of(exp), exp.t_min,
                                          np.full(3, exp.t_air[0])).zones[0]
        gap = clean[:, z] - exp.zone_temp[:, z]
        t_open = door["t_open"][j]
        before = exp.t_min < t_open
        assert np.all(np.abs(gap[before]) < 7.0)
        during = (exp.t_min > t_open + 40) & (exp.t_min < t_open + 60)
        assert gap[during].mean() > 8.0


def test_thermocouple_reading_low_in_episodes():
    case = draw_case("tc_reads_low", _rng(8), furnace=PAPER)
    low = case.truth["tc_reads_low"]
    i = PAPER.sensors.index(low["sensor"])
    partner = i ^ 1
    for j, exp in enumerate(case.fit + case.holdout):
        diff = exp.tc[:, partner] - exp.tc[:, i]
        inside = np.zeros(exp.t_min.size, dtype=bool)
        for lo, hi, _drop in low["episodes"][j]:
            inside |= (exp.t_min >= lo) & (exp.t_min < hi)
        assert inside.any()
        assert diff[inside].mean() > 12.0
        assert abs(diff[~inside].mean()) < 2.5


def test_two_effects_at_once_and_unknown_names():
    case = draw_case(("zone_burners", "sensor_lag"), _rng(9), furnace=PAPER)
    assert set(case.truth) == {"zone_burners", "sensor_lag"}
    assert case.library_effects == ("zone_burners", "sensor_lag")
    assert set(OUT_OF_LIBRARY).isdisjoint(EFFECTS)
    with pytest.raises(ValueError, match="unknown effect"):
        draw_case("door_opened", _rng(0), furnace=PAPER)
    with pytest.raises(ValueError, match="form"):
        draw_case("dead_time", _rng(0), form="odd", furnace=PAPER)


# --- the check itself --------------------------------------------------------------------

def _outcome(label, k, status, correct, absorbed=False):
    return Outcome(label, k, "", status, [], correct, absorbed,
                   ABSORBED_REASON if absorbed else "", 80.0, 95.0, 1.0, {})


def test_summary_counts_absorbed_draws_apart_and_applies_the_acceptance():
    outs = ([_outcome("none", k, "no_gap", True) for k in range(3)]
            + [_outcome("zone_losses", k, "no_gap", False, absorbed=True) for k in range(8)]
            + [_outcome("zone_losses", 8, "explained", True),
               _outcome("zone_losses", 9, "explained", False)]
            + [_outcome("dead_time", k, "explained", k != 3) for k in range(10)]
            + [_outcome("door_open", 0, "unexplained", True),
               _outcome("door_open", 1, "explained", False)])
    rows = {r.label: r for r in summarize(outs)}
    assert rows["none"].passed and rows["none"].verdicts["no_gap"] == 3
    # 2 counted draws, 1 correct: fewer than 9 in 10
    assert rows["zone_losses"].absorbed == 8 and not rows["zone_losses"].passed
    assert rows["dead_time"].correct == 9 and rows["dead_time"].passed
    assert not rows["door_open"].passed  # outside the library: every draw must be right
    text = table(list(rows.values()), outs)
    assert "Absorbed (reported apart, not failures):" in text
    assert text.count(ABSORBED_REASON) == 8
    assert "| dead_time | 10 | 0 | 10 | 0 | 9 | 0 | 80 | 95 |" in text


def test_the_intervals_a_verdict_gives_are_checked_against_the_truth():
    """Each case records, for the true effects its verdict names, whether the 95% intervals
    of their told parameters hold the drawn values; the table counts them."""
    outs = check(["sensor_drift", "fuel_change"], 1, furnace=PAPER,
                 candidates=("sensor_drift", "fuel_change"))
    for o in outs:
        assert o.named == [o.label], o
        assert set(o.held) == set(EFFECTS[o.label].told), o
    text = table(summarize(outs), outs)
    for p in ("drift_rate", "t_drift", "fuel_ratio", "t_fuel"):
        n = sum(o.held.get(p, False) for o in outs)
        assert f"{p} {n} of 1" in text, text
    missed = replace(outs[0], held=dict.fromkeys(outs[0].held, False))
    assert "drift_rate 0 of 1" in table(summarize([missed]), [missed])


def test_labels_name_effects_combinations_and_faults():
    assert parse_label("none") is None
    assert parse_label("zone_burners+sensor_lag") == ("zone_burners", "sensor_lag")
    assert parse_label("door_open") == "door_open"
    with pytest.raises(ValueError, match="unknown effect"):
        parse_label("zone_burner")
    with pytest.raises(ValueError, match="unknown effect"):
        parse_label("dead_time+")


@pytest.mark.timeout(400)
def test_selfcheck_command_on_a_small_set(tmp_path):
    """The command end to end in its own process: a control, an effect and a faulty
    thermocouple, one draw each, the diagnosis limited to two candidates (the full run,
    ten draws of every effect against all nine, is docs/diagnosis.md's table; each effect's
    own diagnosis is tested in test_diagnosis.py)."""
    out = tmp_path / "sc.json"
    proc = subprocess.run(
        [sys.executable, "-m", "furnace_model.cli", "selfcheck", "--draws", "1", "--effects",
         "none", "zone_burners", "tc_reads_low",
         "--candidates", "zone_burners,sensor_lag", "--json", str(out)],
        capture_output=True, text=True, timeout=380)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rows = [ln.split("|")[1].strip() for ln in proc.stdout.splitlines() if ln.startswith("| ")]
    assert rows == ["effect", "none", "zone_burners", "tc_reads_low"]
    doc = json.loads(out.read_text())
    cases = {c["label"]: c for c in doc["cases"]}
    assert cases["none"]["status"] == "no_gap" and cases["none"]["correct"]
    assert cases["zone_burners"]["named"] == ["zone_burners"] and cases["zone_burners"]["correct"]
    assert cases["zone_burners"]["shrink_pct"] >= 50
    assert cases["tc_reads_low"]["status"] == "unexplained" and cases["tc_reads_low"]["correct"]
    assert all(r["passed"] for r in doc["rows"])


def test_selfcheck_stopped_keeps_the_cases_it_diagnosed(tmp_path):
    out = tmp_path / "sc.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "furnace_model.cli", "selfcheck", "--draws", "20", "--effects",
         "none", "--json", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        # Ctrl-C as at a terminal: a job started in the background of a shell (as a test
        # run may be) passes SIGINT on ignored, and a child would never see it.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        line = proc.stderr.readline()
        while line.startswith("selfcheck: "):  # the count of cases done, with the time left
            line = proc.stderr.readline()
        assert line.startswith("none draw 0: no_gap")
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130, stderr
    assert "interrupted after" in stderr and "Traceback" not in stderr
    doc = json.loads(out.read_text())
    assert doc["complete"] is False and 1 <= len(doc["cases"]) < 20
    assert doc["rows"][0]["draws"] == len(doc["cases"])
    assert f"| none | {len(doc['cases'])} |" in stdout


def test_selfcheck_command_refuses_unknown_names():
    proc = subprocess.run([sys.executable, "-m", "furnace_model.cli", "selfcheck", "--effects",
                           "doors_open"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "unknown effect(s) doors_open" in proc.stderr and "Traceback" not in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "furnace_model.cli", "selfcheck",
                           "--candidates", "lag"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "unknown candidate(s) lag" in proc.stderr


def test_a_check_split_into_runs_draws_the_same_cases():
    whole = check(["none"], 2, seed=3, furnace=PAPER)
    second = check(["none"], 1, seed=3, first=1, furnace=PAPER)
    assert [o.draw for o in second] == [1]
    assert second[0].description == whole[1].description != whole[0].description


# -- production: closed-loop records instead of heat-ups ------------------------------------

def test_production_cases_are_records_of_the_plcs_loops():
    """`selfcheck --production` draws each row's case in closed loop: the records carry
    the loops' setpoints and the burners they fired, whole burners changing as a PI loop
    changes them (a heat-up's schedule has 4-7 steps); the held-out record charges the
    same day's charging rates in another order."""
    from furnace_model.diagnosis.cases import production_scenario
    from furnace_model.diagnosis.selfcheck import selfcheck_case

    scenario = production_scenario()
    case = selfcheck_case("none", 0, mode="production", furnace=scenario.furnace)
    assert "closed loop (paper_production)" in case.description
    fit, held = case.fit[0], case.holdout[0]
    for exp in (fit, held):
        assert sorted(exp.signals) == ["setpoint_heat", "setpoint_preheat", "setpoint_soak"]
        assert exp.signals["setpoint_soak"][100] == scenario.t_air_c + 2.0 * 100  # the ramp
        assert np.array_equal(exp.burners, np.round(exp.burners))
        assert np.all(exp.burners <= np.array(scenario.furnace.burners))
        changes = np.any(np.diff(exp.burners, axis=0) != 0, axis=1).sum()
        assert changes > 50, changes
    assert not np.array_equal(fit.disturbances, held.disturbances)
    assert np.array_equal(np.unique(fit.disturbances), np.unique(held.disturbances))
    with pytest.raises(ValueError, match="production cases run on furnace 'paper-production'"):
        selfcheck_case("none", 0, mode="production", furnace=PAPER)


@pytest.mark.parametrize("argv, says", [
    (["--furnace", "six-zone"], "leave out --furnace"),
    (["--effects", "none", "door_open"], "door_open: drawn in heat-ups only"),
])
def test_production_refuses_what_it_cannot_draw(argv, says, capsys):
    from furnace_model.cli import main

    assert main(["selfcheck", "--production", "--draws", "1", *argv]) == 1
    err = capsys.readouterr().err
    assert says in err and "Traceback" not in err


def test_production_with_all_adds_the_pair_and_not_the_faults():
    import argparse

    from furnace_model.cli.selfcheck import labels_of

    args = argparse.Namespace(first_draw=0, draws=1, effects=None, furnace=None, all=True,
                              production=True)
    labels = labels_of(args)
    assert labels[0] == "none" and "zone_burners+sensor_lag" in labels
    assert not set(labels) & set(OUT_OF_LIBRARY)
    assert set(OUT_OF_LIBRARY) <= set(labels_of(argparse.Namespace(**{**vars(args),
                                                                       "production": False})))


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_production_control_row_end_to_end(tmp_path):
    """One draw of the control row in closed loop, through the command: the JSON says the
    mode, and the case is the closed-loop one."""
    out = tmp_path / "sc.json"
    proc = subprocess.run(
        [sys.executable, "-m", "furnace_model.cli", "selfcheck", "--production", "--draws", "1",
         "--effects", "none", "--json", str(out), "--quiet"],
        capture_output=True, text=True, timeout=280)
    assert proc.returncode in (0, 1), proc.stdout + proc.stderr  # 1: the row's verdict missed
    doc = json.loads(out.read_text())
    assert doc["mode"] == "production" and doc["complete"] is True
    (case,) = doc["cases"]
    assert case["label"] == "none" and "closed loop (paper_production)" in case["description"]
    assert case["status"] in ("no_gap", "explained", "explained_in_part", "unexplained")
    assert "| none | 1 |" in proc.stdout


def test_the_json_names_the_furnace_drawn_on_by_its_shipped_name(tmp_path, capsys):
    """`--furnace six-zone --json`: the document names the description's file; the name of
    a shipped description is text, not a path, and once ended the run in a traceback after
    its table, without the document."""
    from furnace_model.cli import main

    out = tmp_path / "table.json"
    assert main(["selfcheck", "--furnace", "six-zone", "--effects", "none", "--draws", "1",
                 "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["furnace"].endswith("config/furnaces/six-zone.yaml")
    assert [r["label"] for r in doc["rows"]] == ["none"] and len(doc["cases"]) == 1
    assert "Traceback" not in capsys.readouterr().err
