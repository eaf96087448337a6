"""Lone glitched readings in a record (known truth: simulated records with readings put
wrong by hand): found and left out where they are, with nothing else touched, and the
commands that read records say so and fit what is left."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from furnace_model.diagnosis.hourlyroom import ROOM, hourly_room
from furnace_model.glitches import glitches, without_glitches
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def heatup():
    sc = load_scenario(ROOT / "config" / "scenarios" / "paper_exp1.yaml")
    return Plant.from_scenario(sc, seed=1).run_scenario(sc).to_experiment("exp1")


def _with(exp, cells: dict[tuple[int, int], float]):
    tc = exp.tc.copy()
    for (row, col), v in cells.items():
        tc[row, col] = v
    return replace(exp, tc=tc)


def test_a_clean_record_has_none(heatup):
    """Burners switching, ramps and kinks of a heat-up, thermocouple noise and bias: none
    is a lone reading."""
    assert glitches(heatup) == []
    again, said = without_glitches(heatup)
    assert again is heatup and said == []


def test_lone_readings_are_found_where_they_are_and_only_they(heatup):
    """A reading 40 °C high, one at zero (an open junction read as 0), one 300 °C low on
    another thermocouple; two neighbouring readings both high (no longer lone: their
    neighbours disagree) and a reading one noise sd off are not taken."""
    cells = {(500, 0): heatup.tc[500, 0] + 40.0, (1200, 3): 0.0,
             (2500, 5): heatup.tc[2500, 5] - 300.0,
             (1800, 1): heatup.tc[1800, 1] + 40.0, (1801, 1): heatup.tc[1801, 1] + 40.0,
             (2000, 2): heatup.tc[2000, 2] + 1.5}
    bad = _with(heatup, cells)
    found = glitches(bad)
    columns = heatup.furnace.tc_columns
    assert [(g.row, g.column) for g in found] == sorted(
        [(500, columns[0]), (1200, columns[3]), (2500, columns[5])], key=lambda rc: (
            columns.index(rc[1]), rc[0]))
    for g in found:
        assert g.expected == pytest.approx(heatup.tc[g.row, columns.index(g.column)], abs=5.0)
    cleaned, said = without_glitches(bad)
    blank = ~np.isfinite(cleaned.tc) & np.isfinite(bad.tc)
    assert sorted(zip(*np.nonzero(blank), strict=True)) == [(500, 0), (1200, 3), (2500, 5)]
    assert np.array_equal(cleaned.tc[~blank], bad.tc[~blank])  # nothing else touched
    assert len(said) == 1 and "3 lone reading(s) left out" in said[0]
    at = heatup.start_time + pd.Timedelta(minutes=float(heatup.t_min[1200]))
    assert f"{columns[3]} at {at:%Y-%m-%d %H:%M}Z (0 °C where" in said[0], said


def test_a_logger_that_rounds_to_whole_degrees_is_not_glitched():
    """A quiet room logged in whole degrees: most readings equal their neighbours, so the
    typical departure is nil; a degree's step is the logger's quantum, not a glitch."""
    room = hourly_room(1, ())
    tc = np.round(room.tc)
    tc[100] = tc[99] + 1.0
    assert glitches(replace(room, tc=tc)) == []


@pytest.mark.parametrize("command", ["fit", "diagnose"])
def test_a_command_leaves_a_glitch_out_and_says_where(tmp_path, command):
    """A room with a wall, hourly over two weeks, one reading logged at 95 °C: left out and
    named with its time, and the diagnosis names the wall (with the reading in, the fit
    bends to it and no candidate explains the gap)."""
    furnace = tmp_path / "room.yaml"
    furnace.write_text(ROOM)
    frame = hourly_room(1, ("wall_storage",), days=14).to_frame()
    frame.loc[120, "tc_room_1"] = 95.0
    csv = tmp_path / "room.csv"
    frame.to_csv(csv, index=False)
    out = tmp_path / "out.json"
    r = subprocess.run([sys.executable, "-m", "furnace_model.cli", command, str(csv),
                        "--furnace", str(furnace), "--json", str(out),
                        *(["--quiet"] if command == "diagnose" else [])],
                       capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert (f"furnace-model {command}: warning: room: 1 lone reading(s) left out" in r.stderr
            and "tc_room_1 at 2026-01-10 00:00Z (95 °C" in r.stderr), r.stderr
    # and in the JSON: a fit's first warning, a diagnosis's `read`
    said = json.loads(out.read_text())["warnings" if command == "fit" else "read"]
    assert said[0].startswith("room: 1 lone reading(s) left out"), said
    if command == "diagnose":
        assert r.stdout.startswith("Verdict: explained (wall_storage)"), r.stdout[:400]


def test_a_refit_window_leaves_a_glitch_out_and_says_so():
    """The daemon's windows of a week of burner steps, one soak reading logged 60 °C high
    for one poll: each window that holds it leaves it out, says so in its message, and
    fits as the windows of the same run without it do."""
    from refit_helpers import assert_fits_alike, scenario, simulate, window_fits

    from furnace_daq.daqconfig import RefitConfig

    s = scenario("week_steps", duration_min=9 * 60)
    config = RefitConfig(period_s=3600.0, window_s=6 * 3600.0, method="polish")
    out = {}
    for kind in ("clean", "glitched"):
        run = simulate(s)
        if kind == "glitched":
            run.tc[300, 0] += 60.0
        out[kind] = window_fits(run, config)
    holding = [m for m in out["glitched"] if "lone reading(s) left out" in m["detail"]]
    assert holding and all("tc_soak_1 at 2026-03-02 05:00Z" in m["detail"] for m in holding)
    assert_fits_alike(out["clean"], out["glitched"])
