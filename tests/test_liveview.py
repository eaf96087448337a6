"""The live view (furnace_daq.liveview) seen by a Foxglove WebSocket client we did not write:

@foxglove/ws-protocol's FoxgloveClient, run by node from tests/node. The daemon runs as the
CLI runs it, against the simulated PLC, on loopback only."""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
from collections import Counter
from pathlib import Path

import pytest
import yaml
from daq_processes import ROOT, free_port, furnace_daq, start_simplc, stop, wait_for_line
from mcap.reader import make_reader
from test_security import listening_sockets

from furnace_daq.daqconfig import parse_config
from furnace_daq.liveview import LiveView, LiveViewConfig
from furnace_daq.mcaplog import LogWriter
from furnace_model.config import Node
from furnace_model.errors import ConfigError, FurnaceError
from furnace_model.log.read import read_messages
from furnace_model.log.schema import (
    AMBIENT,
    BURNERS,
    DAQ_STATUS,
    SCHEMA_ENCODING,
    THERMOCOUPLES,
    topics,
)
from furnace_model.simulation.furnace import PAPER

TOPICS = topics(PAPER)
"""The paper's furnace's topics, which these tests check."""

NODE_DIR = Path(__file__).resolve().parent / "node"
GATEWAY = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())


def gateway(**changes) -> dict:
    doc = json.loads(json.dumps(GATEWAY))
    doc["refit"]["enabled"] = False
    doc.update(changes)
    return doc


# -- config ------------------------------------------------------------------------------

def test_live_view_is_off_by_default_and_loopback_when_on():
    assert parse_config(Node(gateway(), "g.yaml")).live_view is None
    on = parse_config(Node(gateway(live_view={"enabled": True}), "g.yaml")).live_view
    assert on == LiveViewConfig("127.0.0.1", 8765)
    cfg = parse_config(Node(gateway(live_view={"enabled": True, "host": "0.0.0.0",
                                               "port": 9000}), "g.yaml"))
    assert cfg.live_view == LiveViewConfig("0.0.0.0", 9000)


@pytest.mark.parametrize("section, key", [
    ({"enabled": True, "port": 0}, "live_view.port"),
    ({"enabled": True, "port": 70000}, "live_view.port"),
    ({"enabled": False, "port": "http"}, "live_view.port"),  # checked even when off
    ({"enabled": "yes please"}, "live_view.enabled"),
    ({"enabled": True, "host": ""}, "live_view.host"),
    ({"enabled": True, "prot": 8765}, "live_view.prot"),
    ("on", "live_view"),
])
def test_live_view_config_errors_name_the_key(section, key):
    with pytest.raises(ConfigError) as err:
        parse_config(Node(gateway(live_view=section), "g.yaml"))
    assert err.value.path == key, str(err.value)
    assert str(err.value).startswith(f"g.yaml: {key}")


# -- failures ----------------------------------------------------------------------------

def test_a_failing_listener_never_stops_the_log(tmp_path):
    def broken(topic: str, data: bytes, log_time_ns: int) -> None:
        raise RuntimeError("the live view fell over")

    seen: list[tuple[str, int]] = []
    with LogWriter(tmp_path) as log:
        log.listeners += [broken, lambda t, d, ns: seen.append((t, ns))]
        for i in range(5):
            log.write(THERMOCOUPLES, {"soak_1": 600.0 + i}, 10**18 + i)
        log.write(DAQ_STATUS, {"state": "connected", "detail": "ok"}, 10**18 + 9)
    logged = [(t, lt) for t, _, lt, _ in read_messages(sorted(tmp_path.glob("*.mcap")))]
    assert len(logged) == 7  # five readings, the status and its /log line
    assert seen == logged  # the other listener still had every one, /log included


def test_live_view_send_never_raises_once_stopped():
    view = LiveView(LiveViewConfig("127.0.0.1", free_port()), furnace=PAPER)
    view.close()
    view.send(THERMOCOUPLES, b'{"soak_1": 600.0}', 1)
    view.send("/not/a/contract/topic", b"not even json", 2)
    view.close()


def test_port_taken_is_a_clear_error_at_start(tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(FurnaceError, match=r"^live_view\.port: .*127\.0\.0\.1:\d+"):
            LiveView(LiveViewConfig("127.0.0.1", port), furnace=PAPER)
        cfg = tmp_path / "gateway.yaml"
        cfg.write_text(yaml.safe_dump(gateway(live_view={"enabled": True, "port": port})))
        proc = furnace_daq("run", "--config", str(cfg), "--log-dir", str(tmp_path / "logs"),
                           "--plc", "127.0.0.1:1", "--duration", "5")
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 1, err
    assert f"{cfg}: live_view.port: cannot serve the live view on 127.0.0.1:{port}" in err
    assert "Traceback" not in err


# -- a client we did not write -----------------------------------------------------------

@pytest.fixture(scope="module")
def node() -> str:
    exe = shutil.which("node")
    if exe is None:
        pytest.skip("node is not installed: the live view's client test runs "
                    "@foxglove/ws-protocol under node")
    if not (NODE_DIR / "node_modules" / "@foxglove" / "ws-protocol").is_dir():
        npm = shutil.which("npm")
        assert npm, "npm (with node) installs tests/node's client packages"
        out = subprocess.run([npm, "ci", "--no-audit", "--no-fund"], cwd=NODE_DIR,
                             capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stdout + out.stderr
    return exe


def log_schemas(logs: Path) -> dict[str, tuple[str, str, bytes]]:
    """Each MCAP channel's (schema name, schema encoding, schema) by topic."""
    out = {}
    for path in sorted(logs.glob("*.mcap")):
        with path.open("rb") as f:
            summary = make_reader(f).get_summary()
        for ch in summary.channels.values():
            s = summary.schemas[ch.schema_id]
            out[ch.topic] = (s.name, s.encoding, s.data)
    return out


def test_foxglove_client_sees_every_topic_as_logged_and_cannot_write(tmp_path, node):
    sim, plc_port = start_simplc()
    port = free_port()
    cfg = tmp_path / "gateway.yaml"
    cfg.write_text(yaml.safe_dump(gateway(poll_period_s=0.2, status_interval_s=0.5,
                                          live_view={"enabled": True, "port": port})))
    logs = tmp_path / "logs"
    daemon = furnace_daq("run", "--config", str(cfg), "--log-dir", str(logs),
                         "--plc", f"127.0.0.1:{plc_port}", "--duration", "60")
    try:
        line = wait_for_line(daemon, r"live view: Foxglove WebSocket on")[-1]
        assert f"ws://127.0.0.1:{port}" in line
        client = subprocess.run([node, "live_client.mjs", f"ws://127.0.0.1:{port}", "1.5"],
                                cwd=NODE_DIR, capture_output=True, text=True, timeout=30)
        assert client.returncode == 0, client.stdout + client.stderr
        seen = json.loads(client.stdout)
        # The one listening socket: the live view's, on loopback.
        assert listening_sockets(daemon.pid) == [("tcp", f"127.0.0.1:{port}")]
    finally:
        assert stop(daemon) == 0  # SIGTERM: the log is finished
        stop(sim)
    assert not seen["errors"], seen["errors"]

    # Read-only: nothing that writes is advertised, and writing is refused.
    assert seen["serverInfo"]["capabilities"] == []
    assert seen["services"] == []
    refusals = [s["message"] for s in seen["statuses"] if s["level"] == 2]
    assert sum("clientPublish" in m for m in refusals) == 2, seen["statuses"]
    assert [f["callId"] for f in seen["serviceCallFailures"]] == [7]
    assert seen["serviceCallResponses"] == 0

    # Every topic of the contract, each with its log channel's encoding and schema.
    channels = {c["topic"]: c for c in seen["channels"]}
    assert set(channels) == set(TOPICS)
    for name, t in TOPICS.items():
        c = channels[name]
        assert (c["encoding"], c["schemaName"], c["schemaEncoding"]) == \
            ("json", t.schema_name, SCHEMA_ENCODING)
        assert c["schema"].encode() == t.schema_bytes()
    in_file = log_schemas(logs)
    assert {THERMOCOUPLES, BURNERS, AMBIENT, DAQ_STATUS} <= set(in_file)
    for name, (schema_name, encoding, data) in in_file.items():
        assert (channels[name]["schemaName"], channels[name]["schemaEncoding"],
                channels[name]["schema"].encode()) == (schema_name, encoding, data)

    # What arrived is what was logged: same topic, message and log time.
    logged = {(t, lt): m for t, m, lt, _ in read_messages(sorted(logs.glob("*.mcap")))}
    counts = Counter(t for t, _, _ in seen["messages"])
    for name in (THERMOCOUPLES, BURNERS, AMBIENT, DAQ_STATUS):
        assert counts[name] >= 1, counts
    for name, stamp, text in seen["messages"]:
        assert logged[(name, int(stamp))] == json.loads(text)
    assert not any("written_by_client" in json.dumps(m) for m in logged.values())
    assert not any(t == "/client/write" for t, _ in logged)
