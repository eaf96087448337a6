"""What a gateway on a plant network must never do: write to the PLC unless told to (and
then only where told), listen on a network, leave its logs world-readable, or run code
from its configuration."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import struct
import threading
import time
from pathlib import Path

import pytest
import yaml
from daq_processes import (
    ROOT,
    SCENARIO,
    config,
    free_port,
    furnace_daq,
    messages,
    sim,
    start_daemon,
    start_simplc,
    stop,
    until,
)
from faultproxy import READ_FUNCTION_CODES, FaultProxy
from pymodbus.client import AsyncModbusTcpClient

from furnace_daq.daqconfig import parse_config
from furnace_daq.registers import decode
from furnace_daq.simplc import SimPLC
from furnace_daq.writeback import (
    WriteBack,
    WriteBackConfig,
    WriteBackError,
    WritePoint,
    parse_write_back,
)
from furnace_model.config import Node
from furnace_model.errors import ConfigError
from furnace_model.log.read import read_messages
from furnace_model.log.schema import MODEL_PARAMETERS, THERMOCOUPLES
from furnace_model.simulation.scenario import load_scenario

# -- (a) the daemon only reads ----------------------------------------------------------------


def test_daemon_sends_only_read_function_codes(tmp_path):
    """Every table a map can name (coils, discrete inputs, holding and input registers),
    through a connection drop and redial: the PLC sees function codes 1-4 and nothing else."""
    async def scenario():
        plc = await sim(0)
        proxy = FaultProxy(plc.port)
        await proxy.start()
        cfg = config(proxy.port,
                     ambient={"table": "holding", "address": 0, "type": "int16", "scale": 0.1},
                     burners={"source": "modbus", "modbus": {
                         "soak": {"table": "coil", "address": 0},
                         "heat": {"table": "discrete", "address": 10},
                         "preheat": {"table": "coil", "address": 18}}})
        assert cfg.write_back is None  # the shipped map has none
        daemon, task = start_daemon(cfg, tmp_path, None)
        c = daemon.counters
        await until(lambda: c.ok_polls >= 12)
        await proxy.set_mode("drop")
        await asyncio.sleep(0.3)
        await proxy.set_mode("pass")
        polled = c.ok_polls
        await until(lambda: c.connects >= 2 and c.ok_polls >= polled + 10)
        daemon.stop()
        counters = await task
        await proxy.stop()
        await plc.stop()
        return proxy, counters

    proxy, counters = asyncio.run(scenario())
    assert counters.connects >= 2 and len(proxy.requests) > 50
    assert proxy.function_codes == READ_FUNCTION_CODES, proxy.function_codes
    assert [t for t, _, _ in messages(tmp_path)].count(THERMOCOUPLES) > 20


# -- (b) write_back ---------------------------------------------------------------------------

WB = {"enabled": True, "allow": [[100, 111], 120],
      "params": {"a": {"address": 100}, "b": {"address": 102, "word_order": "little"},
                 "c": {"address": 104, "type": "int16", "scale": 0.001},
                 "d": {"address": 106}, "e": {"address": 108}, "f": {"address": 110}},
      "counter": {"address": 120}}


def wb_config(**changes) -> Node:
    doc = yaml.safe_load(yaml.safe_dump(WB))
    doc.update(changes)
    return Node(doc, "daq.yaml", "write_back")


def test_write_back_is_off_unless_enabled():
    assert parse_write_back(Node(None, "daq.yaml", "write_back")) is None
    assert parse_write_back(wb_config(enabled=False)) is None
    cfg = parse_write_back(wb_config())
    assert cfg is not None and cfg.allow == frozenset([*range(100, 112), 120])
    assert [p.name for p in cfg.points] == ["a", "b", "c", "d", "e", "f"]


@pytest.mark.parametrize(("changes", "where", "what"), [
    ({"allow": None}, "write_back", "allow: required"),
    ({"params": {**WB["params"], "b": {"address": 111}}}, "write_back.params.b.address",
     "holding register 112 of b is not on write_back.allow"),
    ({"params": {**WB["params"], "c": {"address": 7, "type": "int16"}}},
     "write_back.params.c.address", "holding register 7 of c is not on write_back.allow"),
    ({"counter": {"address": 0}}, "write_back.counter.address", "not on write_back.allow"),
    ({"params": {**WB["params"], "f": {"address": 109}}}, "write_back.params.f.address",
     "also written for e"),
    ({"enabled": False, "params": {"a": {"adress": 100}}}, "write_back.params.a",
     "adress"),  # checked even while switched off
    ({"allow": [[5, 2]]}, "write_back.allow[0]", "first <= last"),
    ({"params": {}}, "write_back", "at least one parameter"),
])
def test_write_back_map_outside_the_allow_list_is_a_config_error(changes, where, what):
    doc = yaml.safe_load(yaml.safe_dump(WB))
    doc.update(changes)
    if doc.get("allow") is None:
        doc.pop("allow")
    with pytest.raises(ConfigError) as err:
        parse_write_back(Node(doc, "daq.yaml", "write_back"))
    assert err.value.path.startswith(where) and what in str(err.value), str(err.value)


def test_daemon_config_loads_write_back_with_the_key_in_the_error():
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["write_back"] = {**WB, "params": {"a": {"address": 99}}}
    with pytest.raises(ConfigError) as err:
        parse_config(Node(doc, "daq.yaml"))
    assert "daq.yaml: write_back.params.a.address: holding register 99" in str(err.value)
    doc["write_back"] = WB
    assert parse_config(Node(doc, "daq.yaml")).write_back is not None


MODEL = {"a": 0.0201, "b": 0.299, "c": 0.0615, "d": 0.874, "e": 0.728, "f": 0.224,
         "status": "ok"}


def float32(words: list[int], order: str = "big") -> float:
    return decode(words, "float32", order)


def test_write_back_writes_only_allowed_registers_with_fc16(tmp_path):
    """Against the simulated PLC's holding registers, through the recording proxy: an ok
    model lands where the map says; a failed or incomplete one writes nothing; a map that
    names a register off the list (here built past the parser) is refused before anything is
    sent."""
    async def scenario():
        plc = SimPLC(load_scenario(SCENARIO), speed=600, port=0, scan_s=0.05,
                     holding_registers=200)
        await plc.start()
        proxy = FaultProxy(plc.port)
        await proxy.start()
        events: list[dict] = []
        wb = WriteBack(parse_write_back(wb_config()), "127.0.0.1", proxy.port, timeout_s=0.5,
                       events=lambda e: events.append(e.to_json()))
        reader = AsyncModbusTcpClient("127.0.0.1", port=plc.port, timeout=0.5, retries=0)
        await reader.connect()
        try:
            wb.on_model({**MODEL, "status": "failed"})       # not written
            wb.on_model(MODEL)                                # written in the background
            await until(lambda: wb.writes == 1)
            first = (await reader.read_holding_registers(100, count=21)).registers
            wb.on_model({**MODEL, "a": 0.0202})
            await until(lambda: wb.writes == 2)
            second = (await reader.read_holding_registers(100, count=21)).registers
            wb.on_model({**MODEL, "a": 0.05, "c": None})     # incomplete: nothing written
            await until(lambda: events)
            third = (await reader.read_holding_registers(100, count=21)).registers
            before = len(proxy.requests)
            rogue = WriteBackConfig(frozenset(range(100, 102)),
                                    (WritePoint("a", 100), WritePoint("b", 150)))
            with pytest.raises(WriteBackError, match="refused: holding register 150"):
                await WriteBack(rogue, "127.0.0.1", proxy.port).write(MODEL)
            untouched = (await reader.read_holding_registers(150, count=2)).registers
            after = len(proxy.requests)
            await wb.close()
        finally:
            reader.close()
            await proxy.stop()
            await plc.stop()
        return proxy, wb, events, first, second, third, untouched, before, after

    proxy, wb, events, first, second, third, untouched, before, after = asyncio.run(scenario())
    assert float32(first[0:2]) == pytest.approx(0.0201, rel=1e-6)
    assert float32(first[2:4], "little") == pytest.approx(0.299, rel=1e-6)
    assert first[4] == 62  # c = 0.0615 / 0.001, rounded
    assert [round(float32(first[k:k + 2]), 6) for k in (6, 8, 10)] == [0.874, 0.728, 0.224]
    assert first[20] == 1 and second[20] == 2 and wb.writes == 2
    assert float32(second[0:2]) == pytest.approx(0.0202, rel=1e-6)
    assert untouched == [0, 0] and after == before, "the refused write sent nothing"
    writes = [f for f in proxy.requests if f.function_code not in READ_FUNCTION_CODES]
    assert {f.function_code for f in writes} == {16}
    assert len(writes) == 6  # per model: 100-104, 106-111 (104 is one int16), the counter
    allowed = frozenset([*range(100, 112), 120])
    for f in writes:
        start, count = f.address_count
        assert set(range(start, start + count)) <= allowed, (start, count)
    assert third == second and [e["kind"] for e in events] == ["write_back_failed"]
    assert "no value for c" in events[0]["detail"]


def test_write_back_failure_is_one_event_and_never_raises(tmp_path):
    async def scenario():
        events: list[dict] = []
        wb = WriteBack(parse_write_back(wb_config()), "127.0.0.1", free_port(), timeout_s=0.2,
                       events=lambda e: events.append(e.to_json()))
        for _ in range(3):
            wb.on_model(MODEL)
            await asyncio.sleep(0.1)
        await wb.close()
        return events

    events = asyncio.run(scenario())
    assert [e["kind"] for e in events] == ["write_back_failed"], events
    assert "cannot connect" in events[0]["detail"]


# -- (c) listeners bind loopback ----------------------------------------------------------------

def listening_sockets(pid: int) -> list[tuple[str, str]]:
    """(protocol, local address) of every listening TCP socket or bound UDP socket the
    process holds, from /proc/<pid>/fd and /proc/net/*: the view `ss -lnp` has."""
    inodes = set()
    fds = Path(f"/proc/{pid}/fd")
    for fd in fds.iterdir() if fds.exists() else ():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    found = []
    for proto in ("tcp", "tcp6", "udp", "udp6"):
        table = Path(f"/proc/{pid}/net/{proto}")
        if not table.exists():
            continue
        for line in table.read_text().splitlines()[1:]:
            cols = line.split()
            local, state, inode = cols[1], cols[3], cols[9]
            if inode in inodes and (state == "0A" if proto.startswith("tcp") else True):
                found.append((proto, _address(local)))
    return found


def _address(hex_addr: str) -> str:
    host, port = hex_addr.split(":")
    raw = bytes.fromhex(host)
    if len(raw) == 4:
        ip = socket.inet_ntop(socket.AF_INET, raw[::-1])
    else:
        ip = socket.inet_ntop(socket.AF_INET6, b"".join(raw[i:i + 4][::-1]
                                                       for i in range(0, 16, 4)))
    return f"{ip}:{int(port, 16)}"


def test_sim_plc_binds_loopback_by_default():
    assert SimPLC.__init__.__kwdefaults__["host"] == "127.0.0.1"
    proc, port = start_simplc()
    try:
        listening = listening_sockets(proc.pid)
    finally:
        stop(proc)
    assert listening == [("tcp", f"127.0.0.1:{port}")], listening


def test_proxy_binds_loopback():
    async def scenario():
        async with FaultProxy(free_port()) as proxy:
            return listening_sockets(os.getpid()), proxy.port

    listening, port = asyncio.run(scenario())
    assert ("tcp", f"127.0.0.1:{port}") in listening
    assert not [a for _, a in listening if a.endswith(f":{port}") and
                not a.startswith("127.0.0.1:")]


# -- (d) log files 0640, (g) the daemon listens on nothing ---------------------------------------

def test_daemon_listens_on_nothing_and_logs_0640(tmp_path):
    sim_proc, port = start_simplc("--speed", "600")
    log_dir = tmp_path / "logs"
    try:
        daq = furnace_daq("run", "--config", str(ROOT / "config" / "gateway.yaml"), "--plc",
                          f"127.0.0.1:{port}", "--log-dir", str(log_dir), "--no-refit")
        deadline = time.monotonic() + 30
        while not list(log_dir.glob("*.mcap.part")) and time.monotonic() < deadline:
            assert daq.poll() is None, daq.communicate()
            time.sleep(0.2)
        time.sleep(1.5)  # polling
        pids = [daq.pid, *children(daq.pid)]
        listening = [(pid, s) for pid in pids for s in listening_sockets(pid)]
        sockets = sum(1 for pid in pids for fd in Path(f"/proc/{pid}/fd").iterdir()
                      if os.readlink(fd).startswith("socket:"))
        daq.send_signal(signal.SIGTERM)
        daq.communicate(timeout=20)
        assert daq.returncode == 0
    finally:
        stop(daq)
        stop(sim_proc)
    assert sockets >= 1, "the PLC connection is a socket, so the check sees sockets"
    assert listening == [], listening
    files = list(log_dir.glob("*.mcap"))
    assert files and all(f.stat().st_mode & 0o777 == 0o640 for f in files)


def children(pid: int) -> list[int]:
    out = []
    try:
        for task in Path(f"/proc/{pid}/task").iterdir():
            with open(task / "children") as f:  # a thread may end meanwhile
                for child in f.read().split():
                    out += [int(child), *children(int(child))]
    except FileNotFoundError:
        pass
    return out


# -- (e) configuration is data, never code -------------------------------------------------------

def test_yaml_tags_that_build_objects_are_refused(tmp_path):
    marker = tmp_path / "ran"
    doc = (ROOT / "config" / "gateway.yaml").read_text()
    doc += f'\nhack: !!python/object/apply:os.system ["touch {marker}"]\n'
    cfg = tmp_path / "daq.yaml"
    cfg.write_text(doc)
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(SCENARIO.read_text().replace(
        "name: daq_steps", f'name: !!python/object/apply:os.system ["touch {marker}"]'))
    for args in (["run", "--config", str(cfg), "--duration", "1"],
                 ["sim-plc", "--scenario", str(scenario), "--port", "0"]):
        proc = furnace_daq(*args)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 2, (args, err)
        assert "Traceback" not in err and "python/object/apply:os.system" in err, err
        assert err.count("\n") == 1 and str(args[2]) in err, err
    assert not marker.exists()


def test_proxy_request_decoding_sanity():
    """The proxy's frame decoding that the security tests rely on: FC16 address/count."""
    from faultproxy import Frame
    pdu = bytes([16]) + struct.pack(">HHB", 100, 2, 4) + b"\0" * 4
    frame = Frame(1, 7, 1, pdu, b"")
    assert frame.function_code == 16 and frame.address_count == (100, 2)


# -- (b) the whole chain: refits in `furnace-daq run` reach the PLC through write_back ------------

@pytest.mark.slow
def test_run_writes_each_ok_model_to_allowed_registers_only(tmp_path):
    """`furnace-daq run` with refits and write_back, behind the recording proxy, against a
    simulated PLC with holding registers (in this process, on a loop of its own): the PLC
    ends up holding the last ok model, and the only requests that are not reads are FC16
    to allow-listed registers."""
    speed, hours = 3000.0, 9
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()

    def call(coro):
        return asyncio.run_coroutine_threadsafe(coro, loop).result(30)

    plc = SimPLC(load_scenario(ROOT / "config" / "scenarios" / "week_steps.yaml"), speed=speed,
                 port=0, seed=1, scan_s=0.04, holding_registers=128)
    call(plc.start())
    proxy = FaultProxy(plc.port)
    call(proxy.start())
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["poll_period_s"] = 0.04                  # one poll per 2 simulated minutes
    doc["plc"]["timeout_s"] = 0.2
    doc["clock"]["epoch"] = "2026-03-02T00:00:00Z"
    doc["refit"] = {"period_s": 7200, "window_s": 21600, "step_s": 120,
                    "max_gap_fraction": 0.5, "budget_s": 20, "state_dir": str(tmp_path / "state")}
    doc["write_back"] = WB
    cfg = tmp_path / "daq.yaml"
    cfg.write_text(yaml.safe_dump(doc))
    try:
        daq = furnace_daq("run", "--config", str(cfg), "--plc", f"127.0.0.1:{proxy.port}",
                          "--log-dir", str(tmp_path / "logs"),
                          "--duration", str(hours * 3600 / speed))
        deadline = time.monotonic() + 30       # the refit worker process: it listens on
        while not children(daq.pid) and time.monotonic() < deadline:  # nothing either
            time.sleep(0.1)
        pids = [daq.pid, *children(daq.pid)]
        listening = [s for pid in pids for s in listening_sockets(pid)]
        _, err = daq.communicate(timeout=120)
        assert daq.returncode == 0, err

        async def holding():
            reader = AsyncModbusTcpClient("127.0.0.1", port=plc.port, timeout=0.5, retries=0)
            await reader.connect()
            try:
                return (await reader.read_holding_registers(100, count=21)).registers
            finally:
                reader.close()

        words = call(holding())
    finally:
        call(proxy.stop())
        call(plc.stop())
        loop.call_soon_threadsafe(loop.stop)
        thread.join(5)
        loop.close()
    models = [m for t, m, _, _ in read_messages(sorted((tmp_path / "logs").glob("*.mcap")),
                                                 [MODEL_PARAMETERS])]
    ok = [m for m in models if m["status"] == "ok"]
    assert ok, [m.get("detail") for m in models]
    assert len(pids) >= 2 and listening == [], (pids, listening)
    last = ok[-1]
    assert float32(words[0:2]) == pytest.approx(last["a"], rel=1e-6)
    assert float32(words[2:4], "little") == pytest.approx(last["b"], rel=1e-6)
    assert words[4] == round(last["c"] / 0.001)
    for k, p in ((6, "d"), (8, "e"), (10, "f")):
        assert float32(words[k:k + 2]) == pytest.approx(last[p], rel=1e-6)
    assert 1 <= words[20] <= len(ok)  # the counter: one per complete write
    writes = [f for f in proxy.requests if f.function_code not in READ_FUNCTION_CODES]
    assert {f.function_code for f in writes} == {16}
    allowed = frozenset([*range(100, 112), 120])
    for f in writes:
        start, count = f.address_count
        assert set(range(start, start + count)) <= allowed
