"""The daemon reading a Siemens S7 PLC: its map parsed with key-path errors, the reads
planned into the PDU, and the daemon's own source against python-snap7's server on
loopback (the simulated S7 PLC serving the test plant): values as the plant has them at
their stamps, a server restarted, a data block that vanishes, a slow PLC, `furnace-daq
check`, and `sim-plc --protocol s7` with `check` end to end."""

from __future__ import annotations

import asyncio
import sys

import numpy as np
import pytest
import yaml
from daq_processes import ROOT, SCENARIO, free_port, furnace_daq, start_simplc, stop, until
from stallproxy import StallingProxy

from furnace_daq.check import check, format_report
from furnace_daq.daemon import EVENT_PRIORITY, Daemon
from furnace_daq.daqconfig import load_config, parse_config
from furnace_daq.logmeta import build_metadata
from furnace_daq.mcaplog import LogWriter
from furnace_daq.protocols import source_class
from furnace_daq.s7map import S7Address
from furnace_daq.s7server import S7PLC, default_items
from furnace_daq.s7source import S7Block, S7Source, plan_blocks, plan_requests
from furnace_model.config import Node
from furnace_model.errors import ConfigError, FurnaceError
from furnace_model.log.read import read_messages
from furnace_model.log.schema import BURNERS, DAQ_STATUS, THERMOCOUPLES
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

SHIPPED = ROOT / "config" / "gateway-s7.yaml"


def doc(port: int, **s7) -> dict:
    """The shipped S7 map, sped up: 20 Hz polls, 0.3 s timeout, quick redials."""
    d = yaml.safe_load(SHIPPED.read_text())
    d["poll_period_s"] = 0.05
    d["stale_after_s"] = 0.5
    d["refit"]["enabled"] = False
    d["plc"].update(port=port, timeout_s=0.3, max_consecutive_errors=2,
                    reconnect={"initial_s": 0.1, "max_s": 0.4, "retry_s": 0.1})
    d["plc"]["s7"].update(s7)
    return d


def cfg(port: int, change=None, **s7):
    d = doc(port, **s7)
    if change is not None:
        change(d)
    return parse_config(Node(d, str(SHIPPED)))


def heat_2_apart(d: dict) -> None:
    """heat_2 in a data block of its own, DB11 (the one a test makes vanish)."""
    d["thermocouples"]["heat_2"]["s7"] = "DB11.DBD0"


async def serve(port: int = 0, config=None) -> S7PLC:
    scenario = load_scenario(SCENARIO)
    kw = dict(speed=600, port=port, scan_s=0.05)
    plc = S7PLC(scenario, **kw) if config is None else S7PLC.of_config(scenario, config, **kw)
    await plc.start()
    return plc


def plant_tc(plc_seconds) -> np.ndarray:
    """The noise-free test plant's thermocouples at each PLC second, degC, as REALs (single
    precision) hold them."""
    scenario = load_scenario(SCENARIO)
    seconds, back = np.unique(np.asarray(plc_seconds, dtype=float), return_inverse=True)
    run = Plant.from_scenario(scenario).run(scenario.inputs(), seconds / 60.0, scenario.initial_c)
    return run.tc.astype(np.float32).astype(float)[back]


async def run_daemon(config, log_dir, duration: float | None, during=None):
    log = LogWriter(log_dir, flush_interval_s=0.5, metadata=build_metadata(config),
                    event_priority=EVENT_PRIORITY)
    daemon = Daemon(config, log)
    task = asyncio.create_task(daemon.run(duration))
    if during is not None:
        await during(daemon)
    return daemon, await task


def logged(log_dir, topics=None):
    return [(t, m) for t, m, _, _ in read_messages(sorted(log_dir.glob("*.mcap")), topics)]


# -- the map ---------------------------------------------------------------------------------

def test_the_shipped_map_is_the_simulated_plcs():
    config = load_config(SHIPPED)
    assert config.plc.protocol == "s7" and config.plc.s7.rack == 0 and config.plc.s7.slot == 1
    served = {it.name: (it.addresses, getattr(it, "dtype", "bool")) for it in default_items(PAPER)}
    read = {it.name: (it.addresses, getattr(it, "dtype", "bool")) for it in config.plc_items()}
    assert read == served
    assert read["soak"][0][0].text == "I0.0" and read["soak"][0][-1].text == "I1.1"
    assert read["heartbeat"][0][0].text == "MW10"


@pytest.mark.parametrize(("change", "where", "words"), [
    (lambda d: d["thermocouples"]["soak_1"].update(s7="DB10.DBQ4"),
     "thermocouples.soak_1.s7", "'DB10.DBQ4' is not an S7 address"),
    (lambda d: d["thermocouples"]["soak_2"].update(s7="DB10.DBW8.1"),
     "thermocouples.soak_2.s7", "names a whole word (2 bytes), which has no bit"),
    (lambda d: d["thermocouples"]["heat_1"].update(s7="DB10.DBW12"),
     "thermocouples.heat_1.type", "real takes 4 bytes, but DB10.DBW12 is a word"),
    (lambda d: d.update(clock={"s7": "MB4", "type": "dint"}),
     "clock.type", "dint takes 4 bytes, but MB4 is a byte"),
    (lambda d: d["thermocouples"]["heat_2"].update(s7="DB10.DBX16.0"),
     "thermocouples.heat_2.type", "real takes 4 bytes, but DB10.DBX16.0 is a bit"),
    (lambda d: d.update(ambient={"s7": "DB10.DBX28.0", "type": "bool"}),
     "ambient.type", "is a number; bool is for burner states"),
    (lambda d: d["burners"]["modbus"]["soak"].update(s7="IW0"),
     "burners.modbus.soak.s7", "IW0 is a word (2 bytes): give a bit address, e.g. I0.0"),
    (lambda d: d["burners"]["modbus"]["heat"].update(s7=["I1.2", "I1.3"]),
     "burners.modbus.heat.s7", "expected 8 bit addresses, got 2"),
    (lambda d: d["burners"]["modbus"]["heat"].update(s7=["I1.2"] * 7 + ["MB3"]),
     "burners.modbus.heat.s7[7]", "MB3 is a byte"),
    (lambda d: d["plc"]["s7"].update(rack=9), "plc.s7.rack", "9"),
    (lambda d: d["plc"].update(opcua={"path": "/x"}), "plc.opcua", "protocol: opcua only"),
    (lambda d: d["plc"].update(device_id=3), "plc.device_id", "protocol: modbus only"),
    (lambda d: d.update(ambient={"table": "input", "address": 6}), "ambient",
     "device plc speaks s7: give an S7 address (s7:)"),
    (lambda d: d.update(ambient={"node": "ns=2;s=T"}), "ambient",
     "is given as a node (node: or nodes:), but device plc speaks s7"),
])
def test_a_wrong_entry_is_named_by_its_key_path(change, where, words):
    d = doc(102)
    change(d)
    with pytest.raises(ConfigError) as err:
        parse_config(Node(d, "gw.yaml"))
    assert f"gw.yaml: {where}" in str(err.value) and words in str(err.value), str(err.value)


def test_an_s7_address_on_a_modbus_device_is_refused():
    d = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    d["thermocouples"]["soak_2"] = {"s7": "DB10.DBD8"}
    with pytest.raises(ConfigError, match="thermocouples.soak_2: is given as an S7 address "
                                          r"\(s7:\), but device plc speaks modbus"):
        parse_config(Node(d, "gw.yaml"))


def test_reads_are_joined_per_area_and_packed_into_the_pdu():
    db = [S7Address("DB", 10, 4 * k, 4) for k in range(8)]
    far = S7Address("DB", 10, 400, 2)
    other = [S7Address("DB", 11, 0, 4), S7Address("M", 0, 10, 2), S7Address("I", 0, 0, 0, 3)]
    blocks = plan_blocks([*db, far, *other], max_gap=16, max_size=222)
    assert blocks == [S7Block("DB", 10, 0, 32), S7Block("DB", 10, 400, 2),
                      S7Block("DB", 11, 0, 4), S7Block("I", 0, 0, 1), S7Block("M", 0, 10, 2)]
    assert plan_requests(blocks, 480) == [blocks]  # one request reads all five
    # a small PDU: each reply holds 14 bytes of header, then 4 + the data (even) per piece
    big = [S7Block("DB", n, 0, 100) for n in range(1, 6)]
    packed = plan_requests(big, 240)
    assert [len(r) for r in packed] == [2, 2, 1]
    assert all(14 + sum(4 + b.size for b in r) <= 240 for r in packed)
    # and at most 20 pieces in one request, however small
    assert [len(r) for r in plan_requests([S7Block("M", 0, 2 * k, 1)
                                           for k in range(25)], 960)] == [20, 5]


def test_without_snap7_the_protocol_says_which_extra_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "snap7", None)  # an installation without the extra
    monkeypatch.delitem(sys.modules, "furnace_daq.s7source")
    with pytest.raises(FurnaceError, match=r"protocol s7 needs a package this installation "
                                           r"lacks .*pip install 'furnace-daq\[s7\]'"):
        source_class("s7")


# -- the daemon against python-snap7's server ------------------------------------------------

def test_the_daemon_logs_the_plcs_values(tmp_path):
    async def polled(daemon):
        await until(lambda: daemon.counters.ok_polls >= 10)
        daemon.stop()

    async def scenario():
        plc = await serve()
        try:
            return await run_daemon(cfg(plc.port), tmp_path, None, polled)
        finally:
            await plc.stop()

    daemon, counters = asyncio.run(scenario())
    assert counters.connects == 1 and counters.disconnects == 0
    tc = [m for t, m in logged(tmp_path, [THERMOCOUPLES])]
    good = [m for m in tc if set(m["quality"].values()) == {"ok"}]
    assert len(good) >= 10, tc[:3]
    seconds = [m["plc_seconds"] for m in good]
    assert seconds == sorted(seconds) and seconds[-1] > seconds[0]
    # every value is the plant's at the PLC second it was logged with: one scan's memory
    np.testing.assert_allclose([[m[s] for s in PAPER.sensors] for m in good],
                               plant_tc(seconds), rtol=0, atol=1e-9)
    burners = [m for t, m in logged(tmp_path, [BURNERS])]
    assert burners and all(m["quality"] == "ok" and m["source"] == "modbus" for m in burners)
    assert {len(m["soak"]) for m in burners} == {10}
    assert any(sum(m["soak"]) for m in burners), "some burners fire in the test plant"


def test_a_restarted_server_is_redialled_and_the_outage_is_not_ok(tmp_path):
    async def scenario():
        port = free_port()
        plc = await serve(port)

        async def restart(daemon):
            nonlocal plc
            c = daemon.counters
            await until(lambda: c.ok_polls >= 5)
            await plc.stop()
            await asyncio.sleep(1.0)
            plc = await serve(port)
            polled = c.ok_polls
            await until(lambda: c.connects >= 2 and c.ok_polls >= polled + 5)
            daemon.stop()

        try:
            return await run_daemon(cfg(port), tmp_path, None, restart)
        finally:
            await plc.stop()

    daemon, counters = asyncio.run(scenario())
    assert counters.connects == 2 and counters.disconnects == 1
    msgs = logged(tmp_path)
    states = [m["state"] for t, m in msgs if t == DAQ_STATUS]
    changes = [s for i, s in enumerate(states) if i == 0 or s != states[i - 1]]
    assert changes == ["disconnected", "connected", "disconnected", "connected", "disconnected"]
    k_lost = next(i for i, (t, m) in enumerate(msgs) if t == DAQ_STATUS and i > 0
                  and m["state"] == "disconnected" and m["detail"] != "starting")
    k_back = next(i for i, (t, m) in enumerate(msgs) if i > k_lost and t == DAQ_STATUS
                  and m["state"] == "connected")
    gap = [m for t, m in msgs[k_lost:k_back] if t == THERMOCOUPLES]
    assert all("ok" not in m["quality"].values() and "soak_1" not in m for m in gap)
    tc = [m for t, m in msgs if t == THERMOCOUPLES]
    seconds = [m["plc_seconds"] for m in tc if m["quality"]["soak_1"] == "ok"]
    assert min(np.diff(seconds)) < 0  # the new server's clock started again
    after = seconds[int(np.argmin(np.diff(seconds))) + 1:]
    assert len(after) >= 5


def test_a_vanished_data_block_is_named_and_only_its_items_are_comm_error(tmp_path, capsys):
    config = cfg(102, heat_2_apart)

    async def scenario():
        plc = await serve(config=config)

        async def drop(daemon):
            c = daemon.counters
            await until(lambda: c.ok_polls >= 5)
            plc.vanish("DB", 11)
            await until(lambda: sum(c.incomplete.values()) >= 5)
            daemon.stop()

        try:
            return await run_daemon(cfg(plc.port, heat_2_apart), tmp_path, None, drop)
        finally:
            await plc.stop()

    daemon, counters = asyncio.run(scenario())
    assert counters.disconnects == 0
    why = "DB11 bytes 0-3: object does not exist (return code 0x0A)"
    tc = [m for t, m in logged(tmp_path, [THERMOCOUPLES])]
    after = [m for m in tc if m["quality"]["heat_2"] == "comm_error"]
    assert len(after) >= 5
    for m in after:
        assert m["error"] == why and "heat_2" not in m
        assert {q for s, q in m["quality"].items() if s != "heat_2"} == {"ok"}
    before = [m for m in tc if m["quality"]["heat_2"] == "ok"]
    assert before and all("error" not in m for m in before)
    # the journal is told once (then the repeats are counted), naming the key, as for a
    # refused Modbus block; every poll after it is counted incomplete by that area
    err = capsys.readouterr().err.splitlines()
    told = [line for line in err if why in line]
    assert told[0].startswith("<3>PLC 127.0.0.1:") and told[0].endswith(
        f": {why}: thermocouples.heat_2 not read (check the map)"), told
    assert len(told) <= 2 and counters.incomplete == {why: len(after)}


def test_a_slow_plc_is_named_by_the_read_that_timed_out():
    async def scenario():
        plc = await serve()
        proxy = StallingProxy(plc.port)
        await proxy.start()
        config = cfg(proxy.port)
        source = S7Source(config)
        try:
            await source.connect()
            first = await source.read()
            proxy.stalled = True
            with pytest.raises(Exception) as err:
                await asyncio.wait_for(source.read(), config.plc.timeout_s)
            return first, err.value
        finally:
            await source.close()
            await proxy.stop()
            await plc.stop()

    first, error = asyncio.run(scenario())
    assert set(first.quality.values()) == {"ok"}
    assert getattr(error, "kind", None) == "poll timeout", repr(error)
    assert "read of 3 piece(s) at 127.0.0.1:" in str(error)
    assert str(error).endswith("no answer within 0.27 s")


def test_a_plc_that_is_not_there_is_a_refused_dial():
    config = cfg(free_port())
    source = S7Source(config)
    with pytest.raises(Exception) as err:
        asyncio.run(source.connect())
    assert getattr(err.value, "kind", None) == "connection refused", repr(err.value)
    assert str(err.value).startswith(f"cannot connect to 127.0.0.1:{config.plc.port}: ")


def test_check_reads_every_address_and_names_the_failing_one():
    config = cfg(102, heat_2_apart)

    async def scenario():
        plc = await serve(config=config)
        try:
            whole = await check(cfg(plc.port, heat_2_apart))
            plc.vanish("DB", 11)
            return whole, await check(cfg(plc.port, heat_2_apart))
        finally:
            await plc.stop()

    whole, broken = asyncio.run(scenario())
    assert whole.ok and len(whole.points) == 12
    text = format_report(whole)
    assert "S7 127.0.0.1:" in text and "rack 0 slot 1" in text
    assert "connected, 35 address(es) in 4 piece(s), 1 request(s) of PDU 480 bytes" in text
    assert "DB11.DBD0" in text and "I0.0-I1.1" in text and "MW10" in text
    assert [(p.key, p.where, p.error) for p in broken.failed] == [
        ("thermocouples.heat_2", "DB11.DBD0",
         "DB11 bytes 0-3: object does not exist (return code 0x0A)")]


# -- end to end ------------------------------------------------------------------------------

def test_sim_plc_over_s7_and_check_with_the_shipped_config():
    sim, port = start_simplc("--protocol", "s7", "--speed", "600", "--scan-s", "0.05")
    try:
        run = furnace_daq("check", "--config", str(SHIPPED), "--plc", f"127.0.0.1:{port}")
        out, err = run.communicate(timeout=60)
    finally:
        stop(sim)
    assert run.returncode == 0, out + err
    assert f"S7 127.0.0.1:{port} rack 0 slot 1: connected" in out
    assert "all 12 points ok" in out
