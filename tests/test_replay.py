"""The daemon refits online while it polls the simulated PLC at high speed; a replay of its
log gives the same /model/parameters, message by message; polling goes on while a fit runs;
the latest model is in the state directory."""

from __future__ import annotations

import asyncio
import json
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from daq_processes import (
    ROOT,
    config,
    furnace_daq,
    messages,
    sim,
    start_daemon,
    start_simplc,
    stop,
)
from logcheck import check_files

from furnace_daq.daqconfig import parse_config
from furnace_daq.logmeta import read_metadata, recorded_refit
from furnace_daq.replay import replay
from furnace_daq.simplc import SimPLC
from furnace_model.config import Node
from furnace_model.log.read import read_messages
from furnace_model.log.schema import (
    AMBIENT,
    BURNERS,
    DAQ_STATUS,
    LOG,
    MODEL_PARAMETERS,
    PARAM_NAMES,
    THERMOCOUPLES,
    time_ns,
)
from furnace_model.simulation.scenario import load_scenario

SCENARIO = ROOT / "config" / "scenarios" / "week_steps.yaml"
PERIOD = 0.05          # one poll per two simulated minutes at 2400x
SPEED = 2400.0
HOURS = 14             # simulated; refits every 2 h over 6 h windows of 2-minute samples
REFIT = {"period_s": 7200, "window_s": 21600, "step_s": 120, "max_gap_fraction": 0.3,
         "budget_s": 20}


def daemon_config(port: int, state_dir: Path, refit: dict = REFIT):
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["poll_period_s"] = PERIOD
    doc["stale_after_s"] = 1.0
    doc["plc"].update(host="127.0.0.1", port=port, timeout_s=0.2)
    doc["clock"]["epoch"] = "2026-03-02T00:00:00Z"  # the scenario's start: windows on its hours
    doc["refit"] = {**refit, "state_dir": str(state_dir)}
    return parse_config(Node(doc, "test.yaml"))


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("live")
    seen: list[dict] = []

    async def run():
        plc = SimPLC(load_scenario(SCENARIO), speed=SPEED, port=0, seed=1, scan_s=0.05)
        await plc.start()
        try:
            cfg = daemon_config(plc.port, tmp / "state")
            daemon, task = start_daemon(cfg, tmp / "logs", HOURS * 3600 / SPEED + 0.5,
                                        on_model=seen.append)
            counters = await task
        finally:
            await plc.stop()
        return cfg, counters

    cfg, counters = asyncio.run(run())
    logs = sorted((tmp / "logs").glob("*.mcap"))
    msgs = list(read_messages(logs))
    return {"config": cfg, "counters": counters, "logs": logs, "msgs": msgs, "seen": seen,
            "tmp": tmp}


def live_params(live) -> list[dict]:
    return [m for t, m, _, _ in live["msgs"] if t == MODEL_PARAMETERS]


MISSING = re.compile(r"([\d.]+)% of the window's (\d+) samples are missing")


def logged_bins(live, refit: dict) -> int:
    """How many of a window's samples (step_s bins on the PLC clock) hold a reading."""
    lo, hi = (int(np.datetime64(refit[k].rstrip("Z"), "ns").astype(np.int64))
              for k in ("window_start", "window_end"))
    step = int(REFIT["step_s"] * 1e9)
    return len({(pub - lo) // step for t, m, _, pub in live["msgs"]
                if t == THERMOCOUPLES and "error" not in m and lo <= pub < hi})


def common(got: list, want: list) -> list:
    """The replayed refits that the live daemon published too. The live run ends at a fixed
    time: a refit still running in its worker then is not published, while the replay,
    from the same log, fits that window too (at most one: the daemon runs one refit at a
    time), so the replay may hold one more, after the last live one."""
    assert len(want) <= len(got) <= len(want) + 1, (len(got), len(want))
    return got[:len(want)]


def assert_same_timeline(got: list[dict], want: list[dict]) -> None:
    if len(got) > len(want):
        assert got[-1]["window_end"] > want[-1]["window_end"]
    for g, w in zip(common(got, want), want, strict=True):
        assert (g["window_start"], g["window_end"], g["status"]) == \
            (w["window_start"], w["window_end"], w["status"])
        assert g.get("search") == w.get("search")  # the same seed, the same generations
        for p in PARAM_NAMES:
            if w.get(p) is None:
                assert g.get(p) is None
            else:
                assert g[p] == pytest.approx(w[p], rel=1e-6), (w["window_end"], p)
        for z, v in w["rmse_c"].items():
            assert g["rmse_c"][z] == pytest.approx(v, rel=1e-6)


def test_live_refits_while_polling(live):
    params = live_params(live)
    assert len(params) == HOURS // 2 - 1 or len(params) == HOURS // 2, \
        [m["window_end"] for m in params]
    statuses = [m["status"] for m in params]
    assert statuses[:2] == ["insufficient_excitation"] * 2  # 6-h windows still filling
    # a host that starves the poll loop leaves a window short of samples: it is set aside,
    # said so, and that is true of the log; every other window is fitted
    for m in params[2:]:
        if m["status"] != "ok":
            assert m["status"] == "insufficient_excitation", m
            missing = MISSING.search(m["detail"])
            assert missing and float(missing[1]) > 100 * REFIT["max_gap_fraction"], m
            assert logged_bins(live, m) <= (1 - REFIT["max_gap_fraction"]) * int(missing[2])
    fitted = [m for m in params if m["status"] == "ok"]
    assert fitted, [m.get("detail") for m in params]
    assert {m["search"]["method"] for m in fitted} == {"ga_polish"}
    assert [m["window_end"][11:16] for m in params[:3]] == ["02:00", "04:00", "06:00"]
    assert live["seen"] == params  # on_model saw each message
    state = json.loads((live["tmp"] / "state" / "model.json").read_text())
    assert state == params[-1]
    # publish time = window end on the data clock; log time = host time of the result
    pubs = [(pub, m) for t, m, _, pub in live["msgs"] if t == MODEL_PARAMETERS]
    assert all(np.datetime64(m["window_end"].rstrip("Z"), "ns").astype(np.int64) == pub
               for pub, m in pubs)


def test_every_message_validates_against_its_channels_schema(live):
    """The daemon's real log, every message of every topic, against the schema recorded with
    its channel, strictly (an undeclared field fails); furnace messages carry the PLC time."""
    counts, found = check_files(live["logs"])
    assert found == []
    assert {THERMOCOUPLES, BURNERS, AMBIENT, DAQ_STATUS, MODEL_PARAMETERS, LOG} <= set(counts)
    furnace = [(m, pub) for t, m, _, pub in live["msgs"] if t in (THERMOCOUPLES, BURNERS, AMBIENT)
               and "error" not in m]
    assert furnace and all(time_ns(m["plc_time"]) == pub for m, pub in furnace)
    params = [(m, pub) for t, m, _, pub in live["msgs"] if t == MODEL_PARAMETERS]
    assert all(time_ns(m["plc_time"]) == pub for m, pub in params)
    assert not any(p in params[0][0] for p in PARAM_NAMES)  # no model yet: absent, not null


def test_each_log_file_records_how_it_was_made(live):
    meta = read_metadata(live["logs"][:1])
    assert meta is not None and meta["host"] == socket.gethostname()
    assert [z["name"] for z in json.loads(meta["furnace"])["zones"]] == ["soak", "heat", "preheat"]
    config = json.loads(meta["config"])
    assert config["poll_period_s"] == PERIOD and config["plc"]["port"] == live["config"].plc.port
    assert recorded_refit(meta)["window_s"] == REFIT["window_s"]


def test_a_restarted_daemon_goes_on_with_the_saved_model(live, tmp_path):
    """The chain's state is saved next to model.json; a daemon started on it reports so and
    keeps the saved model in force until its own windows are fitted."""
    params = live_params(live)
    saved = json.loads((live["tmp"] / "state" / "refit_chain.json").read_text())
    last_ok = [m for m in params if m["status"] == "ok"][-1]
    assert saved["model"] == last_ok and set(saved["references"]) == set(PARAM_NAMES)
    state = tmp_path / "state"
    state.mkdir()
    (state / "refit_chain.json").write_text(json.dumps(saved))

    async def run():
        plc = SimPLC(load_scenario(SCENARIO), speed=SPEED, port=0, seed=1, scan_s=0.05)
        await plc.start()
        try:
            cfg = daemon_config(plc.port, state)
            _, task = start_daemon(cfg, tmp_path / "logs", 2 * 3600 / SPEED + 0.5)
            await task
        finally:
            await plc.stop()

    asyncio.run(run())
    msgs = list(read_messages(sorted((tmp_path / "logs").glob("*.mcap"))))
    events = [m for t, m, _, _ in msgs if t == "/daq/events" and m["kind"] == "refit_resumed"]
    assert len(events) == 1 and last_ok["window_end"] in events[0]["detail"]
    first = next(m for t, m, _, _ in msgs if t == MODEL_PARAMETERS)
    assert first["status"] == "insufficient_excitation"  # its 6-h window is still filling
    assert first["model_window_end"] == last_ok["window_end"]
    assert all(first[p] == last_ok[p] for p in PARAM_NAMES)
    # a state file that is not one is an event, and the refits start afresh
    (state / "refit_chain.json").write_text('{"version": 1, "model": 3}')
    asyncio.run(run())
    kinds = [m["kind"] for t, m, _, _ in read_messages(sorted((tmp_path / "logs").glob(
        "*.mcap"))) if t == "/daq/events"]
    assert "state_unusable" in kinds


def test_polling_goes_on_while_a_fit_runs(tmp_path):
    """Fits of a known length: a GA given more generations than its budget allows searches
    until the budget is spent (and the window fails), so each fit holds the worker for at
    least `budget_s` however fast the host. A poll loop that waited on a fit would log no
    reading while one runs; one that goes on logs a reading every period, short of the
    ticks a stalled host skips."""
    budget = 1.0
    refit = {"period_s": 3600, "window_s": 7200, "step_s": 120, "max_gap_fraction": 0.9,
             "min_burner_steps": 0, "method": "ga", "generations": 10_000_000,
             "budget_s": budget}

    async def run():
        plc = SimPLC(load_scenario(SCENARIO), speed=SPEED, port=0, seed=1, scan_s=0.05)
        await plc.start()
        try:
            cfg = daemon_config(plc.port, tmp_path / "state", refit)
            _, task = start_daemon(cfg, tmp_path / "logs", 6 * 3600 / SPEED + 0.5)
            await task
        finally:
            await plc.stop()

    asyncio.run(run())
    msgs = list(read_messages(sorted((tmp_path / "logs").glob("*.mcap"))))
    ticks = np.array([lt for t, _, lt, _ in msgs if t == THERMOCOUPLES], dtype=np.int64)
    # the worker's own time for the fit, ending when the daemon took the result: inside the
    # span from handing the window over to taking the result back
    fits = [(lt - m["elapsed_s"] * 1e9, lt) for t, m, lt, _ in msgs
            if t == MODEL_PARAMETERS and "time budget" in m["detail"]]
    assert all(hi - lo >= budget * 1e9 for lo, hi in fits)
    fits = [(lo, hi) for lo, hi in fits if hi < ticks[-1]]  # not those finished at stop
    assert len(fits) >= 3, [m for t, m, _, _ in msgs if t == MODEL_PARAMETERS]
    inside = [int(((ticks > lo) & (ticks < hi)).sum()) for lo, hi in fits]
    asked = sum(hi - lo for lo, hi in fits) / (PERIOD * 1e9)
    assert min(inside) >= 1 and sum(inside) >= 0.5 * asked, (inside, asked)


def test_replay_of_the_log_equals_the_live_parameters(live, tmp_path):
    """Without a config: the log's metadata holds the daemon's refit settings (not the
    defaults: windows of 6 h every 2 h here), so the log alone replays as it was fitted live
    (the paced replay below and the command's test pass the config explicitly); the output
    records the settings it used and validates against its schemas."""
    out = tmp_path / "replay.mcap"
    got = [m.to_json() for m in replay(live["logs"], None, out)]
    assert_same_timeline(got, live_params(live))
    written = [m for t, m, _, _ in read_messages([out]) if t == MODEL_PARAMETERS]
    assert written == got
    assert recorded_refit(read_metadata([out]))["period_s"] == REFIT["period_s"]
    counts, found = check_files([out])
    assert found == [] and counts[MODEL_PARAMETERS] == len(got)


def test_replay_fits_with_the_configured_method(live, tmp_path):
    """The same log replayed with `method: ga`: every window searched by the GA from scratch,
    whatever the live daemon did."""
    cfg = daemon_config(1, tmp_path / "state",  # the port plays no part in a replay
                        {**REFIT, "method": "ga", "population": 12, "generations": 30})
    got = [m.to_json() for m in replay(live["logs"], cfg, tmp_path / "ga.mcap")]
    fitted = [m for m in got if m["status"] != "insufficient_excitation"]
    assert fitted and {m["status"] for m in fitted} == {"ok"}, fitted
    # the windows the live daemon fitted, whichever a starved host left short of samples
    assert {m["window_end"] for m in live_params(live) if m["status"] == "ok"} \
        <= {m["window_end"] for m in fitted}
    assert all(m["search"] == {"method": "ga", "warm_start": False, "population": 12,
                               "generations": 30} for m in fitted)
    want = live_params(live)
    assert [m["window_end"] for m in common(got, want)] == [m["window_end"] for m in want]
    assert not any("zone_offsets_c" in m for m in got)  # the GA fits none: absent, not null
    counts, found = check_files([tmp_path / "ga.mcap"])
    assert found == [] and counts[MODEL_PARAMETERS] == len(got)


def test_replay_command_prints_one_line_per_refit(live, tmp_path):
    cfg = tmp_path / "daq.yaml"
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["refit"] = REFIT
    cfg.write_text(yaml.safe_dump(doc))
    out = tmp_path / "cli.mcap"
    proc = subprocess.run([sys.executable, "-m", "furnace_daq.cli", "replay",
                           *map(str, reversed(live["logs"])), "--config", str(cfg),
                           "--out", str(out), "--fast"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    want = live_params(live)
    last = common(lines, want)[-1]
    assert last.startswith(want[-1]["window_end"]) and want[-1]["status"] in last
    assert f"-> {out}" in proc.stderr
    assert_same_timeline([m for t, m, _, _ in read_messages([out]) if t == MODEL_PARAMETERS],
                         want)


def test_replay_refuses_bad_input(tmp_path):
    bad = tmp_path / "junk.mcap"
    bad.write_bytes(b"not an mcap file at all")
    proc = subprocess.run([sys.executable, "-m", "furnace_daq.cli", "replay", str(bad)],
                          capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.returncode == 1
    assert proc.stderr.startswith("furnace-daq replay: error:") and str(bad) in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "junk.model.mcap").exists()
    proc = subprocess.run([sys.executable, "-m", "furnace_daq.cli", "replay", str(bad),
                           "--speed", "0"], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.returncode == 1 and "--speed" in proc.stderr


def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_daemon_process_refits_and_ends_its_worker_on_sigterm(tmp_path):
    """The real `furnace-daq run` with a refit section: the worker is a child process, the
    latest model lands in --state-dir, SIGTERM ends both and exits 0."""
    sim, port = start_simplc("--speed", "600")
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["poll_period_s"] = 0.05
    doc["plc"]["timeout_s"] = 0.5
    doc["refit"] = {"period_s": 600, "window_s": 1200, "step_s": 60, "budget_s": 10}
    cfg = tmp_path / "daq.yaml"
    cfg.write_text(yaml.safe_dump(doc))
    state = tmp_path / "state"
    try:
        daq = furnace_daq("run", "--config", str(cfg), "--plc", f"127.0.0.1:{port}",
                          "--log-dir", str(tmp_path / "logs"), "--state-dir", str(state))
        deadline = time.monotonic() + 60
        while not (state / "model.json").exists() and time.monotonic() < deadline:
            assert daq.poll() is None, daq.stderr.read()
            time.sleep(0.2)
        workers = _children(daq.pid)  # the fitter, and multiprocessing's resource tracker
        cmdlines = [Path(f"/proc/{p}/cmdline").read_bytes() for p in workers]
        assert sum(b"spawn_main" in c for c in cmdlines) == 1, cmdlines
        daq.send_signal(signal.SIGTERM)
        assert daq.wait(30) == 0, daq.stderr.read()
    finally:
        stop(daq)
        stop(sim)
    # the resource tracker ends when its pipe from the daemon closes; a child that ended but
    # was not reaped (an orphan in a container whose PID 1 does not reap) is a zombie
    deadline = time.monotonic() + 5
    while [p for p in workers if _alive(p)] and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [p for p in workers if _alive(p)], "a child outlived the daemon"
    model = json.loads((state / "model.json").read_text())
    assert model["status"] in ("ok", "insufficient_excitation") and "window_end" in model
    params = [m for t, m, _, _ in read_messages(sorted((tmp_path / "logs").glob("*.mcap")))
              if t == MODEL_PARAMETERS]
    assert params and params[-1] == model


def test_a_failing_state_write_or_consumer_is_an_event_not_a_stop(tmp_path):
    """model.json cannot be written (its directory is a file) and the on_model consumer
    raises: both are /daq/events, refits and polling go on."""
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")

    def consumer(message: dict) -> None:
        raise RuntimeError("consumer bug")

    async def run():
        plc = await sim(0)
        try:
            cfg = config(plc.port, refit={"period_s": 600, "window_s": 1200, "step_s": 60,
                                      "state_dir": str(blocker / "state")})
            daemon, task = start_daemon(cfg, tmp_path / "logs", 5.0, on_model=consumer)
            return await task
        finally:
            await plc.stop()

    counters = asyncio.run(run())
    msgs = messages(tmp_path / "logs")
    kinds = [m["kind"] for t, m, _ in msgs if t == "/daq/events"]
    params = [m for t, m, _ in msgs if t == MODEL_PARAMETERS]
    assert len(params) >= 2
    assert kinds.count("state_write_failed") == 1, kinds  # reported once, not per window
    assert kinds.count("on_model_error") == len(params)
    # polling went on over the whole run: every tick polled or counted as skipped, and the
    # polls answered
    assert counters.polls + counters.skipped_ticks >= 0.9 * 5.0 / 0.05, counters
    assert counters.ok_polls >= 0.9 * counters.polls, counters


def test_replay_at_a_given_speed_is_paced_by_the_data_clock(live, tmp_path):
    # a failed poll is stamped with the host's clock: not the data's span
    pubs = [pub for t, m, _, pub in live["msgs"] if t == THERMOCOUPLES and "error" not in m]
    span_s = (pubs[-1] - pubs[0]) / 1e9
    speed = span_s / 3.0  # three seconds of wall time
    t0 = time.monotonic()
    got = [m.to_json()
           for m in replay(live["logs"], live["config"], tmp_path / "paced.mcap", speed=speed)]
    assert time.monotonic() - t0 >= 2.9
    assert_same_timeline(got, live_params(live))


def _with_failed_poll(logs: list[Path], out: Path) -> None:
    """The logs' messages in one file, with a failed poll (every thermocouple
    `comm_error`) after the middle reading, published on the host's clock as the daemon
    stamps one: months from the PLC's clock here."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with out.open("wb") as sink:
        writer = Writer(sink)
        writer.start()
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        middle = None
        for path in logs:
            with path.open("rb") as f:
                reader = make_reader(f)
                for record in reader.iter_metadata():
                    writer.add_metadata(record.name, record.metadata)
                rows = list(reader.iter_messages())
            for schema, channel, m in rows:
                if schema.id not in schemas:
                    schemas[schema.id] = writer.register_schema(schema.name, schema.encoding,
                                                                schema.data)
                if channel.id not in channels:
                    channels[channel.id] = writer.register_channel(
                        channel.topic, channel.message_encoding, schemas[schema.id],
                        channel.metadata)
                writer.add_message(channels[channel.id], m.log_time, m.data, m.publish_time)
                if middle is None and channel.topic == THERMOCOUPLES \
                        and m.log_time >= (rows[0][2].log_time + rows[-1][2].log_time) // 2:
                    middle = m.log_time + 1
                    quality = dict.fromkeys(json.loads(m.data)["quality"], "comm_error")
                    writer.add_message(channels[channel.id], middle, json.dumps(
                        {"quality": quality, "error": "timeout"}).encode(), middle)
        writer.finish()
    assert middle is not None


def test_a_failed_poll_on_the_hosts_clock_neither_paces_nor_cuts_the_replay(live, tmp_path):
    """Its publish time is the host's (the PLC gave none): paced on it, a replay at a given
    speed would sleep for the months between the two clocks."""
    log = tmp_path / "with_failed_poll.mcap"
    _with_failed_poll(live["logs"], log)
    pubs = [pub for t, m, _, pub in read_messages([log]) if t == THERMOCOUPLES and "error" not in m]
    speed = (pubs[-1] - pubs[0]) / 1e9 / 2.0  # two seconds of wall time
    out = tmp_path / "paced.mcap"
    proc = subprocess.run([sys.executable, "-m", "furnace_daq.cli", "replay", str(log),
                           "--out", str(out), "--speed", f"{speed:g}"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert_same_timeline([m for t, m, _, _ in read_messages([out]) if t == MODEL_PARAMETERS],
                         live_params(live))
