"""The daemon reading an OPC UA PLC: its map parsed with key-path errors, and the daemon's
own source against a real asyncua server on loopback (the simulated OPC UA PLC serving the
test plant): values as the plant has them, in subscription and polling mode, a server
restarted, a node that vanishes, a slow server, security and users, and `sim-plc
--protocol opcua` with `furnace-daq run` end to end."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
import yaml
from cryptography.x509.oid import ExtendedKeyUsageOID
from daq_processes import ROOT, SCENARIO, free_port, furnace_daq, start_simplc, stop, until
from stallproxy import StallingProxy

from furnace_daq.check import check, format_report
from furnace_daq.daemon import EVENT_PRIORITY, Daemon
from furnace_daq.daqconfig import load_config, parse_config
from furnace_daq.logmeta import build_metadata
from furnace_daq.mcaplog import LogWriter
from furnace_daq.opcuaserver import OpcUaPLC, default_items
from furnace_daq.opcuasource import OpcUaSource
from furnace_model.config import Node
from furnace_model.errors import ConfigError
from furnace_model.log.read import read_messages
from furnace_model.log.schema import BURNERS, DAQ_STATUS, THERMOCOUPLES
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

SHIPPED = ROOT / "config" / "gateway-opcua.yaml"


def doc(port: int, **opcua) -> dict:
    """The shipped OPC UA map, sped up: 20 Hz polls, 0.3 s timeout, quick redials."""
    d = yaml.safe_load(SHIPPED.read_text())
    d["poll_period_s"] = 0.05
    d["stale_after_s"] = 0.5
    d["refit"]["enabled"] = False
    d["plc"].update(port=port, timeout_s=0.3, max_consecutive_errors=2,
                    reconnect={"initial_s": 0.1, "max_s": 0.4, "retry_s": 0.1})
    d["plc"]["opcua"].update(opcua)
    return d


def cfg(port: int, **opcua):
    return parse_config(Node(doc(port, **opcua), str(SHIPPED)))


SPEED = 600.0
"""The served plant's seconds per second."""


async def serve(port: int = 0, **kw) -> OpcUaPLC:
    plc = OpcUaPLC(load_scenario(SCENARIO), speed=SPEED, port=port, scan_s=0.05, **kw)
    await plc.start()
    return plc


def plant_tc(plc_seconds) -> np.ndarray:
    """The noise-free test plant's thermocouples at each PLC second, degC (served as
    doubles: no rounding)."""
    scenario = load_scenario(SCENARIO)
    seconds, back = np.unique(np.asarray(plc_seconds, dtype=float), return_inverse=True)
    run = Plant.from_scenario(scenario).run(scenario.inputs(), seconds / 60.0, scenario.initial_c)
    return run.tc[back]


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
    assert config.plc.protocol == "opcua" and config.plc.port == 4840
    assert config.plc.opcua.path == "/furnace" and config.plc.opcua.mode == "subscribe"
    served = {it.name: it.nodes for it in default_items(PAPER)}
    read = {it.name: it.nodes for it in config.plc_items()}
    assert read.keys() == served.keys()
    # the ambient by its browse path, every other item by the NodeId served
    assert {k for k in read if read[k] != served[k]} == {"t_air"}
    assert read["t_air"] == ("/0:Objects/2:Furnace/2:t_air",)


@pytest.mark.parametrize(("change", "where", "words"), [
    (lambda d: d["thermocouples"]["soak_1"].update(node="ns=2;Soak"),
     "thermocouples.soak_1.node", "is not a NodeId"),
    (lambda d: d["thermocouples"]["heat_1"].update(type="boolean"),
     "thermocouples.heat_1.type", "is a number"),
    (lambda d: d["burners"]["modbus"]["soak"].update(node=None, nodes=["ns=2;s=B1"]),
     "burners.modbus.soak", "not both"),
    (lambda d: d["burners"]["modbus"]["heat"].pop("node") and
     d["burners"]["modbus"]["heat"].update(nodes=["ns=2;s=B1", "ns=2;s=B2"]),
     "burners.modbus.heat.nodes", "expected 8 nodes, got 2"),
    (lambda d: d["plc"].update(device_id=3), "plc.device_id", "protocol: modbus only"),
    (lambda d: d["plc"]["opcua"].update(mode="push"), "plc.opcua.mode", "push"),
    (lambda d: d["plc"]["opcua"].update(security={"policy": "Basic256Sha256"}),
     "plc.opcua.security.certificate", "required"),
    (lambda d: d["plc"]["opcua"].update(security={"policy": "None", "mode": "Sign"}),
     "plc.opcua.security.mode", "goes with mode None"),
    (lambda d: d["plc"]["opcua"].update(password="x"), "plc.opcua.password", "goes with user"),
    (lambda d: d.update(ambient={"table": "input", "address": 6}), "ambient",
     "device plc speaks opcua"),
    (lambda d: d["plc"].update(protocol="profinet"), "plc.protocol", "profinet"),
])
def test_a_wrong_entry_is_named_by_its_key_path(change, where, words):
    d = doc(4840)
    change(d)
    with pytest.raises(ConfigError) as err:
        parse_config(Node(d, "gw.yaml"))
    assert f"gw.yaml: {where}" in str(err.value) and words in str(err.value), str(err.value)


def test_a_node_on_a_modbus_device_is_refused():
    d = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    d["thermocouples"]["soak_2"] = {"node": "ns=2;s=Furnace.soak_2"}
    with pytest.raises(ConfigError, match="thermocouples.soak_2: is given as a node .* "
                                          "device plc speaks modbus"):
        parse_config(Node(d, "gw.yaml"))


# -- the daemon against a real server -------------------------------------------------------

@pytest.mark.parametrize("mode", ["subscribe", "poll"])
def test_the_daemon_logs_the_plcs_values(tmp_path, mode):
    async def polled(daemon):
        await until(lambda: daemon.counters.ok_polls >= 10)
        daemon.stop()

    async def scenario():
        plc = await serve()
        try:
            return await run_daemon(cfg(plc.port, mode=mode, sampling_interval_ms=50),
                                    tmp_path, None, polled)
        finally:
            await plc.stop()

    daemon, counters = asyncio.run(scenario())
    assert counters.connects == 1 and counters.disconnects == 0
    tc = [m for t, m in logged(tmp_path, [THERMOCOUPLES])]
    good = [m for m in tc if set(m["quality"].values()) == {"ok"}]
    assert len(good) >= 10, tc[:3]
    seconds = [m["plc_seconds"] for m in good]
    assert seconds == sorted(seconds) and seconds[-1] > seconds[0]
    want = plant_tc(seconds)
    got = np.array([[m[s] for s in PAPER.sensors] for m in good])
    np.testing.assert_allclose(got, want, atol=1e-6)
    burners = [m for t, m in logged(tmp_path, [BURNERS])]
    assert burners and all(m["quality"] == "ok" and m["source"] == "modbus" for m in burners)
    assert {len(m["soak"]) for m in burners} == {10}


def test_a_restarted_server_is_redialled_and_the_outage_is_comm_error(tmp_path):
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
            # the daemon finds the new server within its redial interval (0.1 s) and goes on
            polled = c.ok_polls
            await until(lambda: c.connects >= 2 and c.ok_polls >= polled + 5)
            daemon.stop()

        try:
            return await run_daemon(cfg(port, mode="poll"), tmp_path, None, restart)
        finally:
            await plc.stop()

    daemon, counters = asyncio.run(scenario())
    assert counters.connects == 2 and counters.disconnects == 1
    msgs = logged(tmp_path)
    states = [m["state"] for t, m in msgs if t == DAQ_STATUS]
    changes = [s for i, s in enumerate(states) if i == 0 or s != states[i - 1]]
    assert changes == ["disconnected", "connected", "disconnected", "connected", "disconnected"]
    # while the server is away nothing is read: no reading between the two status changes
    # is ok (a poll that failed on the way down is logged comm_error, without values)
    k_lost = next(i for i, (t, m) in enumerate(msgs) if t == DAQ_STATUS
                  and m["detail"] == "connection closed by the PLC")
    k_back = next(i for i, (t, m) in enumerate(msgs) if i > k_lost and t == DAQ_STATUS
                  and m["state"] == "connected")
    gap = [m for t, m in msgs[k_lost:k_back] if t == THERMOCOUPLES]
    assert all(set(m["quality"].values()) == {"comm_error"} and "soak_1" not in m for m in gap)
    # The new server's clock is its own, started with it: a reading's clock origin (its host
    # time less its PLC seconds at the served speed) moves on by at least the second the
    # server was away, however long the daemon took to find the new one.
    origin = np.array([log_ns / 1e9 - m["plc_seconds"] / SPEED for _, m, log_ns, _
                       in read_messages(sorted(tmp_path.glob("*.mcap")), [THERMOCOUPLES])
                       if m["quality"]["soak_1"] == "ok"])
    moved = int(np.argmax(np.diff(origin)))
    assert np.diff(origin)[moved] > 0.5, origin
    assert origin.size - moved - 1 >= 5  # read from the new server


def test_a_vanished_node_is_named_and_only_its_item_is_comm_error(tmp_path, capsys):
    async def scenario():
        plc = await serve()

        async def drop(daemon):
            c = daemon.counters
            await until(lambda: c.ok_polls >= 5)
            await plc.vanish("heat_2")
            await until(lambda: sum(c.incomplete.values()) >= 5)
            daemon.stop()

        try:
            return await run_daemon(cfg(plc.port, mode="poll"), tmp_path, None, drop)
        finally:
            await plc.stop()

    daemon, counters = asyncio.run(scenario())
    assert counters.disconnects == 0
    tc = [m for t, m in logged(tmp_path, [THERMOCOUPLES])]
    after = [m for m in tc if m["quality"]["heat_2"] == "comm_error"]
    assert len(after) >= 5
    for m in after:
        assert m["error"] == "ns=2;s=Furnace.heat_2: BadNodeIdUnknown"
        assert "heat_2" not in m
        assert {q for s, q in m["quality"].items() if s != "heat_2"} == {"ok"}
    before = [m for m in tc if m["quality"]["heat_2"] == "ok"]
    assert before and all("error" not in m for m in before)
    # the journal hears of it as of a refused Modbus block: once, naming the key
    why = "ns=2;s=Furnace.heat_2: BadNodeIdUnknown"
    told = [line for line in capsys.readouterr().err.splitlines() if why in line]
    assert told and told[0].startswith("<3>PLC 127.0.0.1:") and told[0].endswith(
        f": {why}: thermocouples.heat_2 not read (check the map)"), told
    assert counters.incomplete == {why: len(after)}


def test_a_slow_server_is_named_by_the_read_that_timed_out(tmp_path):
    async def scenario():
        plc = await serve()
        proxy = StallingProxy(plc.port)
        await proxy.start()
        config = cfg(proxy.port, mode="poll", path="/furnace")
        source = OpcUaSource(config)
        try:
            await source.connect()
            first = await source.read()
            proxy.stalled = True
            daemon_budget = config.plc.timeout_s
            with pytest.raises(Exception) as err:
                await asyncio.wait_for(source.read(), daemon_budget)
            return first, err.value
        finally:
            await source.close()
            await proxy.stop()
            await plc.stop()

    first, error = asyncio.run(scenario())
    assert set(first.quality.values()) == {"ok"}
    assert getattr(error, "kind", None) == "poll timeout", repr(error)
    assert "read of 12 node(s) at opc.tcp://127.0.0.1:" in str(error)
    assert "no answer within 0.27 s" in str(error)


# -- security --------------------------------------------------------------------------------

def _certificate(folder, name: str, server: bool):
    from asyncua.crypto.cert_gen import setup_self_signed_certificate

    key, cert = folder / f"{name}-key.pem", folder / f"{name}-cert.der"
    use = [ExtendedKeyUsageOID.SERVER_AUTH if server else ExtendedKeyUsageOID.CLIENT_AUTH]
    asyncio.run(setup_self_signed_certificate(key, cert, f"urn:furnace-daq:{name}",
                                              "localhost", use, {"commonName": name}))
    key.chmod(0o600)
    return cert, key


def test_sign_and_encrypt_with_a_user_and_a_trusted_server(tmp_path):
    pki = tmp_path / "pki"
    pki.mkdir()
    server_cert, server_key = _certificate(pki, "plc", server=True)
    other_cert, _ = _certificate(pki, "impostor", server=True)
    gw_cert, gw_key = _certificate(pki, "gateway", server=False)

    def secured(port, trusted, password):
        d = doc(port, mode="poll", user="furnace", password=password,
                security={"policy": "Basic256Sha256", "mode": "SignAndEncrypt",
                          "certificate": str(gw_cert), "private_key": str(gw_key),
                          "server_certificate": str(trusted)})
        return parse_config(Node(d, str(tmp_path / "gw.yaml")))

    async def scenario():
        plc = await serve(certificate=server_cert, private_key=server_key,
                          users={"furnace": "s3cret"})
        out = {}
        try:
            for case, trusted, password in (("ok", server_cert, "s3cret"),
                                            ("bad password", server_cert, "wrong"),
                                            ("untrusted", other_cert, "s3cret")):
                source = OpcUaSource(secured(plc.port, trusted, password))
                try:
                    await source.connect()
                    out[case] = await source.read()
                except Exception as exc:
                    out[case] = exc
                finally:
                    await source.close()
            plain = OpcUaSource(cfg(plc.port, mode="poll"))
            try:
                await plain.connect()
                out["plain"] = await plain.read()
            except Exception as exc:
                out["plain"] = exc
            finally:
                await plain.close()
        finally:
            await plc.stop()
        return out

    out = asyncio.run(scenario())
    assert set(out["ok"].quality.values()) == {"ok"}, out["ok"]
    assert getattr(out["bad password"], "kind", None) == "access denied", out["bad password"]
    assert "user or password refused" in str(out["bad password"])
    assert getattr(out["untrusted"], "kind", None) == "security refused", out["untrusted"]
    assert "certificate (CN=plc," in str(out["untrusted"])
    assert "is not the trusted one, " in str(out["untrusted"])
    assert str(out["untrusted"]).endswith("impostor-cert.der")
    # no security at all: the server offers none, and refuses the session
    assert getattr(out["plain"], "kind", None) in ("security refused", "session refused"), \
        out["plain"]


def test_check_reads_every_node_and_names_the_failing_one():
    async def scenario():
        plc = await serve()
        try:
            whole = await check(cfg(plc.port))
            await plc.vanish("preheat_1")
            return whole, await check(cfg(plc.port, mode="poll"))
        finally:
            await plc.stop()

    whole, broken = asyncio.run(scenario())
    assert whole.ok and len(whole.points) == 12
    text = format_report(whole)
    assert "OPC UA opc.tcp://127.0.0.1:" in text and "connected, 12 node(s)" in text
    assert "/0:Objects/2:Furnace/2:t_air" in text and "burners.modbus.soak" in text
    assert [(p.key, p.where, p.error) for p in broken.failed] == [
        ("thermocouples.preheat_1", "ns=2;s=Furnace.preheat_1", "BadNodeIdUnknown")]


# -- end to end ------------------------------------------------------------------------------

def test_sim_plc_over_opcua_and_the_daemon_writing_mcap(tmp_path):
    sim, port = start_simplc("--protocol", "opcua", "--speed", "600", "--scan-s", "0.05")
    try:
        config = tmp_path / "gw.yaml"
        d = doc(port, mode="subscribe", sampling_interval_ms=100)
        d["poll_period_s"] = 0.2
        config.write_text(yaml.safe_dump(d))
        run = furnace_daq("run", "--config", str(config), "--log-dir", str(tmp_path / "logs"),
                          "--duration", "3")
        _, err = run.communicate(timeout=60)
        assert run.returncode == 0, err
    finally:
        stop(sim)
    tc = [m for t, m in logged(tmp_path / "logs", [THERMOCOUPLES])
          if set(m["quality"].values()) == {"ok"}]
    assert len(tc) >= 5
    seconds = [m["plc_seconds"] for m in tc]
    np.testing.assert_allclose([[m[s] for s in PAPER.sensors] for m in tc], plant_tc(seconds),
                               atol=1e-6)
