"""The live view's WebSocket handshake as clients meet it: the one subprotocol it accepts
(foxglove.sdk.v1), what a client offering only the older name sees, and the library's own
lines in the journal, prefixed with a priority like the daemon's."""

from __future__ import annotations

import base64
import io
import logging
import os
import re
import socket

import yaml
from daq_processes import ROOT, free_port, furnace_daq, start_simplc, stop, wait_for_line

from furnace_daq.journal import ERR, INFO, WARNING, Journal, JournalHandler
from furnace_daq.liveview import SUBPROTOCOL

GATEWAY = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())


def handshake(port: int, subprotocol: str) -> str:
    """The server's answer to a WebSocket opening handshake offering `subprotocol`."""
    key = base64.b64encode(os.urandom(16)).decode()
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                  f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                  f"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {subprotocol}\r\n"
                  "\r\n".encode())
        answer = b""
        while b"\r\n\r\n" not in answer:
            chunk = s.recv(4096)
            if not chunk:
                break
            answer += chunk
    return answer.decode("latin-1")


def test_the_live_view_speaks_foxglove_sdk_v1_and_says_so_in_the_journal(tmp_path):
    port = free_port()
    doc = {**GATEWAY, "refit": {**GATEWAY["refit"], "enabled": False},
           "live_view": {"enabled": True, "port": port}}
    cfg = tmp_path / "gateway.yaml"
    cfg.write_text(yaml.safe_dump(doc))
    plc, plc_port = start_simplc("--speed", "600")
    daemon = furnace_daq("run", "--config", str(cfg), "--plc", f"127.0.0.1:{plc_port}",
                         "--log-dir", str(tmp_path / "logs"), "--duration", "60")
    try:
        seen = wait_for_line(daemon, r"live view: Foxglove WebSocket on ws://127\.0\.0\.1:")
        old = handshake(port, "foxglove.websocket.v1")
        new = handshake(port, SUBPROTOCOL)
        seen += wait_for_line(daemon, r"Registered client")
        # the refused client's warning and the accepted one's notice come from the
        # server's own threads, in either order
        if not any("handshake failed" in line for line in seen):
            seen += wait_for_line(daemon, r"handshake failed", timeout=10.0)
    finally:
        stop(daemon)
        stop(plc)
    assert old.startswith("HTTP/1.1 400 Bad Request"), old
    assert new.startswith("HTTP/1.1 101 "), new
    assert re.search(r"(?im)^sec-websocket-protocol: foxglove\.sdk\.v1\r$", new), new
    refused = [line for line in seen if "handshake failed" in line]
    # a client's failure is a warning in the journal, never an error of the daemon's
    assert len(refused) == 1 and refused[0].startswith("<4>live view: Dropping client "
                                                       "127.0.0.1:"), seen
    assert f"subprotocol {SUBPROTOCOL}" in refused[0]
    assert any(line.startswith("<6>live view: Registered client 127.0.0.1:") for line in seen)
    assert all(re.match(r"<[3-6]>", line) for line in seen), seen  # nothing unprefixed


def test_library_records_become_journal_lines_capped_and_rate_limited():
    out = io.StringIO()
    now = [0.0]
    journal = Journal(repeat_s=60.0, stream=out, clock=lambda: now[0])
    logger = logging.getLogger("test_liveview_protocol.library")
    logger.propagate = False
    logger.setLevel(logging.DEBUG)  # the handler, not the logger, drops DEBUG
    handler = JournalHandler(journal, "lib", most=WARNING)
    logger.addHandler(handler)
    try:
        logger.error("client %s failed", "10.0.0.1:4000")
        logger.error("client %s failed", "10.0.0.2:4001")  # the same kind: held back, counted
        logger.info("started")
        logger.debug("not said")
        now[0] = 61.0
        logger.error("client %s failed", "10.0.0.1:4002")
    finally:
        logger.removeHandler(handler)
    assert out.getvalue().splitlines() == [
        "<4>lib: client 10.0.0.1:4000 failed",
        "<6>lib: started",
        "<4>lib: client 10.0.0.1:4002 failed [1 more like this in the last 61 s]",
    ]
    uncapped = io.StringIO()
    JournalHandler(Journal(stream=uncapped), "lib").handle(
        logging.LogRecord("x", logging.ERROR, __file__, 1, "broken", None, None))
    assert uncapped.getvalue() == f"<{ERR}>lib: broken\n" and INFO == 6
