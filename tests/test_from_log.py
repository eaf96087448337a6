"""`sim-plc --from-log`: a recorded log served over Modbus is what a daemon polling it logs
again, value for value at the same PLC seconds; the end of the log stops the PLC; bad logs are
one-line errors."""

from __future__ import annotations

import asyncio
import subprocess
import uuid
from dataclasses import astuple, replace
from pathlib import Path

import can
import numpy as np
import pytest
import yaml
from daq_processes import ROOT, furnace_daq, listening, start_simplc, stop
from pymodbus.client import AsyncModbusTcpClient

from furnace_daq.daemon import Daemon
from furnace_daq.daqconfig import load_config
from furnace_daq.logplayer import LogPlayer
from furnace_daq.mcaplog import LogWriter
from furnace_daq.registers import decode
from furnace_daq.simplc import CAN_ID, SimPLC
from furnace_model.log.read import read_messages
from furnace_model.log.schema import AMBIENT, BURNERS, DAQ_STATUS, THERMOCOUPLES
from furnace_model.simulation.furnace import PAPER

SPEED, PERIOD = 600.0, 0.05
EPOCH_NS = 1_772_431_200 * 10**9  # 2026-03-02T06:00:00Z


def daemon_config(tmp_path: Path) -> Path:
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["poll_period_s"] = PERIOD
    doc["plc"]["timeout_s"] = 0.5
    doc["refit"]["enabled"] = False  # polling and logging only: no refit worker
    path = tmp_path / "daq.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def start_player(logs: list[Path], *args: str, timeout: float = 20.0
                 ) -> tuple[subprocess.Popen, int]:
    return listening(furnace_daq("sim-plc", "--from-log", *map(str, logs), "--port", "0",
                                 *args), timeout)


def record(tmp_path: Path, name: str, port: int, duration: float) -> list[Path]:
    log_dir = tmp_path / name
    daq = furnace_daq("run", "--config", str(daemon_config(tmp_path)), "--plc",
                      f"127.0.0.1:{port}", "--log-dir", str(log_dir), "--duration", str(duration))
    _, err = daq.communicate(timeout=60)
    assert daq.returncode == 0, err
    return sorted(log_dir.glob("*.mcap"))


def furnace_series(logs: list[Path]) -> dict[str, list[tuple[int, dict]]]:
    """Per furnace topic: (publish ns, message) in publish order."""
    out: dict[str, list[tuple[int, dict]]] = {THERMOCOUPLES: [], BURNERS: [], AMBIENT: []}
    for topic, msg, _, pub in read_messages(logs, tuple(out)):
        out[topic].append((pub, msg))
    for series in out.values():
        series.sort(key=lambda r: r[0])
    return out


def held(series: list[tuple[int, dict]], origin_ns: int, second: int) -> dict:
    """The recorded message in force at `second` after the log's first message."""
    times = np.array([p - origin_ns for p, _ in series])
    return series[max(int(np.searchsorted(times, second * 10**9, side="right")) - 1, 0)][1]


def test_a_daemon_polling_a_served_log_logs_the_recorded_values(tmp_path):
    plant, port = start_simplc("--speed", str(SPEED), "--scan-s", "0.02")
    try:
        recorded = record(tmp_path, "recorded", port, 3.0)
    finally:
        assert stop(plant) == 0
    rec = furnace_series(recorded)
    origin = min(s[0][0] for s in rec.values())
    last_s = max(s[-1][0] for s in rec.values()) - origin

    # polled from this process, set up before the player starts: its clock runs from its
    # start, no time to lose
    config = load_config(daemon_config(tmp_path))
    log = LogWriter(tmp_path / "replayed", flush_interval_s=1.0)
    player, port = start_player(recorded, "--speed", str(SPEED), "--scan-s", "0.02")
    try:
        config = replace(config, plc=replace(config.plc, port=port))
        counters = asyncio.run(Daemon(config, log).run(4.0))
        replayed = sorted((tmp_path / "replayed").glob("*.mcap"))
    finally:
        player.terminate()
        said, _ = player.communicate(timeout=10)
    assert player.returncode in (0, -15)
    assert f"end of log at PLC second {-(-last_s // 10**9)}" in said

    new = furnace_series(replayed)
    tc = new[THERMOCOUPLES]
    # every poll made was answered and logged (a tick a busy host skipped is not a poll)
    assert len(tc) == counters.ok_polls == counters.polls, counters
    seconds = [m["plc_seconds"] for _, m in tc]
    assert seconds[-1] == -(-last_s // 10**9), "served to the end, then held"
    crossed = set()
    for (_, m), s in zip(tc, seconds, strict=True):
        want = held(rec[THERMOCOUPLES], origin, s)
        got = [m[k] for k in PAPER.sensors]
        assert np.allclose(got, [want[k] for k in PAPER.sensors], atol=0.1 + 1e-9), (s, got, want)
        crossed.add(tuple(want[k] for k in PAPER.sensors))
    assert seconds[0] < 300 and len(crossed) > len(rec[THERMOCOUPLES]) / 2, \
        f"the replay follows the recording: {len(crossed)} values from second {seconds[0]}"
    # Bits are a second request after the registers: a scan may fall between the two.
    scan = int(SPEED * 0.02)
    pubs = np.array([p for p, _ in new[BURNERS]])
    for p, m in new[BURNERS]:
        s = int(round((p - pubs[0]) / 1e9)) + seconds[0]
        wants = [held(rec[BURNERS], origin, s + k) for k in (0, scan, 2 * scan)]
        assert [m[z] for z in PAPER.zones] in [[w[z] for z in PAPER.zones] for w in wants], s
    assert len({tuple(m[f"count_{z}"] for z in PAPER.zones) for _, m in new[BURNERS]}) >= 2
    assert {m["t_air"] for _, m in new[AMBIENT]} == {m["t_air"] for _, m in rec[AMBIENT]}


def write_log(log_dir: Path, seconds: range, *, can_burners: bool = False,
              rotate_s: float = 3600.0, metadata: dict | None = None) -> None:
    """A recording written directly: temperatures rise 1 degC per PLC second per sensor
    index, heat_1 open from second 300 to 600, a failed poll at 450, burners change at 400."""
    with LogWriter(log_dir, flush_interval_s=60.0, rotate_s=rotate_s,
                   metadata=metadata) as log:
        for s in seconds:
            pub = EPOCH_NS + s * 10**9
            host = pub + 123_456_789 + 5 * 10**9  # the gateway clock, a little off
            tc = {k: round(20.0 + i + s / 10.0, 1) for i, k in enumerate(PAPER.sensors)}
            tc["quality"] = {k: "ok" for k in PAPER.sensors}
            if 300 <= s < 600:
                tc["heat_1"], tc["quality"]["heat_1"] = None, "sensor_open"
            tc["plc_seconds"] = s
            log.write(THERMOCOUPLES, tc, host, pub)
            if s == 450:
                failed = {k: None for k in PAPER.sensors}
                failed["quality"] = {k: "comm_error" for k in PAPER.sensors}
                log.write(THERMOCOUPLES, failed, host + 10**8, host + 10**8)
            log.write(AMBIENT, {"t_air": 25.0 + s / 1000.0, "quality": "ok"}, host, pub)
            on = 2 if s < 400 else 7
            burners = {"soak": [k < on for k in range(10)], "heat": [s >= 400] * 8,
                       "preheat": [False] * 8}
            burners.update(count_soak=on, count_heat=8 * (s >= 400), count_preheat=0,
                           source="can" if can_burners else "modbus")
            log.write(BURNERS, burners, host, host if can_burners else pub)
            log.write(DAQ_STATUS, {"state": "connected", "detail": "x"}, host, host)


@pytest.mark.parametrize("can_burners", [False, True])
def test_player_holds_each_recorded_value_until_the_next(tmp_path, can_burners):
    write_log(tmp_path, range(0, 900, 30), can_burners=can_burners, rotate_s=300.0)
    files = sorted(tmp_path.glob("*.mcap"))
    assert len(files) > 2, "a rotated series"
    player = LogPlayer(files[::-1])  # merged in time whatever the order given
    assert player.end_s == player.last_s == 870
    for s in (0, 1, 29, 30, 299, 300, 420, 449, 450, 451, 480, 599, 600, 870):
        v = player.values_at(s)
        rec = s // 30 * 30
        want = [20.0 + i + rec / 10.0 for i in range(6)]
        if 300 <= rec < 600:
            want[2] = np.nan
        np.testing.assert_allclose(v.thermocouples, want, err_msg=str(s))
        assert v.t_air == pytest.approx(25.0 + rec / 1000.0)
        assert v.burners[:10] == [k < (2 if rec < 400 else 7) for k in range(10)], s
        assert v.burners[10:18] == [rec >= 400] * 8, s
    assert player.values_at(5000).thermocouples == player.values_at(870).thermocouples

    looping = LogPlayer(files, loop=True)
    assert looping.end_s is None and looping.cycle_s == 900
    for s in (0, 31, 450, 899):
        np.testing.assert_equal(astuple(looping.values_at(s + 2 * 900)),
                                astuple(looping.values_at(s)))


def test_served_log_ends_frozen_and_loops_on_request(tmp_path):
    write_log(tmp_path, range(0, 120, 10))
    files = sorted(tmp_path.glob("*.mcap"))

    async def poll(plc: SimPLC, n: int) -> list[list[int]]:
        client = AsyncModbusTcpClient("127.0.0.1", port=plc.port)
        await client.connect()
        reads = []
        for _ in range(n):
            await asyncio.sleep(0.15)
            rr = await client.read_input_registers(0, count=10, device_id=1)
            assert not rr.isError()
            reads.append(rr.registers)
        client.close()
        return reads

    async def serve(loop: bool) -> tuple[list[list[int]], bool]:
        plc = SimPLC(LogPlayer(files, loop=loop), speed=600, port=0, scan_s=0.02)
        await plc.start()
        try:
            return await poll(plc, 8), plc.ended.is_set()
        finally:
            await plc.stop()

    reads, ended = asyncio.run(serve(False))
    assert ended
    seconds = [decode(r[7:9], "uint32", "big") for r in reads]
    assert seconds[-1] == 110 and reads[-1] == reads[-2], "clock, values, heartbeat frozen"
    assert reads[-1][:6] == [200 + 10 * i + 110 for i in range(6)]

    reads, ended = asyncio.run(serve(True))
    assert not ended
    seconds = np.array([decode(r[7:9], "uint32", "big") for r in reads])
    assert np.all(np.diff(seconds) > 0) and seconds[-1] > 240, "the clock runs on"
    for r, s in zip(reads, seconds, strict=True):
        rec = s % 120 // 10 * 10
        assert r[:6] == [200 + 10 * i + rec for i in range(6)], s
    assert len({r[9] for r in reads}) == len(reads), "heartbeat keeps counting"


def test_bad_logs_are_one_line_errors(tmp_path):
    text = tmp_path / "notes.mcap"
    text.write_text("not a log\n")
    status_only = tmp_path / "status"
    with LogWriter(status_only) as log:
        log.write(DAQ_STATUS, {"state": "disconnected", "detail": "starting"}, EPOCH_NS)
    cases = {
        tmp_path / "missing.mcap": "missing.mcap",
        text: "notes.mcap",
        next(status_only.glob("*.mcap")): "no thermocouple readings",
    }
    for path, what in cases.items():
        done = furnace_daq("sim-plc", "--from-log", str(path), "--port", "0")
        out, err = done.communicate(timeout=30)
        assert done.returncode == 1, (path, out, err)
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
        assert what in err and "listening" not in out
    done = furnace_daq("sim-plc", "--from-log", str(text), "--manual")
    _, err = done.communicate(timeout=30)
    assert done.returncode != 0 and "--manual" in err


def test_served_log_sends_the_recorded_flames_on_can(tmp_path):
    write_log(tmp_path, range(0, 900, 30))
    channel = f"log-{uuid.uuid4().hex}"
    player = LogPlayer(sorted(tmp_path.glob("*.mcap")))

    async def serve() -> tuple[list[can.Message], list[bool]]:
        listener = can.Bus(interface="virtual", channel=channel)
        plc = SimPLC(player, speed=1200, port=0, scan_s=0.02, can_channel=channel)
        await plc.start()
        try:
            await asyncio.wait_for(plc.ended.wait(), 10)
            await asyncio.sleep(0.1)
            frames = []
            while (msg := listener.recv(timeout=0)) is not None:
                frames.append(msg)
            return frames, plc.states
        finally:
            await plc.stop()
            listener.shutdown()

    frames, last = asyncio.run(serve())
    states = [[bool(int.from_bytes(bytes(f.data), "little") >> i & 1) for i in range(26)]
              for f in frames if f.arbitration_id == CAN_ID]
    assert states[0] == player.values_at(0).burners and states[-1] == last
    assert last == player.values_at(870).burners and sum(last[:10]) == 7 and all(last[10:18])
    assert len({tuple(s) for s in states}) == 2, "the recorded change at second 400"


def unusual_map(tmp_path: Path) -> Path:
    """A PLC program unlike the simulator's default: float thermocouples in word-swapped
    holding registers, a float16 ambient, the clock in little-endian word order, burner
    states packed into two status words."""
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["thermocouples"] = {s: {"table": "holding", "address": 100 + 2 * i, "type": "float32",
                                "byte_order": "CDAB", "range": [-50, 1600]}
                            for i, s in enumerate(PAPER.sensors)}
    doc["ambient"] = {"table": "input", "address": 20, "type": "float16"}
    doc["clock"] = {"table": "input", "address": 30, "type": "uint32", "word_order": "little"}
    doc["heartbeat"] = {"table": "input", "address": 33, "type": "uint16"}
    doc["burners"]["modbus"] = {"soak": {"table": "holding", "address": 40, "bit": 0},
                                "heat": {"table": "holding", "address": 40, "bit": 10},
                                "preheat": {"table": "holding", "address": 41, "bit": 2}}
    doc["refit"]["enabled"] = False
    path = tmp_path / "unusual.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_a_log_is_served_on_the_register_map_it_was_recorded_with(tmp_path):
    """`sim-plc --from-log` rebuilds the recording's map from the log's metadata, so the
    recording's own config reads the recorded values back: every point ok, each value the
    one recorded at PLC second 0 (the served clock barely moves at this speed)."""
    from furnace_daq.check import check
    from furnace_daq.logmeta import build_metadata

    cfg_path = unusual_map(tmp_path)
    config = load_config(cfg_path)
    write_log(tmp_path / "logs", range(0, 120, 30), metadata=build_metadata(config))
    player, port = start_player(sorted((tmp_path / "logs").glob("*.mcap")), "--speed", "0.001")
    try:
        report = asyncio.run(asyncio.wait_for(
            check(replace(config, plc=replace(config.plc, port=port))), 30))
    finally:
        player.terminate()
        _, said = player.communicate(timeout=10)
    assert "; register map: recorded in" in said, said
    rows = {p.key: p for p in report.points}
    assert not report.failed, [(p.key, p.raw, p.error) for p in report.failed]
    for i, s in enumerate(PAPER.sensors):
        assert float(rows[f"thermocouples.{s}"].value) == pytest.approx(20.0 + i, abs=1e-4)
    assert float(rows["ambient"].value) == pytest.approx(25.0, abs=0.02)  # float16
    assert [rows[f"burners.modbus.{z}"].value for z in PAPER.zones] == \
        ["2 of 10 on", "0 of 8 on", "0 of 8 on"]
    assert rows["burners.modbus.soak"].raw == "0x0003"  # bits 40.0 and 40.1, as packed
