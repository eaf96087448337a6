"""The daemon side of a furnace fired at modulated rates, pulse-fired and with a measured
disturbance (config/furnaces/modulated.yaml): its register map (heat:, disturbances:,
signals:), the simulated PLC serving its scenario, the daemon logging /furnace/heat,
/furnace/disturbances and /furnace/signals, the export's row means against the scenario,
and the paper's log left as it was.

Known truth: config/scenarios/modulated_production.yaml, its schedule compressed thirty
times and its pulses a minute long, so that a few wall seconds on loopback hold many steps
and whole pulse cycles."""

from __future__ import annotations

import asyncio
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from daq_processes import start_daemon
from logcheck import check_files, validator

from furnace_daq.check import check, format_report
from furnace_daq.daqconfig import load_config, parse_config
from furnace_daq.gatewayconfig import gateway_yaml
from furnace_daq.logmeta import build_metadata
from furnace_daq.logplayer import LogPlayer
from furnace_daq.messagebuild import MessageBuilder
from furnace_daq.refit import RefitChain, RefitConfig
from furnace_daq.servedmap import ServedMap
from furnace_daq.simplc import SimPLC, pulse_states
from furnace_daq.sources import Sample
from furnace_model.config import Node
from furnace_model.errors import ConfigError
from furnace_model.experiment import read_table
from furnace_model.heldmeans import row_edges
from furnace_model.log.messages import Burners, Disturbances, Heat, Signals
from furnace_model.log.read import log_furnace, read_messages
from furnace_model.log.resample import Resampler
from furnace_model.log.schema import (
    BURNERS,
    DISTURBANCES,
    HEAT,
    SIGNALS,
    THERMOCOUPLES,
    SignalField,
    topics,
)
from furnace_model.records import load_experiments
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.furnacefile import load_furnace
from furnace_model.simulation.plant import row_means
from furnace_model.simulation.scenario import load_scenario, pulse_fired

ROOT = Path(__file__).resolve().parents[1]
MOD_FILE = ROOT / "config" / "furnaces" / "modulated.yaml"
MOD_SCENARIO = ROOT / "config" / "scenarios" / "modulated_production.yaml"
MOD = load_furnace(MOD_FILE)
SIGNALS_YAML = {"o2_pct": {"table": "input", "address": 16, "type": "int16", "scale": 0.01,
                           "range": [0, 21], "unit": "%"},
                "door_open": {"table": "discrete", "address": 8, "unit": ""}}


def mod_doc() -> dict:
    """The config `furnace-daq config` writes for the modulated furnace, with two signals."""
    doc = yaml.safe_load(gateway_yaml(MOD, str(MOD_FILE)))
    doc["signals"] = json.loads(json.dumps(SIGNALS_YAML))
    return doc


def parsed(doc: dict):
    return parse_config(Node(doc, "mod.yaml"))


# -- the register map ------------------------------------------------------------------------

def test_the_default_map_adds_rates_and_disturbances_after_the_existing_registers():
    m = ServedMap.default(MOD)
    assert [(p.name, p.address, p.dtype) for p in m.heat] == [
        ("heat.soak", 10, "float32"), ("heat.heat", 12, "float32")]
    assert [(p.name, p.address, p.dtype) for p in m.disturbances] == [
        ("disturbances.throughput", 14, "float32")]
    assert [(b.name, b.address, b.count) for b in m.burners] == [("preheat", 0, 8)]
    assert m.sizes() == {"input": 16, "holding": 1, "discrete": 8, "coil": 8}
    # the written config reads that map, each point in the range of its description
    config = parsed(yaml.safe_load(gateway_yaml(MOD, str(MOD_FILE))))
    assert config.furnace == MOD and config.signals == ()
    served = ServedMap.of_config(config)
    strip = lambda p: replace(p, lo=None, hi=None)  # noqa: E731
    assert tuple(map(strip, served.heat)) == m.heat
    assert tuple(map(strip, served.disturbances)) == m.disturbances
    assert [(p.lo, p.hi) for p in (*served.heat, *served.disturbances)] == [
        (0, 100), (0, 600), (0, 250)]
    assert served.burners == m.burners
    assert list(config.can.frames) == ["preheat"]


def test_signals_are_analog_points_or_bits_with_a_unit():
    doc = mod_doc()
    doc["signals"]["flag"] = {"table": "holding", "address": 3, "bit": 4, "unit": ""}
    config = parsed(doc)
    by_name = {s.name: s for s in config.signals}
    assert (by_name["o2_pct"].unit, by_name["o2_pct"].bit) == ("%", False)
    assert by_name["o2_pct"].item.scale == 0.01
    assert by_name["door_open"].bit and by_name["door_open"].item.table == "discrete"
    assert by_name["flag"].bit and (by_name["flag"].item.table, by_name["flag"].item.bit) == \
        ("holding", 4)
    assert config.key_paths()["signals.o2_pct"] == "signals.o2_pct"
    assert config.key_paths()["heat.soak"] == "heat.soak"


def _drop(doc: dict, *path: str) -> dict:
    node = doc
    for key in path[:-1]:
        node = node[key]
    del node[path[-1]]
    return doc


@pytest.mark.parametrize("change, key, words", [
    (lambda d: d["heat"].update(preheat={"address": 30}), "heat.preheat",
     "zone 'preheat' of furnace 'modulated' is pulse-fired"),
    (lambda d: _drop(d, "heat", "soak"), "heat.soak",
     "required key is missing: rate-fired zone 'soak' of furnace 'modulated'"),
    (lambda d: d["heat"].update(furnace_top={"address": 30}), "heat.furnace_top",
     "furnace 'modulated' has no rate-fired zone 'furnace_top'"),
    (lambda d: d["disturbances"].update(charging={"address": 30}), "disturbances.charging",
     "furnace 'modulated' has no disturbance 'charging'"),
    (lambda d: _drop(d, "disturbances", "throughput"), "disturbances.throughput",
     "required key is missing: disturbance 'throughput' of furnace 'modulated'"),
    (lambda d: _drop(d, "disturbances"), "disturbances.throughput",
     "required key is missing: disturbance 'throughput'"),
    (lambda d: d["burners"]["modbus"].update(soak={"address": 20}), "burners.modbus.soak",
     "is fired at a rate (%)"),
    (lambda d: d["signals"].update(throughput={"address": 40, "unit": "t/h"}),
     "signals.throughput", "collides with disturbance 'throughput' of furnace 'modulated'"),
    (lambda d: d["signals"].update(t_air={"address": 40, "unit": "degC"}), "signals.t_air",
     "collides with a column of the tabular contract"),
    (lambda d: d["signals"].update(heat_flow={"address": 40, "unit": "kW"}),
     "signals.heat_flow", "collides with the heat_* columns"),
    (lambda d: d["signals"].update(quality={"address": 40, "unit": ""}), "signals.quality",
     "collides with a field the reading topics carry"),
    (lambda d: d["signals"].update(O2_PCT={"address": 40, "unit": "%"}), "signals.O2_PCT",
     "collides with signal 'o2_pct'"),
    (lambda d: _drop(d, "signals", "o2_pct", "unit"), "signals.o2_pct.unit",
     "required key is missing"),
    (lambda d: d["signals"].update(o2_pct={"address": 14, "unit": "%"}),
     "signals.o2_pct", "overlaps disturbances.throughput"),
])
def test_a_bad_map_is_a_config_error_naming_the_key(tmp_path, change, key, words):
    doc = mod_doc()
    change(doc)
    path = tmp_path / "gw.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert f"{path}: {key}: " in str(err.value) and words in str(err.value), str(err.value)


def test_a_heat_point_on_the_papers_furnace_is_refused():
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["heat"] = {"soak": {"address": 20}}
    with pytest.raises(ConfigError, match=r"heat\.soak: zone 'soak' of furnace 'paper' is "
                                          "fired by burners switched on and off"):
        parse_config(Node(doc, "gw.yaml"))


# -- the paper's log stays as it was ----------------------------------------------------------

def test_the_papers_log_has_its_channels_and_nothing_more():
    shipped = load_config(ROOT / "config" / "gateway.yaml")
    assert list(topics(PAPER)) == ["/furnace/thermocouples", "/furnace/burners",
                                   "/furnace/ambient", "/daq/status", "/daq/events",
                                   "/model/parameters", "/model/events", "/model/diagnosis",
                                   "/log"]
    assert "signals" not in build_metadata(shipped, software_version="t", host="h")
    sample = Sample(values=dict.fromkeys(PAPER.sensors, 500.0) | {"t_air": 20.0},
                    quality=dict.fromkeys([*PAPER.sensors, "t_air"], "ok"),
                    burners={z: [True] * n for z, n in zip(PAPER.zones, PAPER.burners,
                                                           strict=True)})
    messages = MessageBuilder(shipped).readings(sample, 0)
    assert [m.TOPIC for m in messages] == ["/furnace/thermocouples", "/furnace/ambient",
                                           "/furnace/burners"]


# -- topics, resampling, pulses, refit: plain data --------------------------------------------

def test_the_new_topics_validate_and_a_missing_value_is_an_absence():
    signals = (SignalField("o2_pct", "%"), SignalField("door_open", "", bit=True))
    schemas = topics(MOD, signals)
    assert [t for t in schemas if t in (HEAT, DISTURBANCES,
                                                                          SIGNALS)] == [HEAT, DISTURBANCES, SIGNALS]
    messages = {
        HEAT: Heat({"soak": 25.4}, {"soak": "ok", "heat": "comm_error"},
                   {"soak": "%", "heat": "Nm3/h"}, 10**18),
        DISTURBANCES: Disturbances({"throughput": 143.0}, {"throughput": "ok"},
                                   {"throughput": "t/h"}),
        SIGNALS: Signals({"door_open": True}, {"o2_pct": "out_of_range", "door_open": "ok"},
                         {"o2_pct": "%", "door_open": ""}),
    }
    for name, msg in messages.items():
        schema = json.loads(schemas[name].schema_bytes())
        assert list(validator(schema).iter_errors(msg.to_json())) == [], name
    assert messages[HEAT].to_json().get("heat") is None
    back = Signals.from_json(messages[SIGNALS].to_json())
    assert back.values == {"door_open": True} and back.unit == {"o2_pct": "%", "door_open": ""}
    assert back.reading("door_open") == 1.0 and np.isnan(back.reading("o2_pct"))
    bad = {**messages[HEAT].to_json(), "unit": {"soak": "kW", "heat": "Nm3/h"}}
    schema = json.loads(schemas[HEAT].schema_bytes())
    assert list(validator(schema).iter_errors(bad)), "a unit is the description's"


def test_rows_carry_time_means_of_rates_and_the_mean_count_of_pulses():
    """Readings every 10 s for five minutes, a rate step at 90 s, a pulse-fired zone with
    three of its eight burners on for 30 s of each minute: the rows hold the time means from
    each row to the next, as the plant's row means are defined."""
    t0 = pd.Timestamp("2026-05-04T06:00:00Z").value
    resampler = Resampler(60 * 10**9, t0, MOD)
    seconds = np.arange(0, 300, 10)
    soak = np.where(seconds < 90, 20.0, 80.0)
    on = np.where(seconds % 60 < 30, 3, 2)
    throughput = 100.0 + seconds / 10
    door = seconds < 30
    for k, s in enumerate(seconds):
        t = t0 + int(s) * 10**9
        resampler.add(THERMOCOUPLES, {**dict.fromkeys(MOD.sensors, 100.0),
                                      "quality": dict.fromkeys(MOD.sensors, "ok")}, t)
        resampler.add(HEAT, Heat({"soak": float(soak[k]), "heat": 300.0},
                                 {"soak": "ok", "heat": "ok"},
                                 {"soak": "%", "heat": "Nm3/h"}), t)
        resampler.add(DISTURBANCES, Disturbances({"throughput": float(throughput[k])},
                                                 {"throughput": "ok"}, {"throughput": "t/h"}), t)
        resampler.add(BURNERS, Burners.from_states({"preheat": [bool(i < on[k])
                                                                for i in range(8)]},
                                                   "modbus", "ok"), t)
        resampler.add(SIGNALS, Signals({"door_open": bool(door[k])}, {"door_open": "ok"},
                                       {"door_open": ""}), t)
    rows = resampler.table()
    assert np.allclose((rows.t - t0) / 1e9, [25, 85, 145, 205, 265])  # the readings' mean
    row_min = (rows.t - t0) / 60e9
    held = lambda v: row_means(seconds / 60.0, v, row_min)[:, 0]  # noqa: E731
    soak_i, heat_i, preheat_i = (MOD.zones.index(z) for z in ("soak", "heat", "preheat"))
    assert np.allclose(rows.burners[:, soak_i], held(soak))
    # [25, 85) s: 20 throughout; [85, 145): 5 s at 20, 55 s at 80
    assert np.allclose(rows.burners[:2, soak_i], [20.0, 75.0])
    assert np.allclose(rows.burners[:, heat_i], 300.0)
    assert np.allclose(rows.burners[:, preheat_i], held(on))
    assert np.allclose(rows.burners[:4, preheat_i], 2.5)  # whole minutes: the duty
    assert np.allclose(rows.disturbances[:, 0], held(throughput))
    assert np.allclose(rows.signals["door_open"], held(door.astype(float)))
    assert rows.signals["door_open"][0] == pytest.approx(5 / 60)  # on until 30 s


def test_pulse_states_fire_each_burner_for_its_duty_as_the_plant_is_fired():
    furnace, cycle = MOD, 1.0
    mean = 2.35
    t = np.arange(0, 600) / 60.0  # ten cycles at every second
    states = np.array([pulse_states(mean, 8, x + 0.5 / 60, cycle) for x in t])
    assert states.mean(axis=0) == pytest.approx(np.full(8, mean / 8), abs=1 / 60)
    assert set(states.sum(axis=1)) == {2, 3}
    scenario = load_scenario(MOD_SCENARIO)
    fired = pulse_fired(replace(scenario, pulse_cycle_min=cycle).inputs(), furnace, cycle,
                        10.0)
    level = scenario.burners_at(0.0)[2]
    plant = fired.burners[np.searchsorted(fired.t, t + 0.5 / 60, side="right") - 1, 2]
    shown = [sum(pulse_states(level, 8, x + 0.5 / 60, cycle)) for x in t]
    assert np.array_equal(plant, shown)


def test_a_disturbance_gain_of_either_sign_is_a_model():
    chain = RefitChain(RefitConfig(), furnace=MOD)
    assert {"gain_throughput_heat", "gain_throughput_preheat"} <= set(chain.names)
    assert not {"gain_throughput_heat", "gain_throughput_preheat"} & chain.positive
    assert "gain_soak" in chain.positive


# -- on loopback: sim-plc serves the scenario, check reads it, the daemon logs it -----------

def compressed_scenario(tmp_path: Path) -> Path:
    """The production scenario thirty times faster, pulses a minute long, without
    thermocouple noise or bias."""
    doc = yaml.safe_load(MOD_SCENARIO.read_text())
    doc["furnace"] = str(MOD_FILE)
    doc["duration_min"] = doc["duration_min"] / 30
    for step in doc["burners"]["steps"]:
        step["at_min"] = step["at_min"] / 30
    for step in doc["disturbances"]["throughput"]["steps"]:
        step["at_min"] = step["at_min"] / 30
    doc["pulse_cycle_min"] = 1.0
    doc["sensors"] = {"noise_sd_c": 0.0, "bias_sd_c": 0.0}
    path = tmp_path / "compressed.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


SPEED = 120.0
RUN_S = 9.0
POLL_S = 0.047
"""5.64 simulated s: polls fall at every phase of the minute-long pulses, not at a few."""


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """The compressed scenario served by the simulated PLC through the written config's map
    (signals included), read once by `check`, polled and logged by the daemon."""
    tmp = tmp_path_factory.mktemp("modulated")
    scenario = load_scenario(compressed_scenario(tmp))
    doc = mod_doc()
    doc["clock"]["epoch"] = scenario.start_time.isoformat()
    doc["refit"]["enabled"] = False
    cfg = parsed(doc)

    async def run():
        plc = SimPLC(scenario, speed=SPEED, port=0, scan_s=0.02,
                     served=ServedMap.of_config(cfg))
        await plc.start()
        try:
            live = replace(cfg, plc=replace(cfg.plc, port=plc.port, timeout_s=0.5),
                           poll_period_s=POLL_S, stale_after_s=1.0)
            report = await check(live)
            _, task = start_daemon(live, tmp / "logs", RUN_S)
            return report, await task
        finally:
            await plc.stop()

    report, counters = asyncio.run(run())
    files = sorted((tmp / "logs").glob("*.mcap"))
    from furnace_daq.cli import main

    export, parquet = tmp / "export.csv", tmp / "export.parquet"
    for out in (export, parquet):
        assert main(["logs", "export", str(tmp / "logs"), "--out", str(out)]) == 0
    return {"scenario": scenario, "files": files, "export": export, "parquet": parquet,
            "report": report, "counters": counters, "tmp": tmp}


def test_check_reads_and_prints_the_new_points(logged):
    report = logged["report"]
    rows = {p.key: p for p in report.points}
    for key in ("heat.soak", "heat.heat", "disturbances.throughput", "signals.o2_pct",
                "signals.door_open", "burners.modbus.preheat"):
        assert rows[key].ok, (key, rows[key])
    assert float(rows["heat.soak"].value) == pytest.approx(25.4, abs=1e-4)
    assert rows["heat.soak"].where == "input 10-11"
    assert rows["signals.door_open"].value == "on"  # the first two minutes of the hour
    assert 0 <= float(rows["signals.o2_pct"].value) <= 21
    assert "heat.heat" in format_report(report) and report.ok


def test_the_log_carries_the_new_topics_valid_against_their_schemas(logged):
    files = logged["files"]
    counts, problems = check_files(files)
    assert problems == [], problems
    polls = counts[THERMOCOUPLES]
    # every poll made was answered and logged (a tick a busy host skipped is not a poll)
    counters = logged["counters"]
    assert polls == counters.ok_polls == counters.polls > 20, (counts, counters)
    assert counts[HEAT] == counts[DISTURBANCES] == counts[SIGNALS] == counts[BURNERS] == polls
    assert log_furnace(files) == MOD
    heat = [m for _, m, _, _ in read_messages(files, (HEAT,))]
    assert all(m["unit"] == {"soak": "%", "heat": "Nm3/h"} for m in heat)
    assert all(set(m["quality"]) == {"soak", "heat"} for m in heat)
    signals = [m for _, m, _, _ in read_messages(files, (SIGNALS,))]
    assert all(isinstance(m["door_open"], bool) and 0 <= m["o2_pct"] <= 21 for m in signals)
    burners = [m for _, m, _, _ in read_messages(files, (BURNERS,))]
    assert all(set(m) >= {"preheat", "count_preheat"} and "soak" not in m for m in burners)
    # sim-plc --from-log serves them again
    player = LogPlayer(files)
    values = player.values_at(60)
    assert set(values.heat) == {"soak", "heat"} and set(values.disturbances) == {"throughput"}
    assert isinstance(values.signals["door_open"], bool) and len(values.burners) == 8


def _truth(logged) -> tuple[pd.DataFrame, np.ndarray, np.ndarray, np.ndarray]:
    """The export, its rows' times in scenario minutes, and what the plant got over each
    row: each zone's heat input and the throughput, time means as the export's."""
    scenario = logged["scenario"]
    frame = pd.read_csv(logged["export"])
    t = (pd.to_datetime(frame["timestamp"]) - scenario.start_time).dt.total_seconds() \
        .to_numpy() / 60.0
    fired = scenario.plant_inputs()
    return frame, t, row_means(fired.t, fired.burners, t), \
        row_means(fired.t, fired.disturbances, t)[:, 0]


EDGE_S = 10.0
"""Simulated seconds around a change of an input within which a message may still show the
value before it: the PLC clock's second, a scan (2.4 s) and a poll (5.6 s). A busy machine
makes polls late, never their values wrong: each message holds what the PLC served at the
time it is stamped with."""


def _stamped(logged, topic: str) -> tuple[list[dict], np.ndarray]:
    """The topic's messages and their PLC times in scenario minutes."""
    start_ns = logged["scenario"].start_time.value
    rows = list(read_messages(logged["files"], (topic,)))
    return [m for _, m, _, _ in rows], np.array([(pub - start_ns) / 60e9
                                                 for _, _, _, pub in rows])


def _near(t: np.ndarray, changes: np.ndarray) -> np.ndarray:
    """Whether each time lies within EDGE_S of a change."""
    if changes.size == 0:
        return np.zeros(t.size, dtype=bool)
    j = np.clip(np.searchsorted(changes, t), 1, changes.size - 1)
    gap = np.minimum(np.abs(t - changes[j - 1]), np.abs(t - changes[j]))
    return gap * 60.0 <= EDGE_S


def test_every_logged_rate_and_throughput_is_the_scenarios_at_its_plc_time(logged):
    scenario = logged["scenario"]
    steps = scenario.steps_t
    heat, t = _stamped(logged, HEAT)
    dist, td = _stamped(logged, DISTURBANCES)
    assert np.unique(steps[steps < t[-1]]).size >= 5  # steps were logged
    for k, zone in ((0, "soak"), (1, "heat")):
        got = np.array([m[zone] for m in heat])
        want = np.array([scenario.burners_at(x)[k] for x in t])
        off = np.abs(got - want) > 1e-3 * max(1.0, np.abs(want).max())
        assert not np.any(off & ~_near(t, steps)), (zone, t[off & ~_near(t, steps)][:5])
        assert np.mean(~off) > 0.8, zone
    got = np.array([m["throughput"] for m in dist])
    want = np.array([scenario.disturbances_at(x)[0] for x in td])
    off = np.abs(got - want) > 1e-3
    assert not np.any(off & ~_near(td, steps)), td[off & ~_near(td, steps)][:5]


def test_the_export_holds_the_logged_inputs_as_time_means(logged):
    """A row holding no change of an input is the input's value; a row with one lies between
    the values around it (the time mean of what was logged, the last value held in)."""
    frame, t, heat, throughput = _truth(logged)
    assert list(frame.columns) == ["timestamp", *MOD.tc_columns, "heat_soak", "heat_heat",
                                   "burners_preheat", "t_air", "throughput", "o2_pct",
                                   "door_open"]
    assert len(frame) >= 0.5 * RUN_S * SPEED / 60, len(frame)
    scenario = logged["scenario"]
    ends = row_edges(t, 1.0)[1:]  # each row spans to the next, as the export takes it
    for column, topic, series in (
            ("heat_soak", HEAT, lambda x: scenario.burners_at(x)[0]),
            ("heat_heat", HEAT, lambda x: scenario.burners_at(x)[1]),
            ("throughput", DISTURBANCES, lambda x: scenario.disturbances_at(x)[0])):
        _, stamps = _stamped(logged, topic)
        held = np.diff(stamps).max()  # the longest a logged value was held into a row
        got = frame[column].to_numpy()
        for lo, hi, value in zip(t, ends, got, strict=True):
            span = np.linspace(lo - held - EDGE_S / 60, hi, 200)
            around = np.array([series(x) for x in span])
            assert around.min() - 1e-3 <= value <= around.max() + 1e-3, (column, lo, value)
            if np.ptp(around) == 0:
                assert value == pytest.approx(around[0], abs=1e-3), (column, lo)
    assert frame["door_open"].iloc[0] == pytest.approx(1.0) and frame["door_open"].iloc[-1] == 0
    assert frame["o2_pct"].between(0, 21).all()


def test_the_pulse_fired_zones_count_is_its_pulses_and_the_export_its_mean(logged):
    scenario = logged["scenario"]
    burners, t = _stamped(logged, BURNERS)
    fired = scenario.plant_inputs()
    counts = np.array([m["count_preheat"] for m in burners])
    want = fired.burners[np.searchsorted(fired.t, t, side="right") - 1, 2]
    off = counts != want
    assert not np.any(off & ~_near(t, fired.t)), t[off & ~_near(t, fired.t)][:5]
    frame, rows, _, _ = _truth(logged)
    got = frame["burners_preheat"].to_numpy()
    assert (got % 1 != 0).any(), "a mean count, not whole burners"
    # each row a mean of the whole counts the pulses take around the mean counts set
    held = np.diff(t).max()
    for lo, hi, value in zip(rows, row_edges(rows, 1.0)[1:], got, strict=True):
        span = np.linspace(lo - held - EDGE_S / 60, hi, 200)
        levels = np.array([scenario.burners_at(x)[2] for x in span])
        assert np.floor(levels.min()) - 1e-9 <= value <= np.ceil(levels.max()) + 1e-9, lo


def test_fit_reads_the_same_rows_from_the_log_as_from_its_export(logged):
    """`furnace-model fit LOG_DIR` and `fit` on its Parquet export: the same rows, bit for
    bit; on the CSV export to its 0.001."""
    from_log = load_experiments([logged["tmp"] / "logs"], furnace=MOD)[0]
    for export, tol in ((logged["parquet"], 0.0), (logged["export"], 5e-4)):
        table = read_table(export, furnace=MOD)
        assert len(from_log) == len(table)
        for field in ("t_min", "burners", "disturbances", "tc", "t_air"):
            np.testing.assert_allclose(getattr(from_log, field), getattr(table, field),
                                       rtol=0, atol=tol + 1e-9, err_msg=field)


# -- make demo FURNACE=modulated (slow: 48 simulated hours and their refits) -----------------

@pytest.mark.slow
def test_the_demo_of_the_modulated_furnace_fits_the_throughput_gains(tmp_path):
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "furnace_daq.demo", "--furnace", "modulated",
                           "--out", str(tmp_path)], capture_output=True, text=True,
                          timeout=600, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    fit = json.loads((tmp_path / "fit.json").read_text())
    truth = load_scenario(MOD_SCENARIO).params
    for name in ("gain_throughput_heat", "gain_throughput_preheat"):
        lo, hi = fit["ci95"][name]
        assert fit["params"][name] < 0 and lo < truth[name] < hi, (name, fit["params"][name])
    logs = sorted((tmp_path / "logs").glob("*.mcap"))
    counts, problems = check_files(logs)
    assert problems == [] and {HEAT, DISTURBANCES, SIGNALS} <= set(counts), counts
