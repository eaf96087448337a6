"""The diagnosis on known-truth cases from the plant simulator: each effect switched on in
turn (strengths and schedules drawn at random, never shown to the diagnosis), a control
with none, two at once, faults outside the effect library, and formulations that differ
from the candidates'.

The quick tests try a few candidates (the true one among distractors) on one draw; the slow
ones try all nine on ten draws per effect, as the acceptance asks."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from furnace_model.cli.diagnose import summary
from furnace_model.diagnosis import (
    COLD_GENERATIONS,
    NEAR_RATIO,
    CandidateResult,
    Task,
    blend_weight,
    credited,
    diagnose,
    further_laws,
    judge,
    run_task,
    split,
)
from furnace_model.diagnosis.cases import case_rng, draw_case
from furnace_model.diagnosis.fitting import determined
from furnace_model.diagnosis.laws import laws_named
from furnace_model.diagnosis.selfcheck import judge_case
from furnace_model.effects import EFFECTS, Clues, FuelChange, Radiation, SensorDrift, ZoneBurners
from furnace_model.effects.zone_burners import soak_only_heads
from furnace_model.errors import FurnaceError
from furnace_model.experiment import Experiment
from furnace_model.identification.model import Model
from furnace_model.identification.noisefloor import pooled_floor, record_floor
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.parameters import PAPER_TABLE_V
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import SensorSpec
from furnace_model.simulation.structure import Inputs, ModelStructure

QUICK = ("zone_burners", "sensor_lag", "zone_losses", "fuel_change")
CONTRACT_KEYS = {"baseline", "where", "candidates", "verdict"}


def _case(effect, seed, form="candidate"):
    return draw_case(effect, np.random.default_rng(seed), form=form, furnace=PAPER)


def test_control_has_no_gap():
    case = _case(None, 11)
    d = diagnose(case.fit, case.holdout, effects=QUICK)
    assert d.verdict.status == "no_gap", d.verdict.sentence
    assert d.verdict.effects == []
    for z, floor in d.noise_floor_c.items():
        assert d.baseline.rmse_holdout_c[z] < 1.15 * floor
        assert 0.9 < floor < 1.2  # 1.5 degC per thermocouple, two per zone
    doc = d.to_json()
    assert set(doc) >= CONTRACT_KEYS
    assert set(doc["baseline"]) >= {"rmse_fit_c", "rmse_holdout_c", "noise_floor_c"}


def test_holdout_cut_from_the_data_when_none_is_given():
    case = _case(None, 15)
    exp = case.fit[0]
    d = diagnose([exp], effects=QUICK)  # one experiment: its tail is held out
    assert d.holdout_how.startswith(f"last 30% of {exp.name}")
    tail = d.holdout[0]
    assert tail.t_min[0] > d.fit_data[0].t_min[-1] and len(d.fit_data[0]) + len(tail) == len(exp)
    assert d.baseline.holdout_pred[0].shape == (len(tail), 3)
    assert d.verdict.status == "no_gap", d.verdict.sentence
    # the tail continues the fitted run: no jump at the cut
    jump = d.baseline.holdout_pred[0][0] - d.baseline.fit_pred[0][-1]
    assert np.all(np.abs(jump) < 5.0)
    d2 = diagnose([exp, case.holdout[0]], effects=QUICK)  # several: the last one held out
    assert d2.holdout_how == f"whole experiments: {case.holdout[0].name} held out"
    assert d2.verdict.status == "no_gap"


def test_zone_burners_named_with_large_shrink():
    case = _case("zone_burners", 12)
    d = diagnose(case.fit, case.holdout, effects=QUICK)
    assert d.verdict.status == "explained", d.verdict.sentence
    assert d.verdict.effects == ["zone_burners"]
    assert d.verdict.shrink_pct >= 50
    best = d.best()
    assert best is not None and best.effects == ("zone_burners",)
    doc = d.to_json()
    top = doc["candidates"][0]
    assert top["effect"] == "zone_burners" and top["shrink_pct"] >= 50 and top["delta_bic"] < 0
    assert doc["verdict"] == {**doc["verdict"], "status": "explained",
                              "effects": ["zone_burners"]}
    assert len(best.holdout_pred) == 1 and best.holdout_pred[0].shape == (len(case.holdout[0]), 3)


def test_a_combination_with_credit_that_is_not_kept_says_why():
    """Zone burners and a sensor lag, with a dead time among the candidates: the lag is
    added to the zone burners; the dead time added instead also earns credit against the
    baseline (it extends the zone burners, which close 99% of the gap alone), so the credit
    the summary shows does not by itself say what the verdict kept: its note does.

    Also: the combinations' stage is announced as it starts, and each combination is heard
    as it is fitted (a combination of nonlinear effects takes minutes on a long record); the
    share done never goes back, from 0 to 1."""
    case = _case(("zone_burners", "sensor_lag"), 300)
    heard: list[str] = []
    shares: list[float] = []

    def progress(stage: str, share: float) -> None:
        heard.append(stage)
        shares.append(share)
    d = diagnose(case.fit, case.holdout, effects=("zone_burners", "sensor_lag", "dead_time"),
                 progress=progress)
    assert shares[0] == 0.0 and shares[-1] == 1.0 and heard[-1] == "done"
    assert all(a <= b for a, b in zip(shares, shares[1:], strict=False)), \
        list(zip(heard, shares, strict=True))
    combos = [s for s in heard if " fitted in " in s and "+" in s.split(" fitted in ")[0]]
    assert any(s.startswith("zone_burners+sensor_lag fitted in ") for s in combos), heard
    assert heard.index("combinations") < heard.index(combos[0]), heard
    assert d.verdict.status == "explained"
    assert set(d.verdict.effects) == {"zone_burners", "sensor_lag"}, d.verdict.sentence
    chosen = d.best()
    assert credited(chosen) and "not kept" not in chosen.note
    others = [c for c in d.candidates if len(c.effects) > 1 and credited(c)
              and set(c.effects) != set(d.verdict.effects)]
    assert others, [(c.label, credited(c)) for c in d.candidates]
    for c in others:
        assert f"not kept: the stepwise search keeps {chosen.label}" in c.note, c.note
        assert f"- {c.label}: " in summary(d)
    assert [c["credit"] for c in d.to_json()["candidates"]] == [credited(c)
                                                              for c in d.candidates]


def test_thermocouple_reading_low_at_times_is_unexplained_and_located():
    case = _case("tc_reads_low", 13)
    d = diagnose(case.fit, case.holdout, effects=QUICK)
    assert d.verdict.status == "unexplained", d.verdict.sentence
    sensor = case.truth["tc_reads_low"]["sensor"]
    assert d.where and d.where[0].sensor == sensor
    assert sensor in d.verdict.sentence
    assert judge_case(case, d) == (True, False, "")
    other = next(s for s in case.fit[0].furnace.sensors if s != sensor)
    moved = dataclasses.replace(case, truth={"tc_reads_low": {**case.truth["tc_reads_low"],
                                                              "sensor": other}})
    assert judge_case(moved, d) == (False, False, f"located thermocouple {sensor}, not "
                                                  f"thermocouple {other}")


def test_split_refuses_what_cannot_be_diagnosed():
    case = _case(None, 14)
    exp = case.fit[0]
    short = exp.between(0, 60)
    with pytest.raises(FurnaceError, match="too short to hold out"):
        split([short], None)
    steady = Experiment("steady", exp.t_min, exp.tc, np.full_like(exp.burners, 2), exp.t_air,
                        furnace=PAPER)
    with pytest.raises(FurnaceError, match="no burner change"):
        split([steady], None)
    with pytest.raises(FurnaceError, match="excitation"):
        split([steady], [exp])
    blind = Experiment("blind", exp.t_min, exp.tc.copy(), exp.burners, exp.t_air, furnace=PAPER)
    blind.tc[:, 2:4] = np.nan
    with pytest.raises(FurnaceError, match="zone 'heat' has no thermocouple readings"):
        split([exp, blind], None)
    fit, hold, tail_of, how = split([exp], None)
    assert tail_of == [0] and "last 30%" in how
    assert hold[0].t_min[0] > fit[0].t_min[-1]
    with pytest.raises(FurnaceError, match="unknown effect"):
        diagnose([exp], effects=("no_such_effect",))


def test_the_experiment_held_out_is_one_whose_burners_the_others_fire():
    exp = _case(None, 14).fit[0]
    soak_only = Experiment("soak_only", exp.t_min, exp.tc, exp.burners * [1, 0, 0], exp.t_air,
                           furnace=PAPER)
    hot = Experiment("hot", exp.t_min, exp.tc, exp.burners * [1, 0, 0] + [0, 2, 0], exp.t_air,
                     furnace=PAPER)
    fit, hold, _, how = split([soak_only, hot], None)  # not the last: no other fires zone 2
    assert [e.name for e in fit] == ["hot"] and [e.name for e in hold] == ["soak_only"]
    assert "hot fires heating-zone burners the rest never fire" in how
    fit, hold, _, how = split([hot, soak_only], None)
    assert [e.name for e in hold] == ["soak_only"] and "never" not in how
    fit, hold, _, how = split([soak_only], [hot])  # as given, and said
    assert [e.name for e in hold] == ["hot"]
    assert "fires heating-zone burners, which the fitted data never fire" in how


def test_zone_burner_fit_starts_from_the_data_before_other_burners_fire():
    # A draw (selfcheck seed 0, draw 3) where the baseline bends to absorb the heating- and
    # preheating-zone burners (f tens of times off the truth) and a zone-burner fit
    # warm-started from it stays in a side valley, off the noise floor.
    case = draw_case("zone_burners", case_rng(0, "zone_burners", 3), furnace=PAPER)
    base = run_task(Task((), {}, case.fit, case.holdout, [None], None, 0))
    assert abs(np.log(base.params["f"] / PAPER_TABLE_V["f"])) > np.log(10.0), base.params
    trial = ZoneBurners.tried.trial(Clues(case.fit, case.fit + case.holdout, bent=True,
                                          furnace=PAPER))
    start = determined(trial.start_on, 0)
    assert set(start) == {"a", "f"}
    for k in start:
        assert start[k] == pytest.approx(PAPER_TABLE_V[k], rel=0.03)
    floor = pooled_floor([record_floor(e) for e in case.holdout])
    # as the diagnosis gives it: the baseline's start, replaced in the task by the heads'
    c = run_task(Task(("zone_burners",), {"zone_burners": {}}, case.fit, case.holdout, [None],
                      dict(base.params), 0, bounds=_bounds(case.fit), baseline_sse=base.sse_fit,
                      baseline_end=base.ended, start_on=trial.start_on))
    for z in PAPER.zones:
        assert c.rmse_holdout_c[z] < NEAR_RATIO * floor[z], (z, c.rmse_holdout_c)
    assert c.params["f_heat"] == pytest.approx(case.truth["zone_burners"]["f_heat"], rel=0.1)
    # no other burner in the fitted data: nothing to start from but the baseline
    soak_only = Experiment("soak_only", case.fit[0].t_min, case.fit[0].tc,
                           case.fit[0].burners * [1, 0, 0], case.fit[0].t_air, furnace=PAPER)
    assert soak_only_heads([soak_only]) is None
    assert ZoneBurners.tried.trial(Clues([soak_only], [soak_only], bent=True,
                                         furnace=PAPER)).start_on is None


@pytest.mark.slow  # a cold GA search of a nonlinear candidate: the selfcheck's radiation rows cover it
def test_nonlinear_candidate_searched_from_scratch_leaves_the_bent_baseline_valley():
    # Selfcheck seed 0, radiation draw 4: strong radiation bends the baseline (a at its
    # bound), and the radiation fit warm-started from there stops 10 degC off the floor (a
    # at 1.0 again). Searched from scratch, it finds the plant.
    case = draw_case("radiation", case_rng(0, "radiation", 4), furnace=PAPER)
    c = run_task(Task(("radiation",), {"radiation": {"exponent": 4.0}}, case.fit, case.holdout,
                      [None], None, 1, bounds=_bounds(case.fit),
                      generations=COLD_GENERATIONS))
    floor = pooled_floor([record_floor(e) for e in case.holdout])
    for z in PAPER.zones:
        assert c.rmse_holdout_c[z] < NEAR_RATIO * floor[z], (z, c.rmse_holdout_c)
    assert c.params["rad_share"] == pytest.approx(case.truth["radiation"]["rad_share"], abs=0.02)
    assert c.params["a"] == pytest.approx(PAPER_TABLE_V["a"], rel=0.05)


def test_a_law_between_the_candidates_laws_is_named_as_their_blend():
    # A furnace whose burner curve is the square of a straight line: between the candidate's
    # straight line and exponential. Fitted on up to 10 burners, both laws fit to the noise;
    # the held-out run fires 14, where they part, and neither alone reaches the floor there.
    case = _case("burner_nonlinearity", 5, form="other")
    assert case.truth["burner_nonlinearity"]["form"] == "quadratic"
    d = diagnose(case.fit, case.holdout, effects=("burner_nonlinearity", "fuel_change"))
    assert d.verdict.status == "explained", d.verdict.sentence
    assert d.verdict.effects == ["burner_nonlinearity"]
    best = d.best()
    blend = best.options["burner_nonlinearity"]
    assert {o["form"] for o in blend["between"]} == {"linear", "exponential"}
    assert 0.2 < blend["weight"] < 0.8  # about halfway, as the square of a line is
    assert "law between" in best.note
    for z in PAPER.zones:
        assert best.rmse_holdout_c[z] < NEAR_RATIO * d.noise_floor_c[z]
    k = case.truth["burner_nonlinearity"]["k_nl"]
    assert best.params["k_nl"] == pytest.approx(k, rel=0.25)


def test_further_laws_only_for_a_candidate_that_helps():
    def cand(name, closed, dbic):
        return CandidateResult((name,), {}, {}, {}, {}, gap_closed_pct=closed, delta_bic=dbic)

    laws = further_laws([cand("radiation", 40.0, -300.0),  # helps
                         cand("wall_storage", 60.0, 5.0),  # closes, but costs BIC
                         cand("burner_nonlinearity", 0.0, -10.0),  # closes nothing
                         cand("dead_time", 90.0, -900.0)], PAPER)  # has one law
    assert [(c.effects[0], o) for c, o in laws] == [("radiation", o) for o in Radiation.tried.further_laws]
    walls = further_laws([cand("wall_storage", 60.0, -50.0)], PAPER)
    assert [o["zones"] for _, o in walls] == [(z,) for z in PAPER.zones]


def test_wall_behind_one_zone_is_named_with_its_zone():
    # A two-layer wall behind the preheating zone alone (selfcheck seed 0, other form, draw
    # 1): one exchange rate shared by walls behind all three zones leaves that zone off the
    # floor; the preheating-zone law reaches it, though its exchange rate trades with the
    # zone's own rates and only its release rate is determined.
    case = draw_case("wall_storage", case_rng(0, "wall_storage", 1), form="other", furnace=PAPER)
    assert case.truth["wall_storage"]["zones"] == ["preheat"]
    d = diagnose(case.fit, case.holdout, effects=["wall_storage"])
    assert d.verdict.status == "explained" and d.verdict.effects == ["wall_storage"]
    best = d.to_json()["candidates"][0]
    assert best["options"] == {"wall_storage": {"zones": ["preheat"]}}
    assert "law chosen among zones preheat" in best["note"]


def test_the_laws_chosen_among_are_each_named():
    """A loss tried in its own options (every zone that might lose heat), then in each zone
    alone: the note names the first by the zones its options give, not a blank."""
    def cand(options):
        return CandidateResult(("zone_losses",), {}, {}, {}, {},
                               options={"zone_losses": options})

    same = [cand({}), cand({"zones": ("soak",)}), cand({"zones": ("heat",)})]
    assert laws_named(same, PAPER) == "zones soak heat, zones soak, zones heat"


def testblend_weight_is_the_least_squares_one():
    rng = np.random.default_rng(0)
    exp = _case(None, 14).fit[0]
    p = exp.zone_temp + rng.normal(0, 5, exp.zone_temp.shape)
    q = exp.zone_temp + rng.normal(0, 5, exp.zone_temp.shape)
    truth = 0.3 * p + 0.7 * q
    held = Experiment("held", exp.t_min, np.repeat(truth, 2, axis=1), exp.burners, exp.t_air,
                      furnace=PAPER)
    assert np.allclose(held.zone_temp, truth)
    assert blend_weight([p], [q], [held]) == pytest.approx(0.7, abs=1e-9)
    assert blend_weight([p], [p], [held]) == 0.0  # nothing to weigh


# --- acceptance, all nine candidates (make test-slow) -------------------------------------

DRAWS = 10


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_control_no_gap_every_draw():
    for s in range(DRAWS):
        case = _case(None, 100 + s)
        d = diagnose(case.fit, case.holdout)
        assert d.verdict.status == "no_gap", (s, d.verdict.sentence)


@pytest.mark.slow
@pytest.mark.timeout(7200)
@pytest.mark.parametrize("effect", list(EFFECTS))
def test_each_effect_named_nine_in_ten(effect):
    hits, absorbed, misses = 0, 0, []
    for s in range(DRAWS):
        case = _case(effect, 200 + s)
        d = diagnose(case.fit, case.holdout)
        v = d.verdict
        if v.status == "no_gap":
            absorbed += 1  # the baseline reaches the floor: honest, reported apart
        elif v.status == "explained" and v.effects == [effect] and v.gap_closed_pct >= 50:
            # the gap above the noise floor, not the plain RMSE: a lag that doubles the
            # error is fully explained at an RMSE shrink of 50%, never more
            hits += 1
        else:
            misses.append((s, v.status, v.effects, round(v.shrink_pct), case.description))
    assert hits >= 9 * (DRAWS - absorbed) / 10, misses


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_two_effects_both_named():
    for s in range(3):
        case = _case(("zone_burners", "sensor_lag"), 300 + s)
        d = diagnose(case.fit, case.holdout)
        assert d.verdict.status == "explained", d.verdict.sentence
        assert set(d.verdict.effects) == {"zone_burners", "sensor_lag"}, case.description


@pytest.mark.slow
@pytest.mark.timeout(3600)
@pytest.mark.parametrize("fault", ["door_open", "tc_reads_low"])
def test_outside_the_library_is_unexplained_and_located(fault):
    for s in range(3):
        case = _case(fault, 400 + s)
        d = diagnose(case.fit, case.holdout)
        assert d.verdict.status == "unexplained", (case.description, d.verdict.sentence)
        truth = case.truth[fault]
        if fault == "door_open":
            assert d.where[0].zone == truth["zone"] and d.where[0].sensor is None
        else:
            assert d.where[0].sensor == truth["sensor"]


@pytest.mark.slow
@pytest.mark.timeout(3600)
@pytest.mark.parametrize("effect", ["sensor_lag", "radiation", "burner_nonlinearity",
                                    "wall_storage"])
def test_other_formulations_still_named(effect):
    hits = absorbed = 0
    for s in range(5):
        case = _case(effect, 500 + s, form="other")
        d = diagnose(case.fit, case.holdout)
        absorbed += d.verdict.status == "no_gap"  # as a weak preheating-zone wall can be
        hits += d.verdict.status == "explained" and d.verdict.effects == [effect]
    assert absorbed <= 2 and hits >= 5 - absorbed - 1


def test_radiation_exponent_is_fitted_from_the_data():
    # The further radiation law fits its exponent. Started at 5.5 on a Stefan-Boltzmann
    # furnace (selfcheck seed 0, radiation draw 1), the fit finds 4 back, and the share.
    case = draw_case("radiation", case_rng(0, "radiation", 1), furnace=PAPER)
    truth = case.truth["radiation"]
    c = run_task(Task(("radiation",), {"radiation": {"exponent": None}}, case.fit, case.holdout,
                      [None], {**PAPER_TABLE_V, "rad_share": 0.3, "rad_exponent": 5.5}, 0,
                      bounds=_bounds(case.fit)))
    assert c.params["rad_exponent"] == pytest.approx(truth["exponent"], abs=0.15)
    assert c.params["rad_share"] == pytest.approx(truth["rad_share"], abs=0.03)
    lo, hi = c.ci95["rad_exponent"]
    assert lo < truth["exponent"] < hi and hi - lo < 0.5
    floor = pooled_floor([record_floor(e) for e in case.holdout])
    for z in PAPER.zones:
        assert c.rmse_holdout_c[z] < NEAR_RATIO * floor[z], (z, c.rmse_holdout_c)


def test_a_parameter_the_fitted_data_do_not_see_is_estimated_on_the_held_out_data():
    # With the heating- and preheating-zone burners on their own zones, f rests on the
    # soaking-zone burners alone; a fitted record in which they never step leaves it
    # anywhere (selfcheck seed 0, zone_burners+sensor_lag draw 8). Fixed where the fit left
    # it, the held-out score would depend on the start, not on the model.
    structure = ModelStructure([EFFECTS["zone_burners"](furnace=PAPER)], furnace=PAPER)
    truth = {**PAPER_TABLE_V, "f_heat": 3.0, "f_preheat": 4.2}
    plant = Plant(structure, truth, SensorSpec(noise_sd_c=1.5, bias_sd_c=0.0), seed=5)
    t = np.arange(0.0, 1500.0, 1.0)

    def run(times, counts, name):
        inputs = Inputs(np.array(times), np.array(counts, dtype=float), np.full(len(times), 25.0))
        return plant.run(inputs, t, np.full(3, 25.0)).to_experiment(name)

    soak_steady = run([0.0, 500.0, 1000.0], [[3, 0, 0], [3, 2, 2], [3, 6, 1]], "soak_steady")
    soak_steps = run([0.0, 400.0, 800.0, 1100.0], [[3, 0, 0], [5, 0, 0], [8, 0, 0], [2, 5, 1]],
                     "soak_steps")
    start = {**truth, "f": 0.5 * truth["f"]}
    c = run_task(Task(("zone_burners",), {"zone_burners": {}}, [soak_steady], [soak_steps],
                      [None], start, 0))
    assert c.held_out_fitted == ("f",) and "f unseen by the fitted data" in c.note, c.note
    floor = pooled_floor([record_floor(soak_steps)])
    for z in PAPER.zones:
        assert c.rmse_holdout_c[z] < NEAR_RATIO * floor[z], (z, c.rmse_holdout_c)
    # an f the fitted data leave anywhere, held where a start put it, misses the held-out data
    fixed = Model(structure, {**c.params, "f": start["f"]},
                  zone_offsets=True).refine([soak_steps]).predict(0)
    rmse_fixed = np.sqrt(np.nanmean((soak_steps.zone_temp - fixed) ** 2, axis=0))
    assert rmse_fixed.max() > 2 * NEAR_RATIO * max(floor.values()), rmse_fixed
    # the same fit on a record whose soaking burners step sees every parameter
    d = run_task(Task(("zone_burners",), {"zone_burners": {}}, [soak_steps], [soak_steady],
                      [None], start, 0))
    assert d.held_out_fitted == () and "unseen" not in d.note
    # and the verdict tells the plant engineer
    v = judge(d, c, [c], floor, {z: NEAR_RATIO * floor[z] for z in PAPER.zones}, PAPER.zones, [],
              furnace=PAPER)
    assert v.status == "explained" and "do not show f (soaking-zone heating rate" in v.sentence


def _bounds(fit_data):
    return {**FuelChange.tried.search_bounds(fit_data),
            **SensorDrift.tried.search_bounds(fit_data)}


def test_a_candidate_that_ends_above_the_baseline_it_nests_is_polished_from_its_null():
    """Radiation at share 0 is the baseline: a radiation fit that stops worse than the
    baseline (its strength started far from the data's, held there below) is polished again
    from the null, and ends no worse than the baseline. Known truth: a dead time, no
    radiation."""
    from furnace_model.diagnosis.fitting import Task, _from_null, run_task
    from furnace_model.diagnosis.holdout import split
    from furnace_model.identification.fit import fit
    from furnace_model.simulation.structure import ModelStructure

    case = draw_case("dead_time", case_rng(0, "dead_time", 0), furnace=PAPER)
    # the first 1000 minutes of each record: the radiation fits cost their length
    fit_data, hold, tail_of, _ = split([e.between(0, 1000) for e in case.fit],
                                       [e.between(0, 1000) for e in case.holdout])
    base = run_task(Task((), {}, fit_data, hold, tail_of, None, 0))
    structure = ModelStructure([Radiation(furnace=PAPER)], furnace=PAPER)
    start = {**structure.defaults(), **base.params}
    stuck = fit(fit_data, structure, init=start, fixed={"rad_share": 0.9}, zone_offsets=True,
                profile=False)
    assert stuck.sse > 1.05 * base.sse_fit
    task = Task(("radiation",), {}, fit_data, hold, tail_of, dict(base.params), 0,
                baseline_sse=base.sse_fit)
    again = _from_null(stuck, task, structure, start, {})
    assert again.sse <= base.sse_fit * (1 + 1e-6)
    assert "rad_share" in again.params


def test_the_baselines_searches_side_by_side_are_the_baseline_of_one_task():
    """The diagnosis runs the baseline's searches as one task each on its pool and keeps
    the lowest: the same fit, to the last digit, as one task of BASELINE_RUNS runs."""
    from furnace_model.diagnosis.fitting import BASELINE_RUNS, baseline_tasks

    case = draw_case("zone_burners", case_rng(0, "zone_burners", 3), furnace=PAPER)
    fit_data, hold, tail_of, _ = split([e.between(0, 1200) for e in case.fit],
                                       [e.between(0, 1200) for e in case.holdout])
    whole = run_task(Task((), {}, fit_data, hold, tail_of, None, 5))
    parts = [run_task(t) for t in baseline_tasks(fit_data, hold, tail_of, 5)]
    assert len(parts) == BASELINE_RUNS and len({p.sse_fit for p in parts}) > 1
    best = min(parts, key=lambda c: c.sse_fit)
    assert best.params == whole.params and best.sse_fit == whole.sse_fit
    assert best.rmse_holdout_c == whole.rmse_holdout_c and best.ci95 == whole.ci95


@pytest.mark.parametrize("label, k, settled", [("none", 1, True), ("wall_storage", 4, False)])
def test_the_baselines_third_search_runs_only_where_the_first_two_end_apart(label, k, settled):
    """Two searches from different seeds that end in one minimum leave nothing for the
    third: on the control's draw it ends no lower, and the diagnosis does not run it (its
    baseline stage stops at the share of two searches in three). Where the first two end
    apart (a wall's draw whose second search stops in a side valley), the third is
    searched and the stage runs to its end."""
    from furnace_model.diagnosis.fitting import SAME_END, baseline_settled, baseline_tasks
    from furnace_model.diagnosis.selfcheck import selfcheck_case

    case = selfcheck_case(label, k, furnace=PAPER)
    fit_data, hold, tail_of, _ = split(case.fit, case.holdout)
    runs = [run_task(t) for t in baseline_tasks(fit_data, hold, tail_of, 0)]
    assert len(runs) == 3 and baseline_settled(runs[:2]) is settled
    first = min(c.sse_fit for c in runs[:2])
    if settled:
        assert runs[2].sse_fit >= first * (1 - SAME_END)
    else:
        assert max(c.sse_fit for c in runs[:2]) > first * 1.01

    class Past(Exception):
        """The diagnosis has left its baseline stage."""

    heard = []

    def progress(stage: str, fraction: float) -> None:
        if stage != "baseline":
            raise Past
        heard.append(fraction)

    with pytest.raises(Past):
        diagnose(case.fit, case.holdout, progress=progress)
    assert heard[-1] == pytest.approx(0.1 * 2 / 3 if settled else 0.1)


def test_a_baseline_that_no_seed_moves_is_searched_once():
    """On a network of many zones the baseline is polished from the equations' least
    squares: no seed moves it, so the diagnosis runs one search, not BASELINE_RUNS alike,
    and a fit asked for several runs makes one, the same fit."""
    from furnace_model.diagnosis.fitting import baseline_tasks
    from furnace_model.identification.fit import fit
    from furnace_model.shipped import FURNACES, shipped
    from furnace_model.simulation.furnacefile import load_furnace

    six = load_furnace(shipped(f"{FURNACES}/six-zone.yaml"))
    case = draw_case(None, case_rng(0, "none", 0), furnace=six)
    fit_data, hold, tail_of, _ = split([e.between(0, 600) for e in case.fit],
                                       [e.between(0, 600) for e in case.holdout])
    assert len(baseline_tasks(fit_data, hold, tail_of, 5)) == 1
    one, three = (fit(fit_data, runs=r, seed=5, zone_offsets=True, profile=False)
                  for r in (1, 3))
    assert len(three.runs) == 1 and three.params == one.params and three.sse == one.sse
    paper = draw_case(None, case_rng(0, "none", 0), furnace=PAPER)
    fd, ho, to, _ = split(paper.fit, paper.holdout)
    assert len(baseline_tasks(fd, ho, to, 5)) > 1
