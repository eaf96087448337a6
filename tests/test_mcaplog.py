"""The MCAP log writer and reader, checked against the real mcap reader on real files."""

from __future__ import annotations

import errno
import json
import math
import os
import re
import time
from pathlib import Path

import numpy as np
import pytest
from logcheck import foxglove_problems
from mcap.reader import make_reader

from furnace_daq import mcaplog
from furnace_daq.mcaplog import LogWriter, finished_files
from furnace_model.log.read import read_messages
from furnace_model.log.salvage import has_footer
from furnace_model.log.schema import topics
from furnace_model.simulation.furnace import PAPER

TOPICS = topics(PAPER)
"""The paper's furnace's topics, which these tests check."""

T0 = 1_772_431_200 * 10**9  # 2026-03-02T06:00:00Z
S = 10**9


def tc_msg(i: int) -> dict:
    return {**{s: 800.0 + i + k / 10 for k, s in enumerate(PAPER.sensors)},
            "quality": dict.fromkeys(PAPER.sensors, "ok")}


EXAMPLES = {
    "/furnace/thermocouples": {**{k: v for k, v in tc_msg(1).items() if k != "soak_2"},
                               "quality": {**dict.fromkeys(PAPER.sensors, "ok"), "soak_2": "sensor_open"}},
    "/furnace/burners": {"soak": [True] * 4 + [False] * 6, "heat": [False] * 8,
                         "preheat": [True] * 8, "count_soak": 4, "count_heat": 0,
                         "count_preheat": 8, "source": "modbus"},
    "/furnace/ambient": {"t_air": 28.5},
    "/daq/status": {"state": "connected", "detail": "PLC 127.0.0.1:5020 answered", "polls": 3},
    "/daq/events": {"kind": "burner_disagreement", "detail": "heat burner 3: PLC on, flame off"},
    "/model/parameters": {"a": 0.02, "b": 0.3, "c": 0.06, "d": 0.87, "e": 0.73, "f": 0.22,
                          "ci95": {p: [0.01, 0.9] for p in "abcdef"},
                          "window_start": "2026-03-02T00:00:00Z",
                          "window_end": "2026-03-02T06:00:00Z",
                          "rmse_c": {"soak": 1.5, "heat": 1.4, "preheat": 1.2}, "status": "ok"},
    "/model/events": {"kind": "drift", "detail": "b moved 12%", "parameters": {"b": 0.336}},
    "/model/diagnosis": {"status": "explained", "detail": "soak_1 drifts from 06:40",
                         "trigger": "drift",
                         "effects": [{"effect": "sensor_drift", "options": {"sensor": "soak_1"},
                                      "params": {"drift_rate": 0.02}}],
                         "sensor": {"thermocouple": "soak_1", "onset": "2026-03-02T06:40:00Z",
                                    "rate_c_per_h": 1.2}},
    "/log": {"timestamp": {"sec": 1_772_431_200, "nsec": 5}, "level": 3, "message": "m",
             "name": "furnace-daq", "file": "/daq/events", "line": 0},
}


def test_every_topic_round_trips_through_the_mcap_reader(tmp_path: Path) -> None:
    assert set(EXAMPLES) == set(TOPICS)
    w = LogWriter(tmp_path)
    for i, (topic, msg) in enumerate(EXAMPLES.items()):
        w.write(topic, msg, T0 + i * S, publish_time_ns=T0 + i * S + 7)
    w.write("/furnace/ambient", {"t_air": float("nan"), "extra": np.float32(2.5)}, T0 + 9 * S)
    w.close()
    assert w.error is None
    (path,) = tmp_path.iterdir()
    assert path.name == "furnace-20260302T060000Z.mcap"

    got = []
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        # + the /log lines mirroring the status, the event and the model event
        assert summary is not None and summary.statistics.message_count == len(EXAMPLES) + 4
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if channel.topic == "/log" and json.loads(message.data)["message"] != "m":
                continue
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            assert json.loads(schema.data) == json.loads(TOPICS[channel.topic].schema_bytes())
            got.append((channel.topic, json.loads(message.data), message.log_time,
                        message.publish_time))
        assert len(summary.chunk_indexes) >= 1
        assert all(c.compression == "zstd" for c in summary.chunk_indexes)
    expected = [(t, m, T0 + i * S, T0 + i * S + 7) for i, (t, m) in enumerate(EXAMPLES.items())]
    expected.append(("/furnace/ambient", {"extra": 2.5}, T0 + 9 * S, T0 + 9 * S))
    assert got == expected
    assert [m for m in read_messages([path]) if m[0] != "/log" or m[1]["message"] == "m"] \
        == expected


def test_schemas_are_plottable_by_foxglove() -> None:
    for name, t in TOPICS.items():
        assert foxglove_problems(t.schema, name) == []
        for key in t.schema.get("required", []):
            assert key in EXAMPLES[name], f"{name}: example lacks required {key}"
    assert foxglove_problems({"type": "object", "properties": {"x": {"type": ["number", "null"]}}},
                             "neg") != []


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o000])
def test_files_are_created_0640_whatever_the_umask(tmp_path: Path, umask: int) -> None:
    old = os.umask(umask)
    try:
        w = LogWriter(tmp_path)
        w.write("/furnace/ambient", {"t_air": 20.0}, T0)
        part = w.current_path
        assert part is not None and part.name.endswith(".mcap.part") and part.exists()
        assert part.stat().st_mode & 0o777 == 0o640
        assert not has_footer(part)
        w.close()
    finally:
        os.umask(old)
    assert w.current_path is None and not part.exists()
    final = tmp_path / "furnace-20260302T060000Z.mcap"
    assert final.stat().st_mode & 0o777 == 0o640 and has_footer(final)


def test_rotation_by_duration_on_utc_boundaries(tmp_path: Path) -> None:
    w = LogWriter(tmp_path, rotate_s=10.0)
    for i in range(35):
        w.write("/furnace/thermocouples", tc_msg(i), T0 + 3 * S + i * S)
    w.close()
    names = [p.name for p in finished_files(tmp_path, "furnace")]
    assert names == [f"furnace-20260302T0600{s}Z.mcap" for s in ("03", "10", "20", "30")]
    per_file = [len(list(read_messages([tmp_path / n]))) for n in names]
    assert per_file == [7, 10, 10, 8]
    got = [m["soak_1"] for _, m, _, _ in read_messages(sorted(tmp_path.iterdir()))]
    assert got == [tc_msg(i)["soak_1"] for i in range(35)]


def test_rotation_by_size(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    limit = 64 * 1024
    w = LogWriter(tmp_path, rotate_bytes=limit)
    n = 3000
    for i in range(n):  # random digits: barely compressible, ~180 bytes each
        w.write("/furnace/thermocouples", {s: float(v) for s, v in zip(PAPER.sensors, rng.random(6), strict=True)}
                | {"i": i}, T0 + i * 10**6)
    w.close()
    files = finished_files(tmp_path, "furnace")
    assert len(files) >= 5
    assert len({p.name for p in files}) == len(files)  # same second: distinct names
    for p in files:
        assert p.stat().st_size < limit + w._chunk_size + 8192
    assert [m["i"] for _, m, _, _ in read_messages(files)] == list(range(n))


def test_retention_keeps_the_newest_finished_files(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("not a log")
    (tmp_path / "other-20200101T000000Z.mcap").write_bytes(b"x")
    w = LogWriter(tmp_path, rotate_s=10.0, retention_files=2)
    for i in range(50):
        w.write("/furnace/ambient", {"t_air": float(i)}, T0 + i * S)
    assert [p.name for p in finished_files(tmp_path, "furnace")] == [
        "furnace-20260302T060020Z.mcap", "furnace-20260302T060030Z.mcap"]
    assert w.current_path.name == "furnace-20260302T060040Z.mcap.part"
    w.close()
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["furnace-20260302T060030Z.mcap", "furnace-20260302T060040Z.mcap",
                     "notes.txt", "other-20200101T000000Z.mcap"]


def test_unwritable_directory_never_raises_and_bounds_the_buffer(tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")  # works as root too: nothing can be created under a regular file
    w = LogWriter(blocker / "logs", max_buffered=50, retry_s=0.0)
    for i in range(80):
        w.write("/furnace/ambient", {"t_air": float(i)}, T0 + i * S)
        w.maybe_flush(time.monotonic())
    assert w.error is not None and "a-file" in w.error
    assert w.current_path is None and w.dropped == 30
    w.close()  # still no exception
    assert "lost at close" in w.error


def _all_messages(directory: Path) -> list[tuple[str, dict, int, int]]:
    return list(read_messages(sorted(directory.iterdir())))


def test_disk_full_on_create_then_resumes_with_a_gap_event(tmp_path: Path, monkeypatch) -> None:
    real_open = os.open

    def full(path, flags, mode=0o777, *a, **k):
        if str(path).endswith(".part"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real_open(path, flags, mode, *a, **k)

    w = LogWriter(tmp_path, retry_s=0.0)
    monkeypatch.setattr(mcaplog.os, "open", full)
    for i in range(5):
        w.write("/furnace/ambient", {"t_air": float(i)}, T0 + i * S)
    assert w.error is not None and "No space left" in w.error
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(mcaplog.os, "open", real_open)
    for i in range(5, 8):
        w.write("/furnace/ambient", {"t_air": float(i)}, T0 + i * S)
    assert w.error is None
    w.close()
    msgs = _all_messages(tmp_path)
    assert [m["t_air"] for t, m, _, _ in msgs if t == "/furnace/ambient"] == list(range(8))
    (gap,) = [m for t, m, _, _ in msgs if t == "/daq/events"]
    assert gap["kind"] == "log_gap" and gap["dropped"] == 0 and "No space left" in gap["error"]


def test_disk_full_mid_file_abandons_it_and_loses_nothing(tmp_path: Path, monkeypatch) -> None:
    w = LogWriter(tmp_path, retry_s=0.0, flush_interval_s=0.0)
    now = 0.0
    for i in range(10):
        w.write("/furnace/thermocouples", tc_msg(i), T0 + i * S)
        now += 1
        w.maybe_flush(now)
    first = w.current_path

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(mcaplog.os, "fsync", full)
    for i in range(10, 20):
        w.write("/furnace/thermocouples", tc_msg(i), T0 + i * S)
        now += 1
        w.maybe_flush(now)
        assert w.error is not None  # every retry fails while the disk is full
    assert w.current_path is None or w.current_path != first
    monkeypatch.undo()
    for i in range(20, 25):
        w.write("/furnace/thermocouples", tc_msg(i), T0 + i * S)
        now += 1
        w.maybe_flush(now)
    assert w.error is None
    w.close()
    assert first.exists() and not has_footer(first)  # abandoned, left for `logs recover`
    seen = {m["soak_1"] for t, m, _, _ in _all_messages(tmp_path) if t.startswith("/furnace")}
    assert seen == {tc_msg(i)["soak_1"] for i in range(25)}


def test_log_file_names_carry_the_utc_start_time(tmp_path: Path) -> None:
    w = LogWriter(tmp_path, prefix="kiln-a")
    w.write("/furnace/ambient", {"t_air": 1.0}, T0 + 3723 * S + 5)
    assert re.fullmatch(r"kiln-a-20260302T070203Z\.mcap\.part", w.current_path.name)
    w.close()
    with pytest.raises(ValueError):
        LogWriter(tmp_path, prefix="../x")
    assert math.isfinite(T0)
