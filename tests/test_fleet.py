"""Fleet jobs on dask.distributed: three simulated furnaces of two days each (a fuel switch,
wall losses, a control). The refit table and drift events, the verdicts per furnace, on a
LocalCluster and on a `dask scheduler` with two `dask worker` processes started apart on
127.0.0.1, one of them killed mid-run; a bad log reported with its furnace; a rerun that
computes nothing; the selfcheck's draws as tasks; the fleet file's errors by key path."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from fleet_helpers import SWITCH_MIN, write_fleet

from furnace_daq.cli import main as daq_main
from furnace_daq.fleet.description import load_fleet
from furnace_daq.fleet.engine import open_client, prepare_worker
from furnace_daq.fleet.jobs.diagnose import run_diagnose
from furnace_daq.fleet.jobs.refit import run_refit, segment_bounds
from furnace_daq.fleet.jobs.selfcheck import run_selfcheck
from furnace_model.config import parse_yaml
from furnace_model.errors import ConfigError
from furnace_model.log.schema import PARAM_NAMES
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
START = pd.Timestamp("2026-03-02T00:00:00Z")
SWITCH = START + pd.Timedelta(minutes=SWITCH_MIN)
WINDOWS = 7  # 6-h windows ending 06:00 .. 18:00 of day 2 (the logs end at 23:59)


@pytest.fixture(scope="module")
def fleet_file(tmp_path_factory) -> Path:
    return write_fleet(tmp_path_factory.mktemp("fleet"), broken=True)


@pytest.fixture(scope="module")
def local(fleet_file, tmp_path_factory):
    """refit, diagnose and refit again (from the store) on one LocalCluster of two workers;
    the client stays open for the tests that submit their own tasks."""
    out = tmp_path_factory.mktemp("local")
    fleet = load_fleet(fleet_file)
    with open_client(workers=2) as client:
        refit = run_refit(client, fleet, out, quiet=True)
        diagnose = run_diagnose(client, fleet, out, quiet=True)
        again = run_refit(client, fleet, out, quiet=True)
        wall = sorted((fleet_file.parent / "wall").glob("*.mcap"))[-1]
        os.utime(wall, ns=(wall.stat().st_atime_ns, wall.stat().st_mtime_ns + 10**9))
        touched = run_refit(client, fleet, out, quiet=True)
        yield {"out": out, "refit": refit, "diagnose": diagnose, "again": again,
               "touched": touched, "client": client, "fleet": fleet}


def table(out: Path, name: str) -> pd.DataFrame:
    return pd.read_parquet(out / f"{name}.parquet")


def test_refit_table_has_every_window_of_every_furnace(local):
    t = table(local["out"], "refit")
    assert sorted(t["furnace"].unique()) == ["control", "switch", "wall"]
    for _, rows in t.groupby("furnace"):
        assert len(rows) == WINDOWS
        assert list(rows["window_end"].dt.hour[:4]) == [6, 12, 18, 0]
        assert (rows["status"] == "ok").all(), rows["detail"].tolist()
    for p in PARAM_NAMES:
        assert (t[f"{p}_ci95_lo"] <= t[p]).all() and (t[p] <= t[f"{p}_ci95_hi"]).all()
    assert t[[f"rmse_{z}_c" for z in ("soak", "heat", "preheat")]].lt(3.0).all().all()
    control = t[t["furnace"] == "control"]
    assert (abs(control["f"] / 0.224131 - 1) < 0.03).all()


def test_a_drift_event_on_f_only_on_the_switched_furnace(local):
    ev = table(local["out"], "drift_events")
    assert list(ev["furnace"]) == ["switch"], ev[["furnace", "detail"]]
    e = ev.iloc[0]
    assert e["parameter"] == "f" and abs(e["relative_change"] + 0.2) < 0.03
    assert SWITCH < e["window_end"] <= SWITCH + pd.Timedelta(hours=12)


def test_verdicts_per_furnace(local):
    v = table(local["out"], "verdicts")
    assert list(v["furnace"]) == ["control", "switch", "wall"]
    assert set(v["fit_campaign"]) == {"d1"} and set(v["holdout_campaign"]) == {"d2"}
    by = v.set_index("furnace")
    assert by.loc["control", "status"] == "no_gap"
    assert by.loc["switch", "status"] != "no_gap"  # held out across the switch: a gap
    assert set(v["status"]) <= {"no_gap", "explained", "explained_in_part", "unexplained"}
    doc = json.loads((local["out"] / "diagnoses" / "switch__d1__d2.json").read_text())
    assert doc["verdict"]["status"] == by.loc["switch", "status"]


def test_a_bad_file_is_reported_with_its_furnace_and_the_rest_completes(local):
    """A furnace with no readable log fails; a bad file among good ones is left out and
    reported, and its furnace goes on (the control's refit and verdict are complete)."""
    for job in ("refit", "diagnose"):
        f = table(local["out"], f"{job}_failures").set_index("furnace")
        assert sorted(f.index) == ["broken", "control"], f
        assert "furnace-20260302T000000Z.mcap" in f.loc["broken", "reason"]
        assert "furnace-20260303T120000Z.mcap" in f.loc["control", "reason"]
        assert (f["task"] == "scan").all()
    report = (local["out"] / "fleet_report.html").read_text()
    assert "broken" in report and "furnace-20260302T000000Z.mcap" in report
    assert report.count("data:image/png;base64,") == 3  # a figure per furnace with windows


def test_a_rerun_computes_nothing_already_stored(local):
    first, again = local["refit"], local["again"]
    assert (first.computed, first.cached) == (3, 0)
    assert (again.computed, again.cached) == (0, 3)
    assert len(again.failures) == 2  # the bad files are tried again, and fail again
    touched = local["touched"]  # one of the wall furnace's files changed: it alone reruns
    assert (touched.computed, touched.cached) == (1, 2)
    assert [s.furnace for s, _ in touched.results if s.furnace == "wall"] == ["wall"]


def _faults_of_temporaries() -> int:
    """Pages faulted in by twenty iterations' worth of large temporaries, made and freed
    inside the numerics' entry (`blas.one_thread`) as a fit's are."""
    import resource

    from furnace_model.blas import one_thread

    with one_thread():
        kept = np.ones(1 << 20)
        for i in range(21):
            if i == 1:  # the first grows the heap
                before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            a, b = np.ones(1 << 20), np.ones(1 << 19)
            del a, b
        del kept
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


def test_the_workers_numerics_reuse_their_temporaries(local):
    """Dask's nanny starts each worker with MALLOC_TRIM_THRESHOLD_ set, which turns off
    glibc's sliding mmap threshold: unless the numerics set the allocator themselves
    (furnace_model.allocator), every large temporary faults in page by page, and a
    diagnosis in a worker spends more time in the kernel than in numpy."""
    assert set(local["client"].run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_")).values()
               ) == {"65536"}  # the nanny's setting, which the test is about
    seen = local["client"].run(_faults_of_temporaries)
    touched = 20 * (3 << 20) // 4096
    assert len(seen) == 2 and max(seen.values()) < touched // 20, seen


def test_plug_in_effects_load_in_the_workers(local):
    plugin = ROOT / "examples" / "slab_charging" / "slab_charging.py"

    def registered(path: str) -> list[str]:
        from furnace_model.effects import EFFECTS

        prepare_worker([path])
        return sorted(EFFECTS)

    names = local["client"].run(registered, str(plugin))
    assert len(names) == 2 and all("slab_charging" in n for n in names.values())


@pytest.mark.slow
def test_selfcheck_draws_as_tasks_give_the_selfchecks_cases(local, tmp_path):
    from furnace_model.diagnosis.selfcheck import check

    got, result = run_selfcheck(local["client"], ["none"], 1, tmp_path, first=3, quiet=True,
                                furnace=PAPER)
    (want,) = check(["none"], 1, 0, first=3, furnace=PAPER)
    assert not result.failures and len(got) == 1
    assert (got[0].label, got[0].draw, got[0].status, got[0].named, got[0].correct) == \
        (want.label, want.draw, want.status, want.named, want.correct)


@pytest.mark.slow
def test_selfcheck_draws_of_another_furnace_are_that_furnaces_cases(local, tmp_path):
    """`fleet selfcheck --furnace`: the draws are heat-ups of that description, the same
    cases as `furnace-model selfcheck --furnace` draws."""
    from furnace_model.diagnosis.selfcheck import check
    from furnace_model.simulation.furnacefile import load_furnace

    six = load_furnace(ROOT / "config" / "furnaces" / "six-zone.yaml")
    got, result = run_selfcheck(local["client"], ["sensor_lag"], 1, tmp_path, quiet=True,
                                furnace=six)
    (want,) = check(["sensor_lag"], 1, 0, furnace=six)
    assert not result.failures and len(got) == 1
    assert "soak_top" in want.description or "heat_" in want.description
    assert (got[0].description, got[0].status, got[0].named, got[0].correct) == \
        (want.description, want.status, want.named, want.correct)


@pytest.mark.slow
def test_selfcheck_production_draws_as_tasks_are_the_closed_loop_cases(local, tmp_path):
    """`fleet selfcheck --production`: the draws are the closed-loop cases
    `furnace-model selfcheck --production` draws."""
    from furnace_model.diagnosis.cases import production_scenario
    from furnace_model.diagnosis.selfcheck import check

    furnace = production_scenario().furnace
    got, result = run_selfcheck(local["client"], ["none"], 1, tmp_path, quiet=True,
                                mode="production", furnace=furnace)
    (want,) = check(["none"], 1, 0, mode="production", furnace=furnace)
    assert not result.failures and len(got) == 1
    assert "closed loop" in want.description
    assert (got[0].description, got[0].status, got[0].named, got[0].correct) == \
        (want.description, want.status, want.named, want.correct)


# -- a cluster started apart, a worker killed mid-run ----------------------------------------

def _dask(*args: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([str(Path(sys.executable).parent / "dask"), *args], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """`dask scheduler` and two `dask worker` processes (no nanny: a killed worker stays
    dead) on 127.0.0.1; every process is stopped at the end."""
    from distributed import Client

    tmp = tmp_path_factory.mktemp("cluster")
    info = tmp / "scheduler.json"
    procs = [_dask("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                   "--scheduler-file", str(info))]
    try:
        deadline = time.monotonic() + 60
        while not info.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(info.read_text())["address"]
        for _ in range(2):
            procs.append(_dask("worker", "--scheduler-file", str(info), "--nthreads", "1",
                               "--no-nanny", "--no-dashboard", "--host", "127.0.0.1"))
        client = Client(address, timeout=60)
        client.wait_for_workers(2, timeout=60)
        yield {"address": address, "client": client, "procs": procs}
        client.close()
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def test_a_running_cluster_gives_the_same_results_and_survives_a_killed_worker(
        local, cluster, fleet_file, tmp_path, capsys):
    """The switched furnace and the broken one (kept short: the LocalCluster run already
    covers the whole fleet), through the command line, on the cluster started apart."""
    doc = yaml.safe_load(fleet_file.read_text())
    doc["furnaces"] = [f for f in doc["furnaces"] if f["name"] in ("switch", "broken")]
    subset = fleet_file.with_name("fleet_subset.yaml")
    subset.write_text(yaml.safe_dump(doc))
    client = cluster["client"]
    pids = client.run(os.getpid)
    killed: list[int] = []

    def kill_one_when_busy():
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not killed:
            busy = [w for w, keys in client.processing().items()
                    if any("segment" in str(k) for k in keys)]
            if busy:
                time.sleep(0.3)  # inside a fit
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(pids[busy[0]])
                return
            time.sleep(0.05)

    killer = threading.Thread(target=kill_one_when_busy)
    killer.start()
    code = daq_main(["fleet", "refit", str(subset), "--out", str(tmp_path),
                     "--scheduler", cluster["address"], "--quiet"])
    killer.join()
    assert killed, "no refit task was seen running"
    victim = next(p for p in cluster["procs"] if p.pid == killed[0])
    assert victim.wait(10) == -signal.SIGKILL
    err = capsys.readouterr().err
    assert code == 1  # the bad file; nothing else
    assert "FAILED broken" in err and "tasks done" not in err  # --quiet: failures only
    got, want = table(tmp_path, "refit"), table(local["out"], "refit")
    want = want[want["furnace"] == "switch"].reset_index(drop=True)
    assert got.drop(columns="elapsed_s").equals(want.drop(columns="elapsed_s"))
    assert table(tmp_path, "drift_events").equals(table(local["out"], "drift_events"))
    assert list(table(tmp_path, "refit_failures")["furnace"]) == ["broken"]


# -- segments ------------------------------------------------------------------------------

def test_segment_bounds_cut_on_the_refit_grid():
    day = 86400 * 10**9
    start, end = int(START.value) + 3600 * 10**9, int(START.value) + 3 * day
    assert segment_bounds(start, end, 900.0, None) == [(None, None)]
    cuts = segment_bounds(start, end, 900.0, 1.0)
    assert cuts == [(None, int(START.value) + day), (int(START.value) + day,
                                                     int(START.value) + 2 * day),
                    (int(START.value) + 2 * day, None)]
    assert segment_bounds(start, end, 7 * 3600.0, 1.0)[0][1] % (7 * 3600 * 10**9) == 0


@pytest.mark.slow
def test_a_cut_history_restarts_cold_and_then_agrees(local, tmp_path):
    """Day-long segments: the same windows, each in one segment; after the cut the first
    window is fitted cold and the drift references start anew."""
    out = tmp_path
    with open_client(workers=2) as client:
        run_refit(client, local["fleet"], out, segment_days=1.0, quiet=True)
    cut, uncut = table(out, "refit"), table(local["out"], "refit")
    key = ["furnace", "window_end"]
    assert cut[key].equals(uncut[key])
    assert sorted(cut["segment"].unique()) == [0, 1]
    merged = cut.merge(uncut, on=key, suffixes=("_cut", ""))
    control = merged[merged["furnace"] == "control"]
    assert (abs(control["f_cut"] / control["f"] - 1) < 0.02).all()


# -- the fleet file -------------------------------------------------------------------------

BAD = [
    ({"furnaces": []}, "furnaces: expected at least 1 entries"),
    ({"furnaces": [{"logs": ["a"]}]}, "furnaces[0].name: required key is missing"),
    ({"furnaces": [{"name": "a b", "logs": ["a"]}]}, "furnaces[0].name: 'a b' is not"),
    ({"furnaces": [{"name": "a", "logs": ["a"], "furnace": "tunnel"}]},
     "furnaces[0].furnace: no furnace description 'tunnel'"),
    ({"furnaces": [{"name": "a", "logs": ["a"]}, {"name": "a", "logs": ["b"]}]},
     "furnaces[1].name: 'a' is already the name of furnaces[0]"),
    ({"furnaces": [{"name": "a", "logs": ["a"], "campaigns": [
        {"name": "c", "from": "2026-03-02T00:00:00Z", "to": "2026-03-01T00:00:00Z"}]}]},
     "furnaces[0].campaigns[0].to: "),
    ({"furnaces": [{"name": "a", "logs": ["a"], "campaigns": [
        {"name": "c", "from": "2026-03-02T00:00:00", "to": "2026-03-03T00:00:00Z"}]}]},
     "furnaces[0].campaigns[0].from: give a UTC offset"),
    ({"furnaces": [{"name": "a", "logs": ["a"]}], "refit": {"window_s": 10}},
     "refit.window_s: "),
    ({"furnaces": [{"name": "a", "logs": ["a"]}], "diagnose": {"effects": ["nope"]}},
     "diagnose.effects[0]: unknown effect 'nope'"),
    ({"furnaces": [{"name": "a", "logs": ["a"], "typo": 1}]}, "furnaces[0].typo: unknown key"),
]


@pytest.mark.parametrize("doc, message", BAD, ids=[m.split(":")[0] for _, m in BAD])
def test_fleet_file_errors_name_the_key_path(doc, message):
    from furnace_daq.fleet.description import parse_fleet

    with pytest.raises(ConfigError) as err:
        parse_fleet(parse_yaml(yaml.safe_dump(doc), "fleet.yaml"))
    assert f"fleet.yaml: {message}" in str(err.value)


def test_the_shipped_example_loads_with_the_papers_furnace_by_default():
    fleet = load_fleet(ROOT / "config" / "fleet.yaml")
    assert [f.description for f in fleet.furnaces] == [PAPER, PAPER]
    assert fleet.refit.period_s == 900.0 and len(fleet.furnaces[0].campaigns) == 2


def test_the_cli_refuses_a_bad_fleet_file_before_starting_a_cluster(tmp_path, capsys):
    bad = tmp_path / "fleet.yaml"
    bad.write_text(yaml.safe_dump({"furnaces": [{"name": "x"}]}))
    assert daq_main(["fleet", "refit", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "furnaces[0].logs: required key is missing" in capsys.readouterr().err



def test_rolling_pairs_each_calendar_period_with_the_next():
    from furnace_daq.fleet.description import FleetFurnace
    from furnace_daq.fleet.jobs.diagnose import campaign_pairs

    f = FleetFurnace("x", PAPER, (Path("x"),))
    scan = {"files": [{"start_ns": int(pd.Timestamp("2026-01-30T05:00Z").value),
                       "end_ns": int(pd.Timestamp("2026-03-02T01:00Z").value)}]}
    pairs, _ = campaign_pairs(f, scan, None, "month")
    assert [(a[0], b[0]) for a, b in pairs] == [("2026-01", "2026-02"), ("2026-02", "2026-03")]
    assert pairs[0][1][1] == int(pd.Timestamp("2026-02-01T00:00Z").value) == pairs[0][0][2]
    days, _ = campaign_pairs(f, scan, None, "day")
    assert len(days) == 31 and days[0][0][0] == "2026-01-30"
    weeks, _ = campaign_pairs(f, scan, None, "week")
    assert weeks[0][0][0] == "2026-W05" and pd.Timestamp(weeks[0][1][1], tz="UTC").weekday() == 0


@pytest.mark.slow
def test_an_uncut_refit_is_the_replay_timeline(local, fleet_file):
    """furnace-daq replay of the switched furnace's logs with the fleet's refit settings
    gives the rows of the fleet's refit table, window for window."""
    from furnace_daq.daqconfig import parse_config
    from furnace_daq.fleet.tasks import list_files
    from furnace_daq.replay import replay

    gateway = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    gateway["refit"] = yaml.safe_load(fleet_file.read_text())["refit"]
    config = parse_config(parse_yaml(yaml.safe_dump(gateway), "gateway.yaml"))
    out = fleet_file.parent / "switch.model.mcap"
    msgs = [m.to_json() for m in replay(list_files([fleet_file.parent / "switch"]), config, out)]
    t = table(local["out"], "refit")
    t = t[t["furnace"] == "switch"].reset_index(drop=True)
    assert len(msgs) == len(t)
    for m, row in zip(msgs, t.itertuples(), strict=True):
        assert pd.Timestamp(m["window_end"]) == row.window_end and m["status"] == row.status
        for p in PARAM_NAMES:
            assert getattr(row, p) == pytest.approx(m[p], rel=1e-9)


def test_progress_rewrites_one_line_on_a_terminal_and_prints_tenths_otherwise(monkeypatch):
    import io

    from furnace_model import progress as progress_module
    from furnace_model.progress import Progress

    clock = iter(range(0, 1000, 10))  # each reading of the clock 10 s after the last
    monkeypatch.setattr(progress_module.time, "monotonic", lambda: float(next(clock)))

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    tty = Tty()
    p = Progress("refit", 3, stream=tty)
    p.finished()
    p.failure("line2", "segment 1", "boom")
    p.finished(ok=False)
    p.close()
    shown = tty.getvalue()
    # a bar, the count, and the time left at this run's pace (10 s per task so far)
    assert "\r[########................] refit: 1/3 tasks done, about 20 s left" in shown
    assert "\r\x1b[Krefit: FAILED line2 segment 1: boom\n" in shown  # the bar's line cleared
    assert shown.endswith("refit: 2/3 tasks done, 1 failed, about 10 s left\x1b[K\n")
    log = io.StringIO()
    p = Progress("refit", 20, stream=log, cached=4)
    for _ in range(16):
        p.finished()
    lines = log.getvalue().splitlines()
    assert lines[0] == "refit: 4/20 tasks done (4 from earlier runs)"  # nothing run: no estimate
    assert lines[-1] == "refit: 20/20 tasks done (4 from earlier runs)"
    assert len(lines) == 9 and all("left" in x for x in lines[1:-1])
    quiet = io.StringIO()
    p = Progress("refit", 2, stream=quiet, quiet=True)
    p.finished()
    p.note("a case's line")
    p.failure("x", "scan", "bad")
    assert quiet.getvalue() == "refit: FAILED x scan: bad\n"


def test_campaign_pairs_in_time_order_or_as_asked():
    from furnace_daq.fleet.description import Campaign, FleetFurnace
    from furnace_daq.fleet.jobs.diagnose import campaign_pairs

    def c(name, day):
        return Campaign(name, pd.Timestamp(f"2026-03-0{day}T00:00Z"),
                        pd.Timestamp(f"2026-03-0{day + 1}T00:00Z"))

    f = FleetFurnace("x", PAPER, (Path("x"),), campaigns=(c("late", 5), c("early", 1), c("mid", 3)))
    pairs, notes = campaign_pairs(f, {}, None, None)
    assert [(a[0], b[0]) for a, b in pairs] == [("early", "mid"), ("mid", "late")] and not notes
    pairs, notes = campaign_pairs(f, {}, [("late", "early"), ("early", "nope")], None)
    assert [(a[0], b[0]) for a, b in pairs] == [("late", "early")]
    assert notes == ["x: no campaign nope; pair early:nope left out"]
    lone = FleetFurnace("y", PAPER, (Path("y"),), campaigns=(c("only", 1),))
    assert campaign_pairs(lone, {}, None, None) == \
        ([], ["y: fewer than two campaigns; nothing to diagnose"])


def test_a_six_zone_furnace_in_the_fleet_and_a_misfiled_log(local, tmp_path):
    """A fleet entry names its furnace description (`furnace: six-zone`): its windows are
    refitted with that furnace's network and its rows carry that network's parameters and
    zones, beside the paper furnaces' a..f; an entry whose logs record another furnace than
    the fleet file says is a failure naming both, and the rest completes."""
    from furnace_daq.logmeta import build_metadata
    from furnace_daq.mcaplog import LogWriter
    from furnace_daq.plantlog import write_run
    from furnace_model.simulation.plant import Plant
    from furnace_model.simulation.scenario import load_scenario

    sc = load_scenario(ROOT / "config" / "scenarios" / "six_zone_heatup.yaml")
    run = Plant.from_scenario(sc, seed=4).run_scenario(sc)
    log = LogWriter(tmp_path / "six", flush_interval_s=3600.0, rotate_s=86400.0,
                    metadata=build_metadata(None, furnace=sc.furnace, software_version="t",
                                            host="h"))
    write_run(run, log, sc.start_time)
    log.close()
    fleet_file = tmp_path / "fleet.yaml"
    fleet_file.write_text(yaml.safe_dump({
        "furnaces": [{"name": "six", "furnace": "six-zone", "logs": ["six"]},
                     {"name": "misfiled", "logs": ["six"]}],
        "refit": {"period_s": 43200, "window_s": 86400, "step_s": 300}}))
    fleet = load_fleet(fleet_file)
    assert fleet.furnace("six").description == sc.furnace
    out = tmp_path / "out"
    result = run_refit(local["client"], fleet, out, quiet=True)
    fails = result.failures_frame()
    assert list(fails["furnace"].unique()) == ["misfiled"], fails
    assert "furnace 'six-zone'" in fails["reason"].iloc[0]
    assert "'paper'" in fails["reason"].iloc[0]
    rows = table(out, "refit")
    assert set(rows["furnace"]) == {"six"}
    fitted = rows[rows["fitted"]]
    assert len(fitted) >= 3
    inside = []
    for name, truth in sc.params.items():
        inside += list((fitted[f"{name}_ci95_lo"] <= truth) & (truth <= fitted[f"{name}_ci95_hi"]))
    assert sum(inside) / len(inside) > 0.85, sum(inside) / len(inside)
    assert all(fitted[f"rmse_{z}_c"].notna().all() for z in sc.furnace.zones)
    assert "a" not in rows.columns
    html = (out / "fleet_report.html").read_text()
    assert "<th>gain_preheat_bottom</th>" in html and "soak_bottom" in html


def test_fit_job_fits_every_campaign_and_stores_what_it_fitted(local, tmp_path):
    """`fleet fit`, the job docs/fleet.md shows as its worked example: a row and a parameter
    file per furnace and campaign, the control furnace's truth inside its intervals, what
    the scan refused reported, and a rerun all from the store."""
    from furnace_daq.fleet.jobs.fit import JOB

    out = tmp_path / "out"
    out.mkdir()
    first = JOB.run(local["client"], local["fleet"], out, quiet=True)
    rows = pd.read_parquet(out / "campaign_fits.parquet")
    assert sorted(zip(rows["furnace"], rows["campaign"], strict=True)) == [
        (f, c) for f in ("control", "switch", "wall") for c in ("d1", "d2")]
    fails = first.failures_frame()  # the broken furnace, and the bad file among the control's
    assert set(fails["furnace"]) == {"broken", "control"} and set(fails["task"]) == {"scan"}
    truth = load_scenario(ROOT / "config" / "scenarios" / "week_steps.yaml").params
    control = rows[rows["furnace"] == "control"]
    inside = [bool((r[f"{p}_ci95_lo"] <= v) & (v <= r[f"{p}_ci95_hi"]))
              for _, r in control.iterrows() for p, v in truth.items()]
    assert sum(inside) >= len(inside) - 2, control.T
    for _, r in rows.iterrows():
        doc = json.loads((out / "fits" / f"{r['furnace']}__{r['campaign']}.json").read_text())
        assert doc["params"] == {p: r[p] for p in PARAM_NAMES}
    again = JOB.run(local["client"], local["fleet"], out, quiet=True)
    assert (again.computed, again.cached) == (0, first.computed)
