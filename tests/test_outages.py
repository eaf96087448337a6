"""An outage in the readings (a gateway that read nothing for most of an hour, a record with
missing days): the inputs in it are unknown, so the online refit fits a window from the
first reading after it, and a fit of a record says where it holds inputs across one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from refit_helpers import scenario, simulate

from furnace_daq.daqconfig import RefitConfig, parse_config
from furnace_daq.logmeta import plain, refit_config
from furnace_daq.plantlog import run_messages
from furnace_daq.refit import RefitChain, WindowCutter
from furnace_model.config import Node
from furnace_model.errors import ConfigError
from furnace_model.experiment import Experiment, outage_words
from furnace_model.identification.fit import fit
from furnace_model.simulation.furnace import PAPER

ROOT = Path(__file__).resolve().parents[1]
HOUR = 3600.0
NOISE_C = 1.0  # the scenario's thermocouple noise, about which each zone mean's RMSE lies


def windows_of(run, config: RefitConfig, hole_min: tuple[float, float], start_ns: int):
    """The refit messages of a run whose readings and burner states in `hole_min` were
    never logged, fitted in order in this process."""
    lo, hi = (start_ns + int(m * 60e9) for m in hole_min)
    cutter, chain = WindowCutter(config, furnace=PAPER), RefitChain(config, furnace=PAPER)
    out = []
    for topic, msg, t in run_messages(run):
        if lo <= t < hi:
            continue
        out += [chain.process(w)[0].to_json() for w in cutter.feed(topic, msg, t)]
    return out


def test_a_window_across_an_outage_is_fitted_from_the_first_reading_after_it():
    """The burners went from 5 to 9 at minute 285, inside a 50-minute outage: held at 5
    across it, the windows that hold it miss by several times the noise and move a and f;
    fitted from the outage's end they are at the noise."""
    s = scenario("week_steps", duration_min=9 * 60)
    run = simulate(s)
    config = RefitConfig(period_s=HOUR, window_s=8 * HOUR, method="polish")
    hole = (260.0, 310.0)
    across = [m for m in windows_of(run, RefitConfig(**{**plain(config), "max_outage_s": 0.0,
                                                        "state_dir": config.state_dir}),
                                    hole, s.start_time.value) if m["status"] == "ok"]
    cut = windows_of(run, config, hole, s.start_time.value)
    after = [m for m in cut if m["status"] == "ok"]
    assert [m["window_end"] for m in after] == [m["window_end"] for m in across] != []
    assert all(max(m["rmse_c"].values()) > 3 * NOISE_C for m in across), \
        [m["rmse_c"] for m in across]
    for m in after:
        assert max(m["rmse_c"].values()) < 1.3 * NOISE_C, m["rmse_c"]
        assert m["detail"].startswith("only the rows after the outage from "
                                      "2026-03-02T04:19:00.000Z to 2026-03-02T05:10:00.000Z "
                                      "fitted (no reading for 51 min"), m["detail"]
        # the rows from the outage's end to the window's
        end_min = (np.datetime64(m["window_end"][:-1]) - np.datetime64("2026-03-02T05:10")) \
            / np.timedelta64(1, "m")
        assert m["n_samples"] == end_min
    # the windows that end before enough rows follow it say so
    short = [m["detail"] for m in cut if m["status"] == "insufficient_excitation"
             and m["window_end"] > "2026-03-02T05:10"]
    assert short and all(d.endswith("; only the rows after the outage from 2026-03-02T04:19:"
                                    "00.000Z to 2026-03-02T05:10:00.000Z count (no reading for "
                                    "51 min: the burners' states in it are unknown)")
                         for d in short), short


def test_a_record_with_an_outage_is_fitted_with_a_warning_that_names_it():
    s = scenario("paper_exp1")
    run = simulate(s)
    keep = (run.t_min < 1200) | (run.t_min >= 1300)
    exp = Experiment("exp1", run.t_min[keep], run.tc[keep], run.burners[keep],
                     np.full(keep.sum(), s.t_air_c), s.start_time, furnace=PAPER)
    assert exp.outages() == [(1199.0, 1300.0)]
    assert exp.outages(longest_min=200.0) == []
    (words,) = outage_words(exp)
    assert words.startswith("exp1: no rows for 1.7 h from 2026-03-03 01:59Z") and "fit the parts" in words
    res = fit([exp], seed=0, profile=False)
    assert words in res.warnings
    whole = Experiment("exp1", run.t_min, run.tc, run.burners, np.full(run.t_min.size,
                       s.t_air_c), s.start_time, furnace=PAPER)
    assert whole.outages() == [] and outage_words(whole) == []


def parse(refit: dict) -> RefitConfig:
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["refit"].update(refit)
    return parse_config(Node(doc, "daq.yaml")).refit


def test_the_outage_setting_is_checked_recorded_and_off_for_older_logs():
    assert parse({}).outage_ns == int(5 * 60e9)  # five steps of the default 60 s
    assert parse({"step_s": 120, "period_s": 1200}).outage_ns == int(10 * 60e9)
    assert parse({"max_outage_s": 0}).outage_ns is None
    assert parse({"max_outage_s": 1800}).outage_ns == int(1800e9)
    with pytest.raises(ConfigError, match=r"refit\.max_outage_s: must be 0 \(never cut\) or at "
                                          r"least step_s \(60 s\)"):
        parse({"max_outage_s": 30})
    given = parse({"max_outage_s": 1800})
    assert refit_config(plain(given)).outage_ns == given.outage_ns
    assert refit_config(plain(parse({}))).outage_ns == int(5 * 60e9)
    old = plain(parse({}))
    del old["max_outage_s"]  # a log written before the setting was refitted across outages
    assert refit_config(old).outage_ns is None


def test_the_diagnosis_waits_for_a_fitted_part_past_the_change_after_the_outage_too():
    """A window cut at an outage holds only the rows after it, and the diagnosis fits the
    first 70% of those: the trigger's wait counts from there."""
    from dataclasses import replace

    from furnace_daq.diagnosistrigger import _holds
    from furnace_daq.refit import Window

    h = int(3600e9)
    whole = Window(0, 10 * h, None, 600, 600, 5)  # fitted part to 7 h
    cut = replace(whole, outage=(2 * h, 4 * h))  # 70% of the 6 h after the outage: to 8.2 h
    # the fitted part must reach a tenth of a window (1 h) past the change
    assert _holds(whole, 6 * h) and not _holds(whole, 7 * h)
    assert _holds(cut, 7 * h) and not _holds(cut, int(7.3 * h))


def test_a_records_parts_between_outages_are_records_of_their_own():
    """Parts split at each outage, named in order, with every row of the record in one part;
    a part too short to fit left out and named, and one short beside the longest (a
    diagnosis of one record holds out a whole part: twenty rows must not be fitted for the
    rest); none long enough: refused."""
    from furnace_model.errors import FurnaceError
    from furnace_model.records import MIN_PART_ROWS, between_outages

    s = scenario("paper_exp1")
    run = simulate(s)
    keep = (run.t_min < 1200) | ((run.t_min >= 1300) & (run.t_min < 1305)) \
        | (run.t_min >= 1400)
    exp = Experiment("exp1", run.t_min[keep], run.tc[keep], run.burners[keep],
                     np.full(keep.sum(), s.t_air_c), s.start_time, furnace=PAPER)
    parts, (words,) = between_outages(exp)
    assert [p.name for p in parts] == ["exp1-1", "exp1-2"]
    assert parts[0].t_min[-1] == 1199.0 and parts[1].t_min[0] == 1400.0
    assert len(parts[0]) + len(parts[1]) + 5 == len(exp)
    assert all(p.outages() == [] for p in parts)
    assert words.startswith("exp1: no rows for 1.7 h from 2026-03-03 01:59Z, 1.6 h from ")
    assert "taken as 2 records (exp1-1, exp1-2)" in words
    assert words.endswith(f"left out, fewer than {MIN_PART_ROWS} rows or a tenth of the "
                          "longest part's: 5 rows from 2026-03-03 03:40Z")
    late = (run.t_min < 20) | (run.t_min >= 30)
    head = Experiment("exp1", run.t_min[late], run.tc[late], run.burners[late],
                      np.full(late.sum(), s.t_air_c), s.start_time, furnace=PAPER)
    (rest,), (said,) = between_outages(head)
    assert rest.name == "exp1-1" and rest.t_min[0] == 30.0
    assert said.endswith("20 rows from 2026-03-02 06:00Z")
    whole = Experiment("exp1", run.t_min, run.tc, run.burners, np.full(run.t_min.size,
                       s.t_air_c), s.start_time, furnace=PAPER)
    assert between_outages(whole) == ([whole], [])
    # rows logged in bursts, three every 100 minutes, are spaced so, not stopped
    bits = exp.rows(exp.t_min % 100 < 3)
    assert bits.outages() == [] and between_outages(bits) == ([bits], [])
    with pytest.MonkeyPatch.context() as mp:  # no part long enough: said, not fitted
        mp.setattr("furnace_model.records.MIN_PART_ROWS", 10 ** 6)
        with pytest.raises(FurnaceError, match="no part between its outages"):
            between_outages(exp)


def test_diagnose_takes_a_record_with_an_outage_as_its_parts(tmp_path):
    """A room with a wall, hourly over two weeks, 73 hours of rows missing in which its
    heating moved as every other hour: held across, the input of the hour before the
    outage would drive the model through it and leave a gap for another effect to be named
    for; taken as its two parts, the fit of the first predicts the second from its own
    start and the wall is named."""
    import subprocess
    import sys

    from furnace_model.diagnosis.hourlyroom import ROOM, hourly_room

    furnace = tmp_path / "room.yaml"
    furnace.write_text(ROOM)
    frame = hourly_room(1, ("wall_storage",), days=14).to_frame()
    csv = tmp_path / "room.csv"
    frame.drop(index=range(100, 173)).to_csv(csv, index=False)
    r = subprocess.run([sys.executable, "-m", "furnace_model.cli", "diagnose", str(csv),
                        "--furnace", str(furnace), "--quiet"], capture_output=True, text=True,
                       timeout=600, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert "room: no rows for 74.0 h from 2026-01-09 03:00Z" in r.stderr, r.stderr
    assert "taken as 2 records (room-1, room-2)" in r.stderr, r.stderr
    verdict = r.stdout.splitlines()[0]
    assert verdict in ("Verdict: explained (wall_storage)",
                       "Verdict: explained_in_part (wall_storage)"), r.stdout[:600]
    assert "Fitted: room-1; held out: whole experiments: room-2 held out" in r.stdout


def test_a_record_logged_on_change_is_spaced_not_stopped(tmp_path):
    """A historian's record of a room, a row only where the reading moved by its 0.2 °C
    deadband (the heating as it stood then), rows minutes to hours apart, most a few, and a
    day the historian was down: only that day is an outage. Split at five median spacings,
    it would be dozens of records of a few rows, each with its own start and offsets."""
    from furnace_model.cli import main
    from furnace_model.diagnosis.hourlyroom import ROOM, hourly_room
    from furnace_model.records import read_records
    from furnace_model.simulation.furnacefile import parse_furnace

    minute = hourly_room(1, ("wall_storage",), days=14, sample_min=1)
    frame = minute.to_frame()
    keep, last = [], None
    for i, t in enumerate(frame["tc_room_1"].round(1)):
        if last is None or abs(t - last) > 0.2 - 1e-9:
            keep.append(i)
            last = t
    logged = frame.iloc[keep]
    logged = logged[~logged["timestamp"].str.startswith("2026-01-10")]
    steps = np.diff(minute.t_min[keep])
    assert np.median(steps) < 10 < steps.max()  # irregular by design
    (tmp_path / "room.yaml").write_text(ROOM)
    logged.to_csv(tmp_path / "a.csv", index=False)
    parts, said = read_records([tmp_path / "a.csv"], furnace=parse_furnace(ROOM))
    assert len(parts) == 2, said
    assert said[0].startswith("a: no rows for 2") and "from 2026-01-09 23:" in said[0], said
    assert main(["fit", str(tmp_path / "a.csv"), "--furnace", str(tmp_path / "room.yaml"),
                 "--json", str(tmp_path / "fit.json")]) == 0
