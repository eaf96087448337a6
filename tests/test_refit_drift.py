"""Drift events: a fuel switch (natural gas to biogas, heat per burner -20%) shows up as a
drift of f within two refit periods; a week of the same plant without it raises none."""

from __future__ import annotations

import pandas as pd
import pytest
from refit_helpers import scenario, simulate, through_pipeline

from furnace_daq.daqconfig import RefitConfig

HOUR = 3600.0
CONFIG = RefitConfig(period_s=6 * HOUR, window_s=6 * HOUR)


def test_fuel_switch_raises_one_drift_event_on_f_within_two_periods():
    s = scenario("fuel_switch")
    switch = s.start_time + pd.Timedelta(minutes=s.effect_values["t_fuel"])
    params, events = through_pipeline(simulate(s), CONFIG)
    assert len(params) == 7 * 4
    drift = [e for e in events if e["kind"] == "drift"]
    assert [e["parameter"] for e in drift] == ["f"], [e["detail"] for e in drift]
    event = drift[0]
    raised = pd.Timestamp(event["window_end"])
    assert switch < raised <= switch + 2 * pd.Timedelta(seconds=CONFIG.period_s)
    assert abs(event["new"] / event["old"] - 0.8) < 0.03  # the fuel's ratio
    assert event["relative_change"] < -0.15
    lo, hi = event["old_ci95"]
    assert not lo <= event["new"] <= hi
    assert event["parameters"] == {"f": event["new"]}
    before = [m for m in params if pd.Timestamp(m["window_end"]) <= switch]
    assert before and all(abs(m["f"] / s.params["f"] - 1) < 0.03 for m in before
                          if m["status"] == "ok")


def test_a_steady_week_raises_no_drift_event():
    s = scenario("week_steps")
    params, events = through_pipeline(simulate(s), CONFIG)
    assert len(params) == 7 * 4 and sum(m["status"] == "ok" for m in params) >= 26
    assert events == [], [e["detail"] for e in events]


@pytest.mark.slow
def test_default_windows_raise_two_events_on_f_not_a_swarm():
    """24-h windows every 15 min: the switch is inside the window for a day of compromise
    fits; after the first event those are not judged, the next event compares a window
    wholly after the switch."""
    s = scenario("fuel_switch", duration_min=3.5 * 1440)
    switch = s.start_time + pd.Timedelta(minutes=s.effect_values["t_fuel"])
    params, events = through_pipeline(simulate(s), RefitConfig(), timeout=600)
    assert [e["parameter"] for e in events] == ["f", "f"], [e["detail"] for e in events]
    first, second = (pd.Timestamp(e["window_end"]) for e in events)
    assert switch < first <= switch + pd.Timedelta(hours=3)
    assert second >= first + pd.Timedelta(hours=24)
    assert all(e["relative_change"] < 0 for e in events)
    assert abs(events[1]["new"] / events[0]["old"] - 0.8) < 0.03
