"""Partial explanations: kept effects that earn credit but leave the held-out error off the
noise floor are named, each with the share of the gap it closes, beside what remains and
where it lies; a gap no candidate touches stays unexplained.

The known-truth cases are the selfcheck's wall draw with a disturbance no candidate can
represent (tests/wandering.py): the held-out heat-up's ambient wanders slowly while the
record says it is constant, a slow random heat input into the preheating zone."""

from __future__ import annotations

import dataclasses
import json
from types import SimpleNamespace

import pytest
from wandering import wandering_holdout

from furnace_model.cli.diagnose import summary
from furnace_model.diagnosis import CandidateResult, credited, diagnose, judge
from furnace_model.diagnosis.cases import Case, case_rng, draw_case
from furnace_model.diagnosis.selfcheck import Outcome, judge_case, summarize, table
from furnace_model.simulation.furnace import PAPER


@pytest.fixture(scope="module")
def wall_and_wander():
    """Selfcheck wall draw 2 (a wall behind every zone, the baseline 7.2/5.5/2.9 °C held
    out against a floor of 1.1) with the wandering ambient in its held-out heat-up."""
    case = draw_case("wall_storage", case_rng(0, "wall_storage", 2), furnace=PAPER)
    case = dataclasses.replace(case, holdout=[wandering_holdout(case, "wall_storage")])
    return case, diagnose(case.fit, case.holdout, effects=("wall_storage",))


def test_a_wall_that_closes_most_of_the_gap_but_not_to_the_floor_is_named_in_part(
        wall_and_wander):
    case, d = wall_and_wander
    v = d.verdict
    assert v.status == "explained_in_part", v.sentence
    assert v.effects == ["wall_storage"]
    kept = d.best()
    assert kept is d.kept and kept.effects == ("wall_storage",) and credited(kept)
    assert 50.0 <= v.gap_closed_pct < 100.0 and v.shrink_pct > 0
    assert [p.effect for p in v.parts] == ["wall_storage"]
    assert v.parts[0].gap_closed_pct == pytest.approx(v.gap_closed_pct)
    # what remains: the preheating zone, where the wander enters, off its floor
    rest = v.remaining
    assert rest.rmse_holdout_c["preheat"] > 2 * rest.noise_floor_c["preheat"]
    assert rest.where_from == "kept" and rest.where[0].zone == "preheat"
    assert rest.where[0].experiment == case.holdout[0].name
    # the sentence: which effect, how much of the gap, what remains and where
    assert "in part" in v.sentence and "(wall_storage)" in v.sentence
    assert f"closes {v.gap_closed_pct:.0f}% of the held-out gap" in v.sentence
    assert "What remains is not explained" in v.sentence
    assert "preheating zone" in v.sentence.split("What remains")[1]
    # a partial explanation of the truth's effect, closing over half the gap, is correct
    assert judge_case(case, d) == (True, False, "")


def test_a_partial_verdict_in_the_json_and_the_summary(wall_and_wander):
    _, d = wall_and_wander
    doc = json.loads(json.dumps(d.to_json(), allow_nan=False))
    v = doc["verdict"]
    assert v["status"] == "explained_in_part" and v["effects"] == ["wall_storage"]
    assert set(v) >= {"shrink_pct", "gap_closed_pct", "parts", "remaining", "sentence"}
    assert [p["effect"] for p in v["parts"]] == ["wall_storage"]
    assert set(v["parts"][0]) >= {"effect", "gap_closed_pct", "shrink_pct"}
    assert sum(p["gap_closed_pct"] for p in v["parts"]) == pytest.approx(v["gap_closed_pct"])
    assert sum(p["shrink_pct"] for p in v["parts"]) == pytest.approx(v["shrink_pct"])
    rest = v["remaining"]
    assert set(rest) >= {"rmse_holdout_c", "noise_floor_c", "where"}
    assert set(rest["rmse_holdout_c"]) == set(rest["noise_floor_c"]) == set(PAPER.zones)
    assert set(rest["where"][0]) == set(doc["where"][0])  # the same shape as `where`
    text = summary(d)
    assert text.startswith("Verdict: explained_in_part (wall_storage)")
    assert "| wall_storage | " in text.split("The kept effects")[1]
    assert "Where it lies, on the kept model's held-out residual:" in text


def test_a_gap_no_candidate_touches_stays_unexplained():
    """The wandering ambient alone, on a furnace without a wall: the wall candidate cannot
    follow it and earns no credit, so nothing is named."""
    case = draw_case(None, case_rng(0, "wall_storage", 2), furnace=PAPER)
    case = dataclasses.replace(case, holdout=[wandering_holdout(case, None)])
    d = diagnose(case.fit, case.holdout, effects=("wall_storage",))
    assert d.verdict.status == "unexplained", d.verdict.sentence
    assert d.verdict.effects == [] and not any(credited(c) for c in d.candidates)
    assert "parts" not in d.to_json()["verdict"]


def _cand(effects, rmse, closed, shrink):
    return CandidateResult(tuple(effects), {}, {}, dict(rmse), dict(rmse), shrink_pct=shrink,
                           delta_bic=-100.0, identifiable=True, gap_closed_pct=closed)


def test_the_parts_of_two_kept_effects_add_up_to_the_whole():
    """Each step's share is of the baseline's gap, so that the steps add up; the sentence
    names both, the first's share and the second's further share."""
    floor = {z: 1.0 for z in PAPER.zones}
    base = _cand((), {"soak": 10.0, "heat": 8.0, "preheat": 4.0}, 0.0, 0.0)
    one = _cand(("wall_storage",), {"soak": 4.0, "heat": 3.0, "preheat": 4.0}, 0.0, 0.0)
    two = _cand(("wall_storage", "dead_time"), {"soak": 2.0, "heat": 2.0, "preheat": 3.0},
                0.0, 0.0)
    rb = base.rmse_holdout_pooled()
    excess = rb ** 2 - 1.0
    for c in (one, two):
        c.gap_closed_pct = 100 * (rb ** 2 - c.rmse_holdout_pooled() ** 2) / excess
        c.shrink_pct = 100 * (1 - c.rmse_holdout_pooled() / rb)
    near = {z: 1.5 for z in PAPER.zones}
    v = judge(base, two, [two, one], floor, near, PAPER.zones, [], furnace=PAPER,
              steps=[one, two])
    assert v.status == "explained_in_part" and v.effects == ["wall_storage", "dead_time"]
    assert [p.effect for p in v.parts] == ["wall_storage", "dead_time"]
    assert sum(p.gap_closed_pct for p in v.parts) == pytest.approx(two.gap_closed_pct)
    assert sum(p.shrink_pct for p in v.parts) == pytest.approx(two.shrink_pct)
    assert v.parts[0].gap_closed_pct == pytest.approx(one.gap_closed_pct)
    assert (f"Adding wall_storage closes {v.parts[0].gap_closed_pct:.0f}% of the held-out gap "
            f"above the noise floor, dead_time a further {v.parts[1].gap_closed_pct:.0f}%"
            in v.sentence)
    # no place found on the kept model's residual: the baseline's, said as such
    assert v.remaining.where_from == "baseline"
    # near the floor, the same kept effects explain it, as they always have
    near_all = {z: 3.5 for z in PAPER.zones}
    assert judge(base, two, [two], floor, near_all, PAPER.zones, [], furnace=PAPER,
                 steps=[one, two]).status == "explained"
    # a kept set without credit explains nothing
    weak = dataclasses.replace(two, identifiable=False)
    assert judge(base, weak, [weak], floor, near, PAPER.zones, [], furnace=PAPER).status \
        == "unexplained"


def test_an_explanation_held_by_its_carried_error_says_so():
    """Within the noise limit alone the sentence says the error is down to the noise; held
    only by what the fit's parameters carry, it says that, with the carried figure, and never
    that 1.2 °C is the noise of 0.70."""
    floor = {z: 0.7 for z in PAPER.zones}
    near = {z: 0.9 for z in PAPER.zones}
    base = _cand((), {"soak": 1.0, "heat": 3.3, "preheat": 1.9}, 0.0, 0.0)
    at_noise = _cand(("wall_storage",), {"soak": 0.8, "heat": 0.85, "preheat": 0.8}, 90.0, 60.0)
    v = judge(base, at_noise, [at_noise], floor, near, ("heat",), [], furnace=PAPER)
    assert v.status == "explained"
    assert "down to about the thermocouple noise of 0.70 °C" in v.sentence, v.sentence
    carried = dataclasses.replace(at_noise, rmse_holdout_c={"soak": 0.8, "heat": 1.2,
                                                            "preheat": 0.8},
                                  carried_c={"soak": 0.3, "heat": 2.2, "preheat": 0.4})
    v = judge(base, carried, [carried], floor, near, ("heat",), [], furnace=PAPER)
    assert v.status == "explained"
    assert "noise" in v.sentence and "down to about" not in v.sentence, v.sentence
    assert "parameters' own uncertainty (up to 2.2 °C there)" in v.sentence, v.sentence
    # without the carry the same error is off the floor
    v = judge(base, dataclasses.replace(carried, carried_c={}), [carried], floor, near,
              ("heat",), [], furnace=PAPER)
    assert v.status == "explained_in_part", v.sentence


def _diagnosis(status, effects, closed=80.0):
    verdict = SimpleNamespace(status=status, effects=list(effects), gap_closed_pct=closed,
                              shrink_pct=40.0)
    return SimpleNamespace(verdict=verdict, where=[], gap_limit_c={},
                           baseline=SimpleNamespace(rmse_holdout_carried_c={}))


def test_the_selfcheck_judges_a_partial_verdict_as_it_judges_an_explanation():
    case = Case(fit=[SimpleNamespace(furnace=PAPER)], holdout=[], truth={"wall_storage": {}},
                description="", effects=("wall_storage",))
    assert judge_case(case, _diagnosis("explained_in_part", ["wall_storage"])) == (
        True, False, "")
    assert judge_case(case, _diagnosis("explained_in_part", ["wall_storage"], 40.0))[0] is False
    assert judge_case(case, _diagnosis("explained_in_part", ["dead_time"]))[0] is False
    assert judge_case(case, _diagnosis("explained_in_part",
                                       ["wall_storage", "dead_time"]))[0] is False
    fault = dataclasses.replace(case, truth={"door_open": {"zone": "heat"}},
                                effects=("door_open",))
    assert judge_case(fault, _diagnosis("explained_in_part", ["wall_storage"])) == (
        False, False, "verdict explained_in_part ['wall_storage']")


def test_the_selfcheck_table_counts_partial_verdicts_in_their_own_column():
    def outcome(k, status, correct):
        return Outcome("wall_storage", k, "", status, ["wall_storage"], correct, False, "",
                       50.0 + k, 90.0 + k, 1.0, {})

    outs = ([outcome(k, "explained", True) for k in range(7)]
            + [outcome(k, "explained_in_part", True) for k in range(7, 9)]
            + [outcome(9, "unexplained", False)])
    row = summarize(outs)[0]
    assert row.verdicts == {"no_gap": 0, "explained": 7, "explained_in_part": 2,
                            "unexplained": 1}
    assert row.correct == 9 and row.passed
    text = table([row], outs)
    head = text.splitlines()[0]
    assert "| explained in part |" in head
    cells = [c.strip() for c in text.splitlines()[2].split("|")[1:-1]]
    assert dict(zip([h.strip() for h in head.split("|")[1:-1]], cells, strict=True))[
        "explained in part"] == "2"
