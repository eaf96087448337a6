"""Readings stuck at one value (known truth: simulated records with a run of one reading repeated
by hand): found where they are, left out after their first, and named; records whose
readings repeat because of their rounding and their pace are left alone."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from furnace_model.diagnosis.cases import draw_closed_loop_case
from furnace_model.diagnosis.hourlyroom import hourly_room
from furnace_model.stuckreadings import MIN_STUCK_REPEATS, stuck_readings, without_stuck

ROOT = Path(__file__).resolve().parents[1]
ONE_ROOM = """
name: office
zones:
  - {name: room, burners: 1, thermocouples: 1, heat: {kind: rate, unit: kW, max: 12}}
"""


def _rounded(exp, quantum: float):
    return replace(exp, tc=np.round(exp.tc / quantum) * quantum)


def _held(exp, column: int, first: int, rows: int):
    tc = exp.tc.copy()
    tc[first + 1:first + rows, column] = tc[first, column]
    return replace(exp, tc=tc)


def test_a_held_run_is_found_where_it_is_and_only_its_repeats_left_out():
    """Two days of an hourly room logged to a tenth of a degree, its reading held from row
    300: the run's first reading (the last the sensor gave) is kept, the 47 after it
    blanked, nothing else touched; a run one row short of `MIN_STUCK_REPEATS` is left."""
    room = _rounded(hourly_room(1, ("wall_storage",)), 0.1)
    bad = _held(_held(room, 0, 300, 48), 0, 500, MIN_STUCK_REPEATS)
    found = stuck_readings(bad)
    assert [(h.column, h.first, h.last) for h in found] == [("tc_room_1", 300, 347)]
    cleaned, said = without_stuck(bad)
    blank = ~np.isfinite(cleaned.tc) & np.isfinite(bad.tc)
    assert np.flatnonzero(blank[:, 0]).tolist() == list(range(301, 348))
    assert np.array_equal(cleaned.tc[~blank], bad.tc[~blank])
    assert len(said) == 1 and "tc_room_1 " in said[0] and "for 48 rows from" in said[0]


@pytest.mark.parametrize("quantum", [None, 0.1, 0.5, 1.0])
def test_readings_that_repeat_by_their_rounding_and_pace_are_not_held(quantum):
    """A room logged every minute to a whole degree stays on one value for hours (it moves
    slowly), a furnace held at its setpoints repeats its readings at a degree's rounding:
    neither is a logger's holding."""
    records = [hourly_room(2, ("wall_storage", "sensor_lag"), 14, sample_min=1),
               hourly_room(3, ("wall_storage",))]
    records += draw_closed_loop_case("sensor_drift", np.random.default_rng(5)).fit
    for exp in records:
        assert stuck_readings(exp if quantum is None else _rounded(exp, quantum)) == []


def test_fit_leaves_a_held_run_out_and_says_where(tmp_path):
    """Through the command, as a file from a historian that filled a dead sensor's cells:
    the warning names the thermocouple, the value, the rows and the times, and the fit goes
    on with what is left."""
    furnace = tmp_path / "room.yaml"
    furnace.write_text(ONE_ROOM)
    frame = _held(_rounded(hourly_room(1, ("wall_storage",), 14), 0.1), 0, 120, 36) \
        .to_frame().drop(columns=["solar"])
    csv = tmp_path / "room.csv"
    frame.to_csv(csv, index=False)
    r = subprocess.run([sys.executable, "-m", "furnace_model.cli", "fit", str(csv),
                        "--furnace", str(furnace)],
                       capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    value = frame["tc_room_1"].iloc[120]
    assert ("furnace-model fit: warning: room: 1 run(s) of a reading repeated unchanged"
            in r.stderr and f"tc_room_1 {value:g} °C for 36 rows from 2026-01-10 00:00Z to "
            "2026-01-11 11:00Z" in r.stderr), r.stderr


def test_a_refit_window_leaves_a_frozen_reading_out_and_says_so():
    """The daemon's windows of a week of burner steps, the first soak thermocouple frozen
    for an hour and a half: each window that holds the run leaves it out after its first
    reading, says so in its message, and fits as the windows of the same run without it."""
    from refit_helpers import assert_fits_alike, scenario, simulate, window_fits

    from furnace_daq.daqconfig import RefitConfig

    s = scenario("week_steps", duration_min=9 * 60)
    config = RefitConfig(period_s=3600.0, window_s=6 * 3600.0, method="polish")
    out = {}
    for kind in ("clean", "frozen"):
        run = simulate(s)
        if kind == "frozen":
            run.tc[301:391, 0] = run.tc[300, 0]
        out[kind] = window_fits(run, config)
    holding = [m for m in out["frozen"] if "repeated unchanged" in m["detail"]]
    assert holding and all("tc_soak_1 " in m["detail"] for m in holding)
    assert_fits_alike(out["clean"], out["frozen"])
