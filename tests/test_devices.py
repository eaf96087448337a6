"""Several Modbus devices: the `devices:` list (each point names its device), RTU over TCP
and RTU on a serial line, and one device going away while the others keep their quality.

The serial line is real: a pseudo-terminal pair made by socat, a pymodbus RTU server on one
end and the daemon's own ModbusSource on the other."""

from __future__ import annotations

import asyncio
import contextlib
import io
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import pytest
import yaml
from daq_processes import ROOT, SCENARIO, messages
from logcheck import check_files
from pymodbus import FramerType
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import SimData, SimDevice
from pymodbus.simulator.simdata import DataType

from furnace_daq.daemon import Daemon
from furnace_daq.daqconfig import load_config, parse_config
from furnace_daq.journal import Journal
from furnace_daq.mcaplog import LogWriter
from furnace_daq.registers import (
    DATA_TYPES,
    TELEGRAF_ORDERS,
    BitRange,
    Point,
    encode,
)
from furnace_daq.simplc import SimPLC
from furnace_daq.sources import ModbusSource, SourceError
from furnace_model.config import Node
from furnace_model.errors import ConfigError
from furnace_model.log.schema import DAQ_STATUS, THERMOCOUPLES
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.scenario import load_scenario

EXAMPLE = ROOT / "config" / "devices.yaml"
NEW_TYPES = ("int64", "uint64", "float64", "float16")
ORDER_NAMES = ("ABCD", "DCBA", "BADC", "CDAB")


def gateway() -> dict:
    return yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())


def two_devices(tc_port: int, burner_port: int) -> dict:
    """The shipped map split over two PLCs: thermocouples, ambient, clock and heartbeat on
    one (Modbus TCP), the burner bits on the other (RTU over TCP)."""
    doc = gateway()
    plc = doc.pop("plc")
    fast = {"timeout_s": 0.2, "max_consecutive_errors": 2,
            "reconnect": {"initial_s": 0.1, "max_s": 0.4, "retry_s": 0.1}}
    doc["devices"] = [
        {"name": "thermo", "host": "127.0.0.1", "port": tc_port, "device_id": plc["device_id"],
         **fast},
        {"name": "burners", "transport": "rtu-over-tcp", "host": "127.0.0.1",
         "port": burner_port, **fast}]
    for entry in doc["thermocouples"].values():
        entry["device"] = "thermo"
    for key in ("ambient", "clock", "heartbeat"):
        doc[key]["device"] = "thermo"
    for entry in doc["burners"]["modbus"].values():
        entry["device"] = "burners"
    doc["poll_period_s"] = 0.05
    doc["stale_after_s"] = 0.5
    doc["refit"]["enabled"] = False
    return doc


# -- the config ------------------------------------------------------------------------------

def test_a_config_without_devices_is_one_implicit_device():
    cfg = load_config(ROOT / "config" / "gateway.yaml")
    assert not cfg.several_devices and cfg.devices == (cfg.plc,)
    assert cfg.plc.name == "plc" and cfg.plc.transport == "tcp"
    assert cfg.device_items(cfg.plc) == cfg.modbus_items()


def test_the_example_multi_device_config():
    cfg = load_config(EXAMPLE)
    assert [d.name for d in cfg.devices] == ["thermo", "burners", "weather"]
    thermo, burners, weather = cfg.devices
    assert (thermo.transport, burners.transport, weather.transport) == \
        ("tcp", "rtu-over-tcp", "rtu")
    assert weather.serial is not None and weather.serial.parity == "E"
    assert burners.workarounds.pause_between_requests_s > 0
    assert weather.workarounds.one_request_per_field
    assert {it.name for it in cfg.device_items(burners)} == {"soak", "heat", "preheat"}
    # the three zones packed in two holding registers of one device: no overlap, one read
    source = ModbusSource(cfg, device=burners)
    assert [(r.table, r.address, r.count) for r in source.requests] == [("holding", 40, 2)]
    assert cfg.plc is thermo  # write-back and --plc act on the first device
    moved = replace(cfg, plc=replace(cfg.plc, port=5999))
    assert [d.port for d in moved.devices][:2] == [5999, 4001]


@pytest.mark.parametrize("change, path, words", [
    (lambda d: d["devices"][1].update(name="thermo"), "devices[1].name", "listed twice"),
    (lambda d: d["thermocouples"]["soak_1"].update(device="nope"),
     "thermocouples.soak_1.device", "must be one of"),
    (lambda d: d["thermocouples"]["soak_1"].pop("device"), "thermocouples.soak_1.device",
     "required key"),
    (lambda d: d["devices"][1].update(transport="rtu"), "devices[1].host", "serial"),
    (lambda d: d["devices"][0].update(serial={"port": "/dev/ttyS0"}), "devices[0].serial",
     "transport: rtu or ascii only"),
    (lambda d: d["devices"][0].update(workarounds={"pause_after_connect": 1}),
     "devices[0].workarounds.pause_after_connect", "unknown key"),
    (lambda d: d.update(plc={"port": 502}), "plc", "not both"),
    (lambda d: d["thermocouples"]["soak_1"].update(byte_order="CDAB", word_order="big"),
     "thermocouples.soak_1.word_order", "already gives the word order"),
    (lambda d: d["thermocouples"]["soak_1"].update(type="string", length=4),
     "thermocouples.soak_1.type", "is a number"),
    (lambda d: d["burners"]["modbus"]["soak"].update(bit=3), "burners.modbus.soak.bit",
     "packed in a register"),
])
def test_device_mistakes_name_the_key_path(change, path, words):
    doc = two_devices(1, 2)
    change(doc)
    with pytest.raises(ConfigError) as err:
        parse_config(Node(doc, "test.yaml"))
    assert err.value.path == path and words in str(err.value), str(err.value)


def test_same_addresses_on_two_devices_are_not_an_overlap_but_on_one_they_are():
    doc = two_devices(1, 2)
    for entry in doc["burners"]["modbus"].values():
        entry["device"] = "burners"
    parse_config(Node(doc, "test.yaml"))  # discrete 0-25 on burners only: fine
    doc["heartbeat"] = {"table": "input", "address": 0, "device": "burners"}
    parse_config(Node(doc, "test.yaml"))  # input 0 on both devices: two PLCs
    doc["heartbeat"]["device"] = "thermo"
    with pytest.raises(ConfigError, match="overlaps thermocouples.soak_1"):
        parse_config(Node(doc, "test.yaml"))


def test_telegraf_byte_order_names_and_old_keys_give_the_same_point():
    doc = gateway()
    doc["clock"] = {"table": "input", "address": 7, "type": "uint32", "byte_order": "CDAB"}
    assert parse_config(Node(doc, "t.yaml")).clock.point.word_order == "little"
    doc["clock"] = {"table": "input", "address": 7, "type": "uint32", "word_order": "little",
                    "byte_order": "big"}
    assert parse_config(Node(doc, "t.yaml")).clock.point.word_order == "little"


# -- new types, every order, over RTU over TCP and serial RTU --------------------------------

def served_points() -> tuple[list[Point | BitRange], list[int], dict[str, object]]:
    """Every new type in every Telegraf order, a string, and bits packed in a register, laid
    out one after the other in holding registers: (points, registers, expected values)."""
    points: list[Point | BitRange] = []
    regs: list[int] = []
    want: dict[str, object] = {}
    samples = {"int64": -1234567890123456789, "uint64": 0xF123456789ABCDEF,
               "float64": -1234.5678901234567, "float16": 1.5}
    for dtype in NEW_TYPES:
        for name in ORDER_NAMES:
            word, byte = TELEGRAF_ORDERS[name]
            key = f"{dtype}_{name}"
            points.append(Point(key, "holding", len(regs), dtype, word, byte))
            regs += encode(samples[dtype], dtype, word, byte)
            want[key] = samples[dtype]
    for name in ORDER_NAMES:
        word, byte = TELEGRAF_ORDERS[name]
        key = f"string_{name}"
        points.append(Point(key, "holding", len(regs), "string", word, byte, length=5))
        regs += encode("SLAB-7", "string", word, byte, length=5)
        want[key] = "SLAB-7"
    states = [True, False, True, True, False, False, True, False, True, True]
    word = sum(1 << (3 + k) for k, on in enumerate(states) if on)
    points.append(BitRange("soak", "holding", len(regs), len(states), bit=3))
    regs.append(word)
    want["soak"] = states
    assert len(regs) <= 125 and set(NEW_TYPES) <= set(DATA_TYPES)
    return points, regs, want


def server_device(regs: list[int]) -> SimDevice:
    return SimDevice(0, simdata=(
        [SimData(0, values=[False] * 8, datatype=DataType.BITS)],
        [SimData(0, values=[False] * 8, datatype=DataType.BITS)],
        [SimData(0, values=regs, datatype=DataType.REGISTERS)],
        [SimData(0, values=[0] * 8, datatype=DataType.REGISTERS)]))


def device_config(device: dict):
    doc = gateway()
    doc.pop("plc")
    doc["devices"] = [{"name": "dev", "timeout_s": 1.0, **device}]
    return parse_config(Node(doc, "t.yaml"))


async def read_points(cfg, points) -> dict[str, object]:
    source = ModbusSource(cfg, items=points)
    await asyncio.wait_for(source.connect(), 5)
    try:
        image, refused = await asyncio.wait_for(source.read_image(), 10)
    finally:
        await source.close()
    assert not refused
    got: dict[str, object] = {}
    for p in points:
        words = image.words(p)
        assert words is not None, p
        got[p.name] = p.states(words) if isinstance(p, BitRange) else p.raw(words)
    return got


def test_every_new_type_and_order_over_rtu_over_tcp():
    points, regs, want = served_points()

    async def main():
        server = ModbusTcpServer(server_device(regs), framer=FramerType.RTU,
                                 address=("127.0.0.1", 0))
        await server.serve_forever(background=True)
        try:
            port = server.transport.sockets[0].getsockname()[1]
            cfg = device_config({"transport": "rtu-over-tcp", "host": "127.0.0.1",
                                 "port": port, "device_id": 7})
            one_by_one = device_config({"transport": "rtu-over-tcp", "host": "127.0.0.1",
                                        "port": port, "workarounds": {
                                            "one_request_per_field": True,
                                            "pause_between_requests_s": 0.002,
                                            "close_connection_after_gather": True}})
            return await read_points(cfg, points), await read_points(one_by_one, points)
        finally:
            await server.shutdown()

    merged, separate = asyncio.run(asyncio.wait_for(main(), 30))
    assert merged == want and separate == want


@contextlib.contextmanager
def pty_pair():
    """Two connected pseudo-terminals (socat), as a null-modem cable between two serial
    ports; socat is stopped on the way out."""
    tmp = Path(tempfile.mkdtemp(prefix="ptys-"))
    a, b = tmp / "plc", tmp / "gateway"
    proc = subprocess.Popen(["socat", f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 10
        while not (a.exists() and b.exists()):
            assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
            assert time.monotonic() < deadline, "socat made no pty pair"
            time.sleep(0.02)
        yield str(a), str(b)
    finally:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stderr:
            proc.stderr.close()
        for link in (a, b):
            with contextlib.suppress(OSError):
                os.unlink(link)
        with contextlib.suppress(OSError):
            tmp.rmdir()


needs_socat = pytest.mark.skipif(shutil.which("socat") is None,
                                 reason="socat not installed (make system-deps)")


@needs_socat
def test_every_new_type_and_order_over_a_serial_line():
    points, regs, want = served_points()

    async def main(plc_end: str, gateway_end: str):
        # a pty takes any baud rate but refuses parity bits (EINVAL): no parity here
        server = ModbusSerialServer(server_device(regs), port=plc_end, baudrate=38400)
        await server.serve_forever(background=True)
        try:
            cfg = device_config({"transport": "rtu", "device_id": 3, "serial": {
                "port": gateway_end, "baudrate": 38400, "parity": "N", "stopbits": 1}})
            assert cfg.plc.where == gateway_end
            return await read_points(cfg, points)
        finally:
            await server.shutdown()

    with pty_pair() as (plc_end, gateway_end):
        got = asyncio.run(asyncio.wait_for(main(plc_end, gateway_end), 30))
    assert got == want


@needs_socat
def test_the_simulated_plc_on_a_serial_line_is_polled_by_the_daemon(tmp_path):
    """The whole path on RTU: the simulated PLC serves the default map on one pty, the
    daemon polls it on the other and logs ok thermocouples."""
    async def main(plc_end: str, gateway_end: str):
        plc = SimPLC(load_scenario(SCENARIO), speed=600, scan_s=0.05, transport="rtu",
                     serial_port=plc_end, baudrate=115200)
        await plc.start()
        try:
            doc = gateway()
            doc.pop("plc")
            doc["devices"] = [{"name": "furnace", "transport": "rtu", "timeout_s": 0.3,
                               "serial": {"port": gateway_end, "baudrate": 115200}}]
            doc["poll_period_s"] = 0.1
            doc["refit"]["enabled"] = False
            cfg = parse_config(Node(doc, "t.yaml"))
            daemon = Daemon(cfg, LogWriter(tmp_path, flush_interval_s=0.5),
                            journal=Journal(stream=io.StringIO()))
            task = asyncio.create_task(daemon.run())
            while daemon.counters.ok_polls < 5 and not task.done():  # however slow the host
                await asyncio.sleep(0.01)
            daemon.stop()
            return await asyncio.wait_for(task, 20)
        finally:
            await plc.stop()

    with pty_pair() as (plc_end, gateway_end):
        counters = asyncio.run(asyncio.wait_for(main(plc_end, gateway_end), 30))
    assert counters.ok_polls >= 5 and counters.comm_errors == 0, counters
    tc = [m for t, m, _ in messages(tmp_path) if t == THERMOCOUPLES]
    assert tc and all(m["quality"][s] == "ok" for m in tc for s in PAPER.sensors)


# -- one device going away --------------------------------------------------------------------

def test_a_device_killed_mid_run_leaves_the_other_ok_and_is_named(tmp_path):
    out = io.StringIO()

    async def main():
        thermo = SimPLC(load_scenario(SCENARIO), speed=600, port=0, scan_s=0.05)
        burners = SimPLC(load_scenario(SCENARIO), speed=600, port=0, scan_s=0.05,
                         transport="rtu-over-tcp")
        await thermo.start()
        await burners.start()
        try:
            cfg = parse_config(Node(two_devices(thermo.port, burners.port), "t.yaml"))
            daemon = Daemon(cfg, LogWriter(tmp_path, flush_interval_s=0.5),
                            journal=Journal(stream=out))
            task = asyncio.create_task(daemon.run())

            async def polls(n: int) -> None:  # n more ticks, however slow the host is
                start = daemon.counters.polls
                while daemon.counters.polls < start + n and not task.done():
                    await asyncio.sleep(0.01)

            await asyncio.wait_for(polls(10), 15)
            await burners.stop()
            killed_at = time.time_ns()
            await asyncio.wait_for(polls(30), 15)
            daemon.stop()
            counters = await asyncio.wait_for(task, 20)
            return counters, killed_at
        finally:
            await burners.stop()
            await thermo.stop()

    counters, killed_at = asyncio.run(asyncio.wait_for(main(), 40))
    msgs = messages(tmp_path)
    tc = [(m, lt) for t, m, lt in msgs if t == THERMOCOUPLES]
    before = [m for m, lt in tc if lt < killed_at]
    after = [m for m, lt in tc if lt > killed_at]
    assert len(before) >= 5 and len(after) >= 20, (len(before), len(after))
    # the thermocouple PLC never stalled or lost quality while the burner PLC was away
    assert all(m["quality"][s] == "ok" for m in before + after for s in PAPER.sensors)
    assert any("burners:" in m.get("error", "") for m in after)
    # /daq/status names the device whose state changed, and lists each device's state
    status = [m for t, m, _ in msgs if t == DAQ_STATUS]
    lost = [m for m in status if m.get("device") == "burners" and m["state"] == "disconnected"
            and m["devices"]["burners"] == "disconnected"]
    assert lost and lost[0]["devices"]["thermo"] == "connected"
    assert lost[0]["detail"].startswith("burners: ")
    assert all(m["device"] == "thermo" and m["devices"]["thermo"] == "connected"
               for m in status if m.get("device") == "thermo")
    # stderr: an error-priority line naming the device
    lines = out.getvalue().splitlines()
    assert any(line.startswith("<3>PLC burners (127.0.0.1:") and "connection lost" in line
               for line in lines), lines
    assert not any("thermo" in line and line.startswith(("<3>", "<4>")) for line in lines), lines
    assert counters.failures and all(k.startswith("burners:") for k in counters.failures)
    # every message of the outage, its device fields included, is declared by its schema
    _, problems = check_files(sorted(tmp_path.glob("*.mcap")))
    assert not problems, problems


def test_write_back_needs_the_first_device_on_modbus_tcp():
    doc = two_devices(1, 2)
    doc["refit"]["enabled"] = True
    doc["write_back"] = {"enabled": True, "allow": [[100, 111]],
                         "params": {p: {"address": 100 + 2 * i} for i, p in enumerate("abcdef")}}
    parse_config(Node(doc, "t.yaml"))
    doc["devices"][0]["transport"] = "rtu-over-tcp"
    with pytest.raises(ConfigError, match="over Modbus TCP") as err:
        parse_config(Node(doc, "t.yaml"))
    assert err.value.path == "write_back"


def test_check_dials_every_device_and_names_the_one_that_is_down():
    from furnace_daq.check import check, format_report

    async def main():
        thermo = SimPLC(load_scenario(SCENARIO), speed=600, port=0, scan_s=0.05)
        await thermo.start()
        try:
            with socket.socket() as s:  # a port nobody listens on: the burner PLC is off
                s.bind(("127.0.0.1", 0))
                dead = s.getsockname()[1]
            cfg = parse_config(Node(two_devices(thermo.port, dead), "t.yaml"))
            return await asyncio.wait_for(check(cfg), 10)
        finally:
            await thermo.stop()

    report = asyncio.run(main())
    text = format_report(report)
    assert [d.split(":")[0] for d, _ in report.devices] == ["thermo", "burners"], text
    assert "connected" in report.devices[0][1] and "cannot connect" in report.devices[1][1]
    assert report.devices[1][0].startswith("burners: Modbus RTU over TCP 127.0.0.1:")
    bad = {p.key for p in report.failed}
    assert bad == {"burners.modbus.soak", "burners.modbus.heat", "burners.modbus.preheat"}, text
    assert not report.ok


def test_sim_plc_cli_refuses_a_serial_port_without_rtu_and_rtu_without_one():
    for extra in (["--transport", "rtu"], ["--serial-port", "/dev/null"]):
        r = subprocess.run([sys.executable, "-m", "furnace_daq.cli", "sim-plc", "--scenario",
                            str(SCENARIO), *extra], cwd=ROOT, capture_output=True, text=True,
                           timeout=60)
        assert r.returncode != 0 and "--serial-port goes with --transport rtu" in r.stderr, \
            r.stderr


def test_close_connection_after_gather_hangs_up_after_each_poll_and_stays_connected():
    """The daemon sees a device that answers; the device sees one short connection per
    poll, opened after the pause it asked for."""
    points, regs, want = served_points()
    opened: list[bool] = []

    async def main():
        server = ModbusTcpServer(server_device(regs), address=("127.0.0.1", 0),
                                 trace_connect=opened.append)
        await server.serve_forever(background=True)
        try:
            port = server.transport.sockets[0].getsockname()[1]
            cfg = device_config({"host": "127.0.0.1", "port": port, "workarounds": {
                "close_connection_after_gather": True, "pause_after_connect_s": 0.01}})
            source = ModbusSource(cfg, items=points)
            await source.connect()
            reads = []
            for _ in range(3):
                image, _refused = await asyncio.wait_for(source.read_image(), 10)
                reads.append({p.name: p.raw(image.words(p)) for p in points
                              if isinstance(p, Point)})
                assert source.connected and source._client is None  # line closed, session on
            await source.close()
            assert not source.connected
            for _ in range(100):  # the server hears of the last hang-up a moment later
                if opened.count(False) >= 3:
                    break
                await asyncio.sleep(0.01)
            return reads
        finally:
            await server.shutdown()

    reads = asyncio.run(asyncio.wait_for(main(), 30))
    assert all(r == {k: v for k, v in want.items() if k != "soak"} for r in reads)
    assert opened.count(True) == 3 and opened.count(False) >= 3, opened


def test_a_missing_serial_port_is_a_short_stable_failure_kind(tmp_path):
    cfg = device_config({"transport": "rtu", "serial": {"port": str(tmp_path / "ttyNONE")}})

    async def main():
        source = ModbusSource(cfg)
        with pytest.raises(SourceError) as err:
            await asyncio.wait_for(source.connect(), 10)
        await source.close()
        return err.value

    err = asyncio.run(main())
    assert err.kind == "no such device" and "ttyNONE" in str(err), (err.kind, str(err))
