"""The rest of Telegraf's Modbus input, against real pymodbus servers on loopback and on a
socat pseudo-terminal pair: several device ids on one serial line (one port, one read at a
time, one silent device costing the other nothing), ASCII framing, busy retries, bits and
strings as signals, coils read from address 0, and `check` naming the point that breaks a
refused block."""

from __future__ import annotations

import asyncio
import io
import time

import pytest
import yaml
from daq_processes import ROOT, messages
from pymodbus import FramerType
from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import SimData, SimDevice
from pymodbus.simulator.simdata import DataType
from test_devices import needs_socat, pty_pair

from furnace_daq.check import check, format_report
from furnace_daq.daemon import Daemon
from furnace_daq.daqconfig import parse_config
from furnace_daq.journal import Journal
from furnace_daq.logmeta import build_metadata
from furnace_daq.mcaplog import LogWriter
from furnace_daq.sources import AllRefused, ModbusSource
from furnace_model.config import Node
from furnace_model.errors import ConfigError
from furnace_model.log.schema import BURNERS, SIGNALS, THERMOCOUPLES
from furnace_model.simulation.furnace import PAPER

INPUTS = [250 + k for k in range(7)]  # six thermocouples and the ambient, 25.0 degC and up
BURNER_BITS = [k % 3 == 0 for k in range(32)]


def plc(device_id: int, *, coils=None, discrete=None, holding=None, inputs=None,
        action=None) -> SimDevice:
    """A device of the server: its four tables (registers or bits from address 0; a list of
    SimData for a table with holes), answering to `device_id`."""
    def table(values, bits: bool):
        if isinstance(values, list) and values and isinstance(values[0], SimData):
            return values
        kind = DataType.BITS if bits else DataType.REGISTERS
        return [SimData(0, values=values or ([False] * 16 if bits else [0] * 16), datatype=kind)]
    return SimDevice(device_id, simdata=(table(coils, True), table(discrete, True),
                                         table(holding, False), table(inputs, False)),
                     action=action)


def gateway(**changes) -> dict:
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    for key in ("clock", "heartbeat"):  # a still heartbeat would make every point stale
        doc.pop(key)
    doc["refit"]["enabled"] = False
    doc.update(changes)
    return doc


def one_device(port: int, **device) -> dict:
    doc = gateway()
    doc["plc"] = {"host": "127.0.0.1", "port": port, "timeout_s": 1.0}
    if device:
        doc.pop("plc")
        doc["devices"] = [{"name": "plc", "host": "127.0.0.1", "port": port, "timeout_s": 1.0,
                           **device}]
    return doc


async def tcp_server(device: SimDevice | list[SimDevice], framer=FramerType.SOCKET):
    server = ModbusTcpServer(device, framer=framer, address=("127.0.0.1", 0))
    await server.serve_forever(background=True)
    return server, server.transport.sockets[0].getsockname()[1]


async def read_once(doc: dict):
    source = ModbusSource(parse_config(Node(doc, "t.yaml")))
    await asyncio.wait_for(source.connect(), 5)
    try:
        return await asyncio.wait_for(source.read(), 10)
    finally:
        await source.close()


# -- several device ids on one serial line ----------------------------------------------------

def shared_line(doc: dict, port: str, framing: str = "rtu") -> dict:
    """Thermocouples and ambient on device 1, burner bits on device 2, both on `port`."""
    doc.pop("plc")
    line = {"transport": framing, "timeout_s": 0.25, "max_consecutive_errors": 2,
            "serial": {"port": port, "baudrate": 115200},
            "reconnect": {"initial_s": 0.1, "max_s": 0.3, "retry_s": 0.1}}
    doc["devices"] = [{"name": name, "device_id": k + 1, **line,
                       "serial": dict(line["serial"])}
                      for k, name in enumerate(("thermo", "burners"))]
    for entry in doc["thermocouples"].values():
        entry["device"] = "thermo"
    doc["ambient"]["device"] = "thermo"
    for entry in doc["burners"]["modbus"].values():
        entry["device"] = "burners"
    return doc


@needs_socat
@pytest.mark.parametrize("framing, framer", [("rtu", FramerType.RTU),
                                             ("ascii", FramerType.ASCII)])
def test_two_device_ids_on_one_serial_port_are_both_read(framing, framer):
    """Both devices dial and read at once, again and again: the port is opened once (a
    second open fails with "Resource temporarily unavailable") and their reads take turns."""
    async def main(plc_end: str, gateway_end: str):
        server = ModbusSerialServer([plc(1, inputs=INPUTS), plc(2, discrete=BURNER_BITS)],
                                    framer=framer, port=plc_end, baudrate=115200)
        await server.serve_forever(background=True)
        try:
            cfg = parse_config(Node(shared_line(gateway(), gateway_end, framing), "t.yaml"))
            sources = [ModbusSource(cfg, device=d) for d in cfg.devices]
            await asyncio.wait_for(asyncio.gather(*(s.connect() for s in sources)), 10)
            try:
                return [await asyncio.wait_for(asyncio.gather(*(s.read() for s in sources)), 10)
                        for _ in range(3)]
            finally:
                for s in sources:
                    await s.close()
        finally:
            await server.shutdown()

    with pty_pair() as (plc_end, gateway_end):
        rounds = asyncio.run(asyncio.wait_for(main(plc_end, gateway_end), 40))
    for thermo, burners in rounds:
        assert [thermo.values[s] for s in PAPER.sensors] == [v / 10 for v in INPUTS[:6]]
        assert thermo.values["t_air"] == INPUTS[6] / 10 and thermo.burners is None
        assert burners.burners == {"soak": BURNER_BITS[:10], "heat": BURNER_BITS[10:18],
                                   "preheat": BURNER_BITS[18:26]}


@needs_socat
def test_a_silent_device_on_the_line_leaves_the_other_read(tmp_path):
    """The burner device stops answering mid-run: its points go comm_error and its link is
    redialled, while every thermocouple message of the thermo device stays ok."""
    silent = asyncio.Event()

    async def burner_action(*_args):
        if silent.is_set():  # the server then answers nothing, as a device that is off
            raise NoSuchIdException("switched off")
        return None

    async def main(plc_end: str, gateway_end: str):
        server = ModbusSerialServer([plc(1, inputs=INPUTS),
                                     plc(2, discrete=BURNER_BITS, action=burner_action)],
                                    port=plc_end, baudrate=115200, ignore_missing_devices=True)
        await server.serve_forever(background=True)
        try:
            doc = shared_line(gateway(poll_period_s=0.1), gateway_end)
            daemon = Daemon(parse_config(Node(doc, "t.yaml")),
                            LogWriter(tmp_path, flush_interval_s=0.5),
                            journal=Journal(stream=io.StringIO()))
            task = asyncio.create_task(daemon.run())

            async def polls(n: int) -> None:  # n more ticks, however slow the host is
                start = daemon.counters.polls
                while daemon.counters.polls < start + n and not task.done():
                    await asyncio.sleep(0.01)

            await asyncio.wait_for(polls(5), 15)
            silent.set()
            silenced_at = time.time_ns()
            await asyncio.wait_for(polls(12), 30)
            daemon.stop()
            return await asyncio.wait_for(task, 20), silenced_at
        finally:
            await server.shutdown()

    with pty_pair() as (plc_end, gateway_end):
        counters, silenced_at = asyncio.run(asyncio.wait_for(main(plc_end, gateway_end), 60))
    msgs = messages(tmp_path)
    tc = [(m, t) for topic, m, t in msgs if topic == THERMOCOUPLES]
    after = [m for m, t in tc if t > silenced_at]
    assert len(after) >= 8, len(after)
    assert all(m["quality"][s] == "ok" for m, _ in tc for s in PAPER.sensors)
    assert any("burners:" in m.get("error", "") for m in after)
    burners = [t for topic, m, t in msgs if topic == BURNERS]
    assert any(t < silenced_at for t in burners)
    assert counters.failures and all(k.startswith("burners:") for k in counters.failures)


def test_devices_on_one_line_must_agree_on_it():
    def doc_with(change) -> dict:
        doc = shared_line(gateway(), "/dev/ttyUSB0")
        change(doc["devices"][1])
        return doc

    for change, path, words in (
            (lambda d: d["serial"].update(baudrate=9600), "devices[1].serial", "other settings"),
            (lambda d: d.update(device_id=1), "devices[1].device_id", "is device thermo's"),
            (lambda d: d.update(transport="ascii"), "devices[1].transport", "one framing")):
        with pytest.raises(ConfigError) as err:
            parse_config(Node(doc_with(change), "t.yaml"))
        assert err.value.path == path and words in str(err.value), str(err.value)


# -- ASCII over TCP, busy retries ---------------------------------------------------------------

def test_ascii_over_tcp():
    async def main():
        server, port = await tcp_server(plc(1, inputs=INPUTS, discrete=BURNER_BITS),
                                        FramerType.ASCII)
        try:
            return await read_once(one_device(port, transport="ascii-over-tcp"))
        finally:
            await server.shutdown()

    sample = asyncio.run(asyncio.wait_for(main(), 30))
    assert [sample.values[s] for s in PAPER.sensors] == [v / 10 for v in INPUTS[:6]]
    assert sample.burners is not None and sample.burners["soak"] == BURNER_BITS[:10]


def busy_for(n: int):
    """An action that answers the first `n` requests with exception 6 (server device busy)."""
    seen = []

    async def action(*_args):
        seen.append(time.monotonic())
        return ExcCodes.DEVICE_BUSY if len(seen) <= n else None
    return action, seen


def test_a_busy_device_is_asked_again_after_the_wait():
    action, seen = busy_for(2)

    async def main():
        server, port = await tcp_server(plc(1, inputs=INPUTS, action=action))
        try:
            doc = one_device(port, busy_retries=3, busy_retries_wait_s=0.05)
            doc["burners"] = {"source": "can", "can": {"interface": "virtual"}}
            return await read_once(doc)
        finally:
            await server.shutdown()

    sample = asyncio.run(asyncio.wait_for(main(), 30))
    assert [sample.values[s] for s in PAPER.sensors] == [v / 10 for v in INPUTS[:6]]
    assert not sample.errors and len(seen) == 3
    assert all(b - a >= 0.05 for a, b in zip(seen, seen[1:], strict=False))


def test_a_device_busy_beyond_the_retries_is_named():
    action, seen = busy_for(100)

    async def main():
        server, port = await tcp_server(plc(1, inputs=INPUTS, action=action))
        try:
            doc = one_device(port, busy_retries=2, busy_retries_wait_s=0.01)
            doc["burners"] = {"source": "can", "can": {"interface": "virtual"}}
            with pytest.raises(AllRefused) as err:
                await read_once(doc)
            return err.value
        finally:
            await server.shutdown()

    err = asyncio.run(asyncio.wait_for(main(), 30))
    assert len(seen) == 3  # the request and its two retries
    assert "Modbus exception code 6 (server device busy)" in str(err), str(err)


# -- bits, bytes and strings as signals; coils from zero ---------------------------------------

SIGNAL_MAP = {
    "door_open": {"table": "discrete", "address": 40, "unit": ""},
    "lamp": {"table": "coil", "address": 5, "unit": ""},
    "recipe": {"table": "holding", "address": 20, "type": "string", "length": 3,
               "byte_order": "BA", "unit": ""},
    "mode": {"table": "holding", "address": 23, "type": "uint8h", "unit": ""},
    "trim": {"table": "holding", "address": 23, "type": "int8l", "scale": 0.5, "unit": "%"},
}


def signal_server(action=None) -> SimDevice:
    holding = [0] * 20 + [0x3153, 0x412D, 0x0037, 0x03FE]  # "S1-A7" byte-swapped; 3 | -2
    discrete = [False] * 48
    discrete[40] = True
    coils = [False] * 16
    coils[5] = True
    return plc(1, inputs=INPUTS, discrete=discrete, coils=coils, holding=holding,
               action=action)


def test_bits_bytes_and_strings_as_signals():
    async def main():
        server, port = await tcp_server(signal_server())
        try:
            return await read_once(one_device(port) | {"signals": SIGNAL_MAP})
        finally:
            await server.shutdown()

    sample = asyncio.run(asyncio.wait_for(main(), 30))
    got = {k.removeprefix("signals."): v for k, v in sample.values.items()
           if k.startswith("signals.")}
    assert got == {"door_open": True, "lamp": True, "recipe": "S1-A7", "mode": 3.0,
                   "trim": -1.0}
    assert all(sample.quality[f"signals.{k}"] == "ok" for k in got)


def test_a_disturbance_from_a_discrete_input_is_a_number():
    doc = one_device(1) | {"furnace": "modulated"}
    doc["disturbances"] = {"throughput": {"table": "discrete", "address": 30, "scale": 120.0}}
    doc["heat"] = {"soak": {"address": 20}, "heat": {"address": 22}}
    doc["burners"] = {"modbus": {"preheat": {"address": 0}}}
    cfg = parse_config(Node(doc, "t.yaml"))
    point = cfg.disturbance_point("throughput")
    assert point.value([1]) == (120.0, "ok")
    doc["disturbances"]["throughput"]["type"] = "int16"
    with pytest.raises(ConfigError, match="one bit") as err:
        parse_config(Node(doc, "t.yaml"))
    assert err.value.path == "disturbances.throughput.type"
    doc = one_device(1)
    doc["thermocouples"]["soak_1"]["table"] = "coil"
    with pytest.raises(ConfigError, match="must be one of") as err:
        parse_config(Node(doc, "t.yaml"))
    assert err.value.path == "thermocouples.soak_1.table"


def test_read_coils_starting_at_zero():
    """A device that refuses coil reads not starting at 0 (telegraf#8905): refused without
    the workaround, read with it."""
    coil_reads: list[int] = []

    async def action(fc, _start, address, *_rest):
        if fc == 1:
            coil_reads.append(address)
            return ExcCodes.ILLEGAL_ADDRESS if address else None
        return None

    async def main():
        server, port = await tcp_server(signal_server(action))
        try:
            plain = await read_once(one_device(port) | {"signals": SIGNAL_MAP})
            fixed = await read_once(one_device(port, workarounds={
                "read_coils_starting_at_zero": True}) | {"signals": SIGNAL_MAP})
            return plain, fixed
        finally:
            await server.shutdown()

    plain, fixed = asyncio.run(asyncio.wait_for(main(), 30))
    assert plain.quality["signals.lamp"] == "comm_error"
    assert plain.errors == ["coil 5+1: Modbus exception code 2 (illegal data address)"]
    assert fixed.values["signals.lamp"] is True and not fixed.errors
    assert coil_reads == [5, 0]


def test_coils_from_zero_beyond_one_request_is_refused_at_load():
    doc = one_device(1, workarounds={"read_coils_starting_at_zero": True})
    doc["signals"] = {"far": {"table": "coil", "address": 2500, "unit": ""}}
    with pytest.raises(ConfigError, match="2501 coils") as err:
        parse_config(Node(doc, "t.yaml"))
    assert err.value.path == "devices[0].workarounds.read_coils_starting_at_zero"


# -- check: the point that breaks a refused block ----------------------------------------------

def test_check_names_the_point_that_breaks_a_refused_block():
    """Six signals read in one block of holding registers; the device refuses address 13
    (one point's) and address 31 (a hole between two others)."""
    holding = [SimData(0, values=list(range(100, 113)), datatype=DataType.REGISTERS),
               SimData(13, datatype=DataType.INVALID),
               SimData(14, values=list(range(114, 131)), datatype=DataType.REGISTERS),
               SimData(31, datatype=DataType.INVALID),
               SimData(32, values=[132, 133], datatype=DataType.REGISTERS)]
    signals = {f"s{a}": {"table": "holding", "address": a, "unit": ""}
               for a in (10, 11, 12, 13, 14, 15, 30, 32)}

    async def main():
        server, port = await tcp_server(plc(1, inputs=INPUTS, discrete=BURNER_BITS,
                                            holding=holding))
        try:
            return await asyncio.wait_for(check(parse_config(Node(
                one_device(port) | {"signals": signals}, "t.yaml"))), 20)
        finally:
            await server.shutdown()

    report = asyncio.run(main())
    text = format_report(report)
    rows = {p.key: p for p in report.points}
    bad = rows["signals.s13"]
    assert bad.quality == "comm_error" and "this point breaks it" in bad.error, text
    for a in (10, 11, 12, 14, 15):
        row = rows[f"signals.s{a}"]  # comm_error as the daemon reads it, its own value shown
        assert row.quality == "comm_error" and "broken by signals.s13" in row.error, text
        assert row.value == str(100 + a), text
    for a in (30, 32):
        row = rows[f"signals.s{a}"]
        assert row.quality == "comm_error" and "unmapped addresses" in row.error, text
        assert row.value == str(100 + a), text
    assert all(rows[f"thermocouples.{s}"].ok for s in PAPER.sensors), text


def test_text_signals_are_logged_and_schema_valid(tmp_path):
    """A string signal goes to /furnace/signals as text, declared by its schema."""
    from logcheck import check_files

    async def main():
        server, port = await tcp_server(signal_server())
        try:
            doc = one_device(port) | {"signals": SIGNAL_MAP, "poll_period_s": 0.05}
            cfg = parse_config(Node(doc, "t.yaml"))
            log = LogWriter(tmp_path, flush_interval_s=0.5, metadata=build_metadata(cfg))
            daemon = Daemon(cfg, log, journal=Journal(stream=io.StringIO()))
            return await daemon.run(0.5)
        finally:
            await server.shutdown()

    asyncio.run(asyncio.wait_for(main(), 30))
    signals = [m for topic, m, _ in messages(tmp_path) if topic == SIGNALS]
    assert signals and all(m["recipe"] == "S1-A7" and m["door_open"] is True
                           for m in signals)
    _, problems = check_files(sorted(tmp_path.glob("*.mcap")))
    assert not problems, problems
