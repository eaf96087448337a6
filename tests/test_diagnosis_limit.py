"""A time limit's cuts as a record: given back to diagnose in place of the clock, they cut
the same fits and no others, and the verdict is the limited run's on any host."""

from __future__ import annotations

import numpy as np

from furnace_model.diagnosis import diagnose
from furnace_model.diagnosis.cases import draw_case
from furnace_model.simulation.furnace import PAPER

EFFECTS = ("zone_burners", "sensor_lag", "dead_time")


def test_a_limited_diagnosis_repeats_from_its_record_of_cuts():
    case = draw_case("zone_burners", np.random.default_rng(21), furnace=PAPER)
    # a limit that lets the baseline through and cuts every candidate: the record names
    # each cut fit, and nothing the clock decided is left out of it
    limited = diagnose(case.fit, case.holdout, effects=EFFECTS, time_limit_s=0.001)
    assert limited.cut and set(limited.untried) == set(EFFECTS)
    again = diagnose(case.fit, case.holdout, effects=EFFECTS, cut=limited.cut)
    assert again.cut == limited.cut and again.untried == limited.untried
    assert again.time_limit_s is None
    assert again.verdict.status == limited.verdict.status
    assert again.verdict.effects == limited.verdict.effects
