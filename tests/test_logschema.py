"""The log's schemas as Foxglove and a strict validator read them, the metadata record of
every file, CRCs, and the /log lines (CONTRACTS.md section 2; docs/logs.md). The full chain,
a daemon's real log validated message by message, is in test_replay.py (its module fixture)."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import pytest
from logcheck import check_files, foxglove_problems, problems
from mcap.reader import make_reader
from mcap.records import DataEnd
from mcap.stream_reader import StreamReader

from furnace_daq.daemon import EVENT_PRIORITY
from furnace_daq.logmeta import build_metadata, read_metadata, recorded_refit
from furnace_daq.mcaplog import LogWriter, finished_files
from furnace_model.log.schema import (
    AMBIENT,
    DAQ_EVENTS,
    DAQ_STATUS,
    LOG,
    LOG_LEVELS,
    MODEL_PARAMETERS,
    THERMOCOUPLES,
    absent,
    plc_time,
    time_ns,
    topics,
)
from furnace_model.simulation.furnace import PAPER

TOPICS = topics(PAPER)
"""The paper's furnace's topics, which these tests check."""

T0 = 1_772_409_600_000_000_000  # 2026-03-02T00:00:00Z


@pytest.mark.parametrize("name", list(TOPICS))
def test_every_schema_is_one_foxglove_can_parse(name: str) -> None:
    schema = TOPICS[name].schema
    assert foxglove_problems(schema) == []
    assert json.loads(TOPICS[name].schema_bytes())["$schema"].endswith("2020-12/schema")


def test_the_foxglove_rules_catch_a_nullable_union() -> None:
    bad = {"type": "object", "properties": {"x": {"type": ["number", "null"]}}}
    assert foxglove_problems(bad) == ["/x: type ['number', 'null']"]


def test_a_null_reading_and_an_undeclared_field_are_caught() -> None:
    schema = json.loads(TOPICS[THERMOCOUPLES].schema_bytes())
    good = {"soak_1": 1012.5, "quality": {s: "ok" for s in PAPER.sensors},
            "plc_time": plc_time(T0 + 1_500_000_000)}
    assert problems(THERMOCOUPLES, schema, good) == []
    null = {**good, "soak_1": None}
    assert problems(THERMOCOUPLES, schema, null) == \
        [f"{THERMOCOUPLES}: /soak_1: None is not of type 'number'"]
    extra = {**good, "soak_9": 3.0}
    assert problems(THERMOCOUPLES, schema, extra) and "soak_9" in problems(
        THERMOCOUPLES, schema, extra)[0]
    # before the first model a..f are absent, not null
    params = json.loads(TOPICS[MODEL_PARAMETERS].schema_bytes())
    first = {"status": "insufficient_excitation", "window_start": "x", "window_end": "y",
             "ci95": {}, "rmse_c": {}}
    assert problems(MODEL_PARAMETERS, params, first) == []
    assert problems(MODEL_PARAMETERS, params, {**first, "a": None})
    assert problems(MODEL_PARAMETERS, params, {**first, "zone_offsets_c": None})


def test_absent_drops_nulls_in_objects_not_in_arrays() -> None:
    assert absent({"a": None, "b": {"c": None, "d": 1}, "e": [None, 2]}) == \
        {"b": {"d": 1}, "e": [None, 2]}


def test_plc_time_is_foxgloves_time_and_round_trips() -> None:
    assert plc_time(T0 + 5) == {"sec": T0 // 10**9, "nsec": 5}
    assert plc_time(-1) == {"sec": -1, "nsec": 999_999_999}
    assert time_ns(plc_time(T0 + 123_456_789)) == T0 + 123_456_789


def _write(w: LogWriter, t_ns: int) -> None:
    w.write(THERMOCOUPLES, {"quality": {s: "comm_error" for s in PAPER.sensors}, "error": "timeout"},
            t_ns)
    w.write(AMBIENT, {"t_air": 25.0, "quality": "ok", "plc_time": plc_time(t_ns)}, t_ns)


def test_every_file_carries_the_metadata_record_and_crcs(tmp_path) -> None:
    """Rotated files each carry the record; the data section's CRC is written; the recorded
    config drops secrets; the messages and the /log lines validate."""
    meta = build_metadata({"plc": {"host": "10.0.0.5", "password": "hunter2"},
                           "api_token": "x", "refit": {"period_s": 600.0}},
                          furnace=PAPER, software_version="9.9.9", host="gw-1")
    w = LogWriter(tmp_path, rotate_s=10.0, metadata=meta, event_priority=EVENT_PRIORITY)
    for k in range(3):
        _write(w, T0 + k * 10 * 10**9)
    w.write(DAQ_STATUS, {"state": "connected", "detail": "up", "polls": 3}, T0 + 1)
    w.write(DAQ_STATUS, {"state": "connected", "detail": "up", "polls": 4}, T0 + 2)
    w.write(DAQ_EVENTS, {"kind": "missed_tick", "detail": "2 skipped", "skipped": 2}, T0 + 3)
    w.close()
    files = finished_files(tmp_path, "furnace")
    assert len(files) == 3
    for f in files:
        with open(f, "rb") as fh:
            reader = make_reader(fh)
            records = list(reader.iter_metadata())
            assert [r.name for r in records] == ["furnace-daq"]
            got = records[0].metadata
            assert reader.get_summary() is not None  # finished: read through its index
        assert got["software_version"] == "9.9.9" and got["host"] == "gw-1"
        furnace = json.loads(got["furnace"])
        assert [(z["name"], z["burners"], len(z["thermocouples"])) for z in furnace["zones"]] \
            == [("soak", 10, 2), ("heat", 8, 2), ("preheat", 8, 2)]
        config = json.loads(got["config"])
        assert config == {"plc": {"host": "10.0.0.5"}, "refit": {"period_s": 600.0}}
        with open(f, "rb") as fh:
            ends = [r for r in StreamReader(fh, validate_crcs=True).records
                    if isinstance(r, DataEnd)]
        assert len(ends) == 1 and ends[0].data_section_crc != 0
    assert read_metadata(files) == got
    counts, found = check_files(files)
    assert found == []
    assert counts[LOG] == 2  # one status change (the repeat is no news) and one event
    lines = []
    for f in files:
        with open(f, "rb") as fh:
            lines += [json.loads(m.data) for _, _, m in make_reader(fh).iter_messages(
                topics=[LOG])]
    assert lines[0] == {"timestamp": plc_time(T0 + 1), "level": LOG_LEVELS["info"],
                        "message": "connected: up", "name": "furnace-daq", "file": DAQ_STATUS,
                        "line": 0}
    assert lines[1]["level"] == LOG_LEVELS["warning"] and lines[1]["file"] == DAQ_EVENTS


def test_daemon_metadata_holds_the_config_host_and_refit() -> None:
    from furnace_daq.daqconfig import load_config

    cfg = load_config(Path(__file__).resolve().parents[1] / "config" / "gateway.yaml")
    meta = build_metadata(cfg)
    assert meta["host"] == socket.gethostname() and meta["software_version"]
    config = json.loads(meta["config"])
    assert config["plc"]["port"] == cfg.plc.port
    assert config["poll_period_s"] == cfg.poll_period_s
    assert recorded_refit(meta) == (None if cfg.refit is None else json.loads(meta["refit"]))
    assert recorded_refit({"refit": "null"}) is None and recorded_refit(None) is None
