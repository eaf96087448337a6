"""The daemon side on another furnace: the six-zone ladder furnace (config/furnaces/six-zone.yaml)
served by the simulated PLC through its derived register map, polled and logged by the
daemon, exported, fitted, refitted online and replayed; and the paper's furnace, the default,
still exactly CONTRACTS.md section 3.

Known truth: the six-zone scenario's parameters (config/scenarios/six_zone_heatup.yaml)."""

from __future__ import annotations

import asyncio
import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from daq_processes import start_daemon, start_simplc, stop
from logcheck import check_files
from test_mbpoll import mbpoll

from furnace_daq.daqconfig import RefitConfig, load_config, parse_config
from furnace_daq.gatewayconfig import gateway_yaml
from furnace_daq.logmeta import build_metadata
from furnace_daq.logplayer import LogPlayer
from furnace_daq.mcaplog import LogWriter
from furnace_daq.plantlog import write_run
from furnace_daq.refit import RefitChain, WindowCutter
from furnace_daq.registers import BitRange, Point
from furnace_daq.replay import replay
from furnace_daq.servedmap import ServedMap
from furnace_daq.simplc import SimPLC
from furnace_model.config import Node, parse_yaml
from furnace_model.errors import ConfigError, DataError
from furnace_model.log.read import log_furnace, read_messages
from furnace_model.log.schema import (
    AMBIENT,
    BURNERS,
    MODEL_PARAMETERS,
    THERMOCOUPLES,
    param_names,
)
from furnace_model.records import load_experiment, load_experiments
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.furnacefile import load_furnace
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
SIX_FILE = ROOT / "config" / "furnaces" / "six-zone.yaml"
SIX_SCENARIO = ROOT / "config" / "scenarios" / "six_zone_heatup.yaml"
SIX_CONFIG = ROOT / "config" / "gateway-six-zone.yaml"
SIX = load_furnace(SIX_FILE)


# -- the register map ------------------------------------------------------------------------

def test_the_paper_derived_map_is_contracts_section_3():
    tc = tuple(Point(s, "input", i, "int16", scale=0.1, sentinels=(32767.0,))
               for i, s in enumerate(("soak_1", "soak_2", "heat_1", "heat_2", "preheat_1",
                                      "preheat_2")))
    want = ServedMap(tc, Point("t_air", "input", 6, "int16", scale=0.1),
                     Point("clock", "input", 7, "uint32", word_order="big"),
                     Point("heartbeat", "input", 9, "uint16"),
                     (BitRange("soak", "discrete", 0, 10), BitRange("heat", "discrete", 10, 8),
                      BitRange("preheat", "discrete", 18, 8)), PAPER)
    assert ServedMap.default(PAPER) == ServedMap.default(PAPER) == want
    assert ServedMap.default(PAPER).sizes() == {"input": 10, "holding": 1, "discrete": 26,
                                           "coil": 26}
    # the config written for the paper's description reads what config/gateway.yaml reads
    shipped = load_config(ROOT / "config" / "gateway.yaml")
    written = parse_config(parse_yaml(gateway_yaml(PAPER, "furnaces/paper.yaml"),
                                      str(ROOT / "config" / "written.yaml")))
    assert written.furnace == PAPER
    assert ServedMap.of_config(written) == ServedMap.of_config(shipped)
    assert written.can.frames == shipped.can.frames


def test_the_six_zone_map_follows_the_rule_and_the_shipped_config_is_it():
    m = ServedMap.default(SIX)
    n = len(SIX.sensors)
    assert n == 11
    assert [(p.name, p.address) for p in m.thermocouples] == \
        [(s, i) for i, s in enumerate(SIX.sensors)]
    assert (m.ambient.address, m.clock.address, m.heartbeat.address) == (n, n + 1, n + 3)
    assert [(b.name, b.address, b.count) for b in m.burners] == [
        ("soak_top", 0, 6), ("soak_bottom", 6, 4), ("heat_top", 10, 8), ("heat_bottom", 18, 6),
        ("preheat_top", 24, 4), ("preheat_bottom", 28, 2)]
    # config/gateway-six-zone.yaml is what `furnace-daq config` writes for the description
    assert SIX_CONFIG.read_text() == gateway_yaml(SIX, "furnaces/six-zone.yaml")
    config = load_config(SIX_CONFIG)
    assert config.furnace == SIX
    served = ServedMap.of_config(config)
    strip = lambda p: replace(p, lo=None, hi=None)  # noqa: E731 - the config adds ranges
    assert tuple(map(strip, served.thermocouples)) == m.thermocouples
    assert served.burners == m.burners
    assert [f.start_bit for f in config.can.frames.values()] == [0, 6, 10, 18, 24, 28]


def six_doc() -> dict:
    return yaml.safe_load(SIX_CONFIG.read_text())


def _drop(d: dict, *path: str) -> dict:
    node = d
    for key in path[:-1]:
        node = node[key]
    del node[path[-1]]
    return d


@pytest.mark.parametrize("change, key, words", [
    (lambda d: _drop(d, "thermocouples", "heat_top_3"), "thermocouples.heat_top_3",
     "required key is missing: thermocouple 'heat_top_3' of furnace 'six-zone'"),
    (lambda d: d["thermocouples"].update(soak_bottom_2={"address": 40}),
     "thermocouples.soak_bottom_2", "furnace 'six-zone' has no thermocouple 'soak_bottom_2'"),
    (lambda d: _drop(d, "burners", "modbus", "preheat_bottom"),
     "burners.modbus.preheat_bottom", "required key is missing: zone 'preheat_bottom'"),
    (lambda d: d["burners"]["modbus"].update(soak={"address": 40}), "burners.modbus.soak",
     "furnace 'six-zone' has no zone 'soak'"),
    (lambda d: d["burners"]["can"].update(heat={"id": 0x181, "start_bit": 0}),
     "burners.can.heat", "has no zone 'heat'"),
    (lambda d: d.update(furnace="nowhere.yaml"), "furnace", "no furnace description"),
    (lambda d: d.update(write_back={"enabled": True, "allow": [[100, 101]],
                                    "params": {"a": {"address": 100}}}),
     "write_back.params.a", "not a parameter of the model of furnace 'six-zone'"),
    (lambda d: _drop(d, "furnace"), "thermocouples.soak_top_1",
     "furnace 'paper' has no thermocouple 'soak_top_1'"),
])
def test_a_map_that_does_not_match_the_furnace_is_a_config_error(tmp_path, change, key, words):
    doc = six_doc()
    doc["furnace"] = str(SIX_FILE)
    change(doc)
    path = tmp_path / "gw.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert f"{path}: {key}: " in str(err.value) and words in str(err.value), str(err.value)


def test_the_commands_refuse_a_mismatch_in_one_line(tmp_path, capsys):
    from furnace_daq.cli import main

    doc = six_doc()
    doc["furnace"] = str(SIX_FILE)
    del doc["thermocouples"]["soak_bottom_1"]
    bad = tmp_path / "gw.yaml"
    bad.write_text(yaml.safe_dump(doc))
    assert main(["check", "--config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "thermocouples.soak_bottom_1: required key" in err
    # a scenario of the paper's furnace is not served as the six-zone furnace
    assert main(["sim-plc", "--scenario", str(ROOT / "config" / "scenarios" /
                                              "paper_exp1.yaml"), "--furnace", str(SIX_FILE),
                 "--duration", "0.1", "--port", "0"]) == 2
    assert "not the furnace 'six-zone'" in capsys.readouterr().err
    # a config relative to its own directory finds its furnace; `config` writes one
    out = tmp_path / "sub" / "gw.yaml"
    out.parent.mkdir()
    assert main(["config", "--furnace", str(SIX_FILE), "--out", str(out)]) == 0
    assert load_config(out).furnace == SIX


# -- on loopback: sim-plc serves, the daemon polls and logs ------------------------------------

def quiet_scenario(tmp_path: Path) -> Path:
    """The six-zone heat-up without thermocouple noise or bias: every logged reading is the
    plant's, to the register's 0.1 degC."""
    doc = yaml.safe_load(SIX_SCENARIO.read_text())
    doc["furnace"] = str(SIX_FILE)
    doc["sensors"] = {"noise_sd_c": 0.0, "bias_sd_c": 0.0}
    path = tmp_path / "quiet.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_sim_plc_serves_the_six_zone_furnace_and_the_daemon_logs_it(tmp_path):
    scenario = load_scenario(quiet_scenario(tmp_path))
    doc = six_doc()
    doc["furnace"] = str(SIX_FILE)
    doc["refit"]["enabled"] = False

    async def run():
        plc = SimPLC(scenario, speed=1200.0, port=0, scan_s=0.05)
        assert plc.served == ServedMap.default(SIX)
        await plc.start()
        try:
            doc["plc"].update(port=plc.port, timeout_s=0.5)
            cfg = replace(parse_config(Node(doc, str(SIX_CONFIG))), poll_period_s=0.05,
                          stale_after_s=1.0)
            daemon, task = start_daemon(cfg, tmp_path / "logs", None)
            await asyncio.sleep(3.0)
            async with asyncio.timeout(60):  # and 21 polls, however busy the host
                while daemon.counters.ok_polls <= 20:
                    await asyncio.sleep(0.02)
            daemon.stop()
            return await task
        finally:
            await plc.stop()

    counters = asyncio.run(run())
    files = sorted((tmp_path / "logs").glob("*.mcap"))
    counts, problems = check_files(files)
    assert problems == [] and counts[THERMOCOUPLES] == counters.ok_polls > 20, counts
    assert log_furnace(files) == SIX
    msgs = list(read_messages(files, (THERMOCOUPLES, BURNERS, AMBIENT)))
    tc = [(m, pub) for t, m, _, pub in msgs if t == THERMOCOUPLES]
    assert all(set(m["quality"]) == set(SIX.sensors) for m, _ in tc)
    seconds = np.array([m["plc_seconds"] for m, _ in tc])
    truth = Plant.from_scenario(scenario).run(scenario.inputs(), seconds / 60.0,
                                              scenario.initial_c)
    logged = np.array([[m[s] for s in SIX.sensors] for m, _ in tc])
    assert np.max(np.abs(logged - np.round(truth.tc * 10) / 10)) <= 0.1 + 1e-9
    burners = [m for t, m, _, _ in msgs if t == BURNERS]
    assert all([len(m[z]) for z in SIX.zones] == list(SIX.burners) for m in burners)
    counts_at = [[m[f"count_{z}"] for z in SIX.zones] for m in burners]
    agree = np.mean([np.array_equal(c, scenario.burners_at(s / 60.0))
                     for c, s in zip(counts_at, seconds, strict=True)])
    assert agree > 0.9
    # sim-plc --from-log: the log alone says its furnace and serves it again
    player = LogPlayer(files)
    assert player.furnace == SIX
    values = player.values_at(int(seconds[5] - seconds[0]))
    assert len(values.thermocouples) == 11 and len(values.burners) == sum(SIX.burners)


# -- a whole heat-up as the daemon logs it: export, fit, refit, replay ------------------------

@pytest.fixture(scope="module")
def heatup(tmp_path_factory):
    """The six-zone scenario's 3300-minute heat-up at 1-minute samples, logged with the
    daemon's topics and metadata (furnace_daq.plantlog), and its export."""
    tmp = tmp_path_factory.mktemp("six")
    scenario = load_scenario(SIX_SCENARIO)
    run = Plant.from_scenario(scenario, seed=1).run_scenario(scenario)
    log = LogWriter(tmp / "logs", flush_interval_s=60.0,
                    metadata=build_metadata(None, furnace=SIX, software_version="t", host="h"))
    write_run(run, log)
    log.close()
    files = sorted((tmp / "logs").glob("*.mcap"))
    from furnace_daq.cli import main

    export = tmp / "export.csv"
    assert main(["logs", "export", str(tmp / "logs"), "--out", str(export)]) == 0
    return {"scenario": scenario, "run": run, "files": files, "export": export, "tmp": tmp}


def assert_recovers(params: dict, ci95: dict, truth: dict) -> None:
    for name, want in truth.items():
        assert params[name] == pytest.approx(want, rel=0.02), name
        lo, hi = ci95[name]
        assert lo <= want <= hi, (name, lo, want, hi)


def test_the_log_exports_the_furnace_columns(heatup):
    """(Every message of a daemon's six-zone log is validated strictly on loopback above.)"""
    n = sum(1 for _ in read_messages(heatup["files"], (THERMOCOUPLES,)))
    assert n == heatup["run"].t_min.size
    head = heatup["export"].read_text().splitlines()[0].split(",")
    assert head == ["timestamp", *SIX.tc_columns, *SIX.burner_columns, "t_air"]


def test_fit_on_the_export_and_on_the_log_recovers_the_parameters(heatup, capsys):
    from furnace_model.cli import main

    truth = heatup["scenario"].params
    out = heatup["tmp"] / "fit.json"
    assert main(["fit", str(heatup["export"]), "--furnace", str(SIX_FILE), "--json",
                 str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["furnace"] == "six-zone" and set(doc["params"]) == set(param_names(SIX))
    assert_recovers(doc["params"], doc["ci95"], truth)
    # the log read directly: the same rows as its export, the same fit
    from_log = load_experiments([heatup["tmp"] / "logs"], furnace=SIX)[0]
    from_csv = load_experiment(heatup["export"], furnace=SIX)
    assert from_log.furnace == SIX and len(from_log) == len(from_csv)
    np.testing.assert_allclose(from_log.tc, from_csv.tc, atol=1e-3)
    out2 = heatup["tmp"] / "fit_log.json"
    assert main(["fit", str(heatup["tmp"] / "logs"), "--furnace", str(SIX_FILE), "--json",
                 str(out2)]) == 0
    doc2 = json.loads(out2.read_text())
    assert_recovers(doc2["params"], doc2["ci95"], truth)
    # without --furnace the log's furnace is not taken for the paper's
    with pytest.raises(DataError, match="the log is of furnace 'six-zone'"):
        load_experiments([heatup["tmp"] / "logs"], furnace=PAPER)
    capsys.readouterr()


def test_the_online_refit_fits_the_network(heatup):
    """The refit pipeline's windows of the six-zone log, fitted in this process: the
    /model/parameters message carries the network's parameters and validates against the
    furnace's schema; the last window recovers them."""
    cfg = RefitConfig(period_s=12 * 3600, window_s=36 * 3600)
    cutter, chain = WindowCutter(cfg, 30.0, furnace=SIX), RefitChain(cfg, 30.0, furnace=SIX)
    windows = [w for t, m, _, pub in read_messages(heatup["files"],
                                                   (THERMOCOUPLES, BURNERS, AMBIENT))
               for w in cutter.feed(t, m, pub)]
    msg, events = chain.process(windows[-1])
    msg = msg.to_json()
    assert msg["status"] == "ok" and events == [], msg.get("detail")
    assert set(msg["ci95"]) == set(param_names(SIX)) and set(msg["rmse_c"]) == set(SIX.zones)
    assert_recovers(msg, msg["ci95"], heatup["scenario"].params)
    from logcheck import validator

    from furnace_model.log.schema import topics

    schema = json.loads(topics(SIX)[MODEL_PARAMETERS].schema_bytes())
    assert list(validator(schema).iter_errors(json.loads(json.dumps(msg)))) == []


# -- live refits and their replay (slow: a refit worker, twice) --------------------------------

@pytest.mark.slow
def test_live_refits_of_the_six_zone_furnace_equal_their_replay(tmp_path):
    scenario = load_scenario(SIX_SCENARIO)
    doc = six_doc()
    doc["furnace"] = str(SIX_FILE)
    doc["clock"]["epoch"] = str(scenario.start_time.isoformat())
    doc["refit"] = {"period_s": 7200, "window_s": 6 * 3600, "step_s": 120,
                    "max_gap_fraction": 0.3, "budget_s": 20, "state_dir": str(tmp_path / "st")}
    hours, speed = 14, 1500.0  # a poll per 75 simulated s: most 2-min bins hold two
    seen: list[dict] = []

    async def run():
        plc = SimPLC(scenario, speed=speed, port=0, seed=1, scan_s=0.05)
        await plc.start()
        try:
            doc["plc"].update(port=plc.port, timeout_s=0.2)
            cfg = replace(parse_config(Node(doc, str(SIX_CONFIG))), poll_period_s=0.05,
                          stale_after_s=1.0)
            _, task = start_daemon(cfg, tmp_path / "logs", hours * 3600 / speed + 0.5,
                                   on_model=seen.append)
            await task
        finally:
            await plc.stop()

    asyncio.run(run())
    files = sorted((tmp_path / "logs").glob("*.mcap"))
    counts, problems = check_files(files)
    assert problems == [], problems
    live = [m for t, m, _, _ in read_messages(files, (MODEL_PARAMETERS,))]
    assert live == seen and sum(m["status"] == "ok" for m in live) >= 3, \
        [m.get("detail") for m in live]
    names = param_names(SIX)
    assert all(set(names) <= set(m) for m in live if m["status"] == "ok")
    got = [m.to_json() for m in replay(files, None, tmp_path / "replay.mcap")]
    # a window cut as the daemon stopped may be left unfitted live (refit_abandoned)
    assert len(live) <= len(got) <= len(live) + 1
    assert [(m["window_end"], m["status"]) for m in got[:len(live)]] == \
        [(m["window_end"], m["status"]) for m in live]
    for g, w in zip(got, live, strict=False):
        for p in names:
            assert (g.get(p) is None) == (w.get(p) is None)
            if w.get(p) is not None:
                assert g[p] == pytest.approx(w[p], rel=1e-6), (w["window_end"], p)
    counts, problems = check_files([tmp_path / "replay.mcap"])
    assert problems == [] and counts[MODEL_PARAMETERS] == len(got)


@pytest.mark.skipif(shutil.which("mbpoll") is None,
                    reason="mbpoll not installed (make system-deps)")
def test_mbpoll_reads_the_six_zone_map(tmp_path):
    """A Modbus master we did not write reads the derived map as documented."""
    path = quiet_scenario(tmp_path)
    scenario = load_scenario(path)
    proc, port = start_simplc("--scenario", str(path), "--furnace", str(SIX_FILE),
                              "--speed", "60")
    try:
        regs = mbpoll(port, "-t", "3", "-r", "1", "-c", "15")     # FC4
        burners = mbpoll(port, "-t", "1", "-r", "1", "-c", "30")  # FC2
    finally:
        assert stop(proc) == 0
    seconds = (regs[12] << 16) | regs[13]  # UINT32, high word first, at n+1
    assert 0 <= seconds < 5 * 60 and regs[14] > 0
    run = Plant.from_scenario(scenario).run(scenario.inputs(), np.array([seconds / 60.0]),
                                            scenario.initial_c)
    np.testing.assert_array_equal(regs[:11], np.round(run.tc[0] * 10).astype(int))
    assert regs[11] == round(scenario.t_air_c * 10)
    # the first step: soak_top 2, soak_bottom 2, heat_top 4, heat_bottom 0, preheat_top 0,
    # preheat_bottom 1 (of 6/4/8/6/4/2), the first burners of each zone firing
    assert burners == [1, 1, 0, 0, 0, 0] + [1, 1, 0, 0] + [1] * 4 + [0] * 4 + [0] * 6 \
        + [0] * 4 + [1, 0]


@pytest.mark.slow
def test_make_demo_with_the_six_zone_furnace(tmp_path):
    """`make demo FURNACE=config/furnaces/six-zone.yaml`: the whole chain on the other
    furnace; the closing table has every network parameter, the whole run's fit within 2.5%
    of the truth and the last online refit's within 5%."""
    import re
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "furnace_daq.demo", "--out", str(tmp_path),
                           "--furnace", "config/furnaces/six-zone.yaml"],
                          capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    logs = sorted((tmp_path / "logs").glob("*.mcap"))
    counts, problems = check_files(logs)
    assert problems == [] and counts[MODEL_PARAMETERS] > 0
    assert log_furnace(logs) == SIX
    cell = r"([-+.\deE]+)\s+([-+][\d.]+)% \(±[\d.e+]+%\)"
    rows = {m.group(1): (float(m.group(4)), float(m.group(6)))
            for m in re.finditer(rf"^\s+(\S+)\s+([-+.\deE]+)\s+{cell}\s+{cell}", done.stdout,
                                 re.M)}
    assert set(rows) == set(param_names(SIX)), done.stdout[-3000:]
    assert all(abs(online) < 5 and abs(whole) < 2.5 for online, whole in rows.values()), rows
