"""Locating a model's error: noise floor from thermocouple pairs, error spans, sensor faults,
whiteness and input cross-correlation tests. Known-truth arrays, no fitting."""

from __future__ import annotations

import numpy as np
import pytest

from furnace_model.diagnosis import Located, locate, where_lines
from furnace_model.experiment import Experiment
from furnace_model.identification.noisefloor import record_floor
from furnace_model.identification.residuals import (
    error_spans,
    regime,
    residual_tests,
    sensor_faults,
    sudden_change,
)
from furnace_model.simulation.furnace import PAPER


def _experiment(rng, n=3000, noise=(1.5, 1.0, 2.0), truth=None, burners=None) -> Experiment:
    t = np.arange(n, dtype=float)
    if truth is None:
        truth = np.column_stack([300 + 0.2 * t, 250 + 0.15 * t, 100 + 0.05 * t])
    tc = np.empty((n, 6))
    for w in range(3):
        for k in range(2):
            tc[:, 2 * w + k] = truth[:, w] + rng.normal(0, noise[w], n) + rng.normal(0, 0.5)
    if burners is None:
        burners = np.zeros((n, 3), dtype=int)
        burners[:, 0] = 4
        burners[n // 2:, 0] = 8
        burners[2 * n // 3:, 1] = 3
    return Experiment("exp", t, tc, burners, np.full(n, 30.0), furnace=PAPER)


def _unit_floors(exps: list[Experiment]) -> list:
    """Each record's floor set to 1 degC of white noise, as the residuals drawn here have."""
    floors = [record_floor(e) for e in exps]
    for f in floors:
        for zf in f.zones.values():
            zf.floor_c, zf.lag1 = 1.0, 0.0
    return floors


def test_error_span_found_where_the_residual_is_large():
    rng = np.random.default_rng(3)
    e = _experiment(rng)
    r = rng.normal(0, 1.0, (len(e), 3))
    r[1200:1500, 1] += 8.0 * np.sin(np.linspace(0, np.pi, 300))
    spans = error_spans([e], [r], [{"soak": 1.0, "heat": 1.0, "preheat": 1.0}])
    top = spans[0]
    assert top.zone == "heat"
    assert 1180 <= top.i0 <= 1260 and 1440 <= top.i1 <= 1520
    assert all(s.excess < 0.05 * top.excess for s in spans[1:])


def test_error_throughout_a_record_is_one_entry_and_a_local_one_keeps_its_stretch():
    """The heating zone errs through the whole of the first record (a slow swing of 6 °C,
    crossing zero every 250 minutes); the soaking zone of the second errs for 300 minutes
    only. The first is one entry covering the record, the second its own stretch."""
    rng = np.random.default_rng(6)
    exps = [_experiment(rng), _experiment(rng)]
    n = len(exps[0])
    floors = _unit_floors(exps)
    r0, r1 = rng.normal(0, 1.0, (n, 3)), rng.normal(0, 1.0, (n, 3))
    r0[:, 1] += 6.0 * np.sin(2 * np.pi * np.arange(n) / 500.0)
    r1[1200:1500, 0] += 8.0 * np.sin(np.linspace(0, np.pi, 300))
    spans = error_spans(exps, [r0, r1], [f.floor_c for f in floors])
    assert [(s.zone, s.experiment) for s in spans] == [("heat", 0), ("soak", 1)], spans
    whole, local = spans
    assert whole.throughout and (whole.i0, whole.i1) == (0, n)
    assert not local.throughout and 1180 <= local.i0 <= 1260 and 1440 <= local.i1 <= 1520
    where = [w for w in locate(exps, [r0, r1], floors, []) if w.kind != "change"]
    assert [(w.zone, w.kind) for w in where] == [("heat", "throughout"), ("soak", "span")]
    assert (where[0].start_min, where[0].end_min) == (0.0, float(n - 1))
    assert where[0].share_of_error > 0.9


def test_zones_erring_throughout_one_record_are_said_once():
    """Three zones erring throughout exp2 make one line, zones and shares in order, with
    the record's burners said once and each zone's temperature band; the verdict says it so."""
    def whole(zone, share, band):
        return Located(zone, None, "exp2", 0.0, 3473.0, None, None, share,
                       f"soaking-zone burners firing; burners 3 -> 5 at 882 min; {band} °C",
                       "throughout")
    where = [whole("soak", 0.92, "0-1400"),
             Located("heat", "heat_1", "exp1", 100.0, 400.0, None, None, 0.3,
                     "heat_1 drifts +4.0 °C from its partner", "sensor"),
             whole("heat", 0.93, "0-1300"), whole("preheat", 0.91, "0-700")]
    lines = where_lines(where, PAPER.zones)
    assert [(w.who, w.kind) for w in lines] == [
        ("soaking, heating and preheating zones", "throughout"), ("thermocouple heat_1", "sensor")]
    assert lines[0].share == "92%, 93% and 91%" and lines[0].span == "0-3473 min"
    assert lines[0].regime == ("soaking-zone burners firing; burners 3 -> 5 at 882 min; "
                               "0-1400, 0-1300 and 0-700 °C")
    assert lines[1].span == "100-400 min" and lines[1].share == "30%"


def test_sudden_change_points_at_the_zone_a_disturbance_enters():
    """A heat loss entering the heating zone at minute 2000: that zone drops fast, the
    soaking zone (larger capacity) follows slowly and ends with more squared error; the
    sharpest step is found in the heating zone at the minute. Noise alone gives none."""
    rng = np.random.default_rng(5)
    e = _experiment(rng)
    floor = _unit_floors([e])
    r = rng.normal(0, 1.0, (len(e), 3))
    assert sudden_change([e], [r], floor) is None
    t = np.arange(len(e), dtype=float) - 2000.0
    on = t >= 0
    r[on, 1] -= 30.0 * (1 - np.exp(-t[on] / 5.0))
    r[on, 0] -= 60.0 * (1 - np.exp(-t[on] / 400.0))
    assert np.sum(r[:, 0] ** 2) > np.sum(r[:, 1] ** 2)  # size alone would blame the soak zone
    change = sudden_change([e], [r], floor)
    assert change is not None and change.zone == "heat" and change.size_c < -15
    assert change.i0 <= 2000 < change.i1 and change.i1 - change.i0 == 30


def test_regime_words():
    rng = np.random.default_rng(4)
    e = _experiment(rng)
    words = regime(e, 2100, 2900, "heat")
    assert "soaking and heating-zone burners firing" in words
    assert "11 burners on" in words and "->" not in words
    assert words.split("; ")[-1].endswith("00 °C")
    assert "burners 4 -> 8 at 1500 min" in regime(e, 1400, 1600, "soak")


@pytest.mark.parametrize("culprit", [2, 3])
def test_drifting_thermocouple_is_named(culprit):
    rng = np.random.default_rng(5)
    e = _experiment(rng)
    t = e.t_min
    e.tc[:, culprit] += 0.02 * np.maximum(t - 1000, 0.0)
    truth_pred = np.column_stack([300 + 0.2 * t, 250 + 0.15 * t, 100 + 0.05 * t])
    faults = sensor_faults([e], [truth_pred], [{z: f.tc_sd_c for z, f in record_floor(e).zones.items()}])
    assert [f.sensor for f in faults] == [("heat_1", "heat_2")[culprit - 2]]
    assert faults[0].kind == "drift"
    assert 800 <= t[faults[0].i0] <= 1200


def test_episodes_of_low_readings_are_named_and_a_clean_pair_is_not():
    rng = np.random.default_rng(6)
    e = _experiment(rng)
    for lo in (500, 1300, 2200):
        e.tc[lo:lo + 20, 1] -= 30.0  # soak_2 reads low at times
    t = e.t_min
    truth_pred = np.column_stack([300 + 0.2 * t, 250 + 0.15 * t, 100 + 0.05 * t])
    faults = sensor_faults([e], [truth_pred], [{z: f.tc_sd_c for z, f in record_floor(e).zones.items()}])
    assert [(f.sensor, f.kind) for f in faults] == [("soak_2", "episodes")]
    assert faults[0].size_c == pytest.approx(30.0, rel=0.2)


def test_whiteness_and_input_correlation():
    rng = np.random.default_rng(7)
    e = _experiment(rng)
    white = rng.normal(0, 1.0, (len(e), 3))
    out = residual_tests([e], [white])
    assert all(out[z]["white"] for z in out)
    assert all(x["independent"] for z in out for x in out[z]["xcorr"].values())
    # a residual that answers the heating-zone burner step: coloured and tied to the input
    resp = white.copy()
    step = np.zeros(len(e))
    k = 2 * len(e) // 3
    step[k:] = 10.0 * np.exp(-np.arange(len(e) - k) / 30.0)
    resp[:, 1] += step
    out = residual_tests([e], [resp])
    assert not out["heat"]["white"]
    assert not out["heat"]["xcorr"]["d_burners_heat"]["independent"]
    assert out["heat"]["xcorr"]["d_burners_heat"]["at_lag"] >= 0


def test_a_change_that_holds_none_of_the_error_is_not_listed_first():
    """A half-hour spike of the soaking zone's residual in the first record is the sharpest
    step anywhere, but the zone's error lies in the second record (a slow swing of 20 °C):
    the spike holds 0% of it and is listed after the stretches, which come by share."""
    rng = np.random.default_rng(8)
    exps = [_experiment(rng), _experiment(rng)]
    n = len(exps[0])
    floors = _unit_floors(exps)
    r0, r1 = rng.normal(0, 1.0, (n, 3)), rng.normal(0, 1.0, (n, 3))
    r0[1500:1530, 0] += 8.0
    r1[:, 0] += 20.0 * np.sin(2 * np.pi * np.arange(n) / 500.0)
    r1[1000:1600, 1] += 5.0 * np.sin(np.linspace(0, np.pi, 600))
    where = locate(exps, [r0, r1], floors, [])
    change = next(w for w in where if w.kind == "change")
    assert change.zone == "soak" and round(100 * change.share_of_error) == 0
    assert where[0] is not change and round(100 * where[0].share_of_error) > 0
    shares = [w.share_of_error for w in where]
    assert shares == sorted(shares, reverse=True)


def test_a_change_spans_the_error_it_opens_and_leads():
    """A loss entering the heating zone at minute 2000 (as above): the sharpest step leads
    the list, and its entry runs on to the end of the stretch of error the step opens, so
    that its share is that error's, not the half hour's."""
    rng = np.random.default_rng(5)
    e = _experiment(rng)
    floors = _unit_floors([e])
    r = rng.normal(0, 1.0, (len(e), 3))
    t = np.arange(len(e), dtype=float) - 2000.0
    on = t >= 0
    r[on, 1] -= 30.0 * (1 - np.exp(-t[on] / 5.0))
    r[on, 0] -= 60.0 * (1 - np.exp(-t[on] / 400.0))
    where = locate([e], [r], floors, [])
    first = where[0]
    assert (first.kind, first.zone) == ("change", "heat")
    assert first.start_min <= 2000 and first.end_min == float(len(e) - 1)
    assert first.share_of_error > 0.9
    assert "the sharpest change in any zone: -" in first.regime
    assert [w.share_of_error for w in where[1:]] == sorted(
        (w.share_of_error for w in where[1:]), reverse=True)
