"""The daemon speaks systemd's notify protocol to a real datagram socket, feeds the watchdog
from the poll loop even while the PLC is down, and SIGTERM leaves a finished MCAP file."""

from __future__ import annotations

import signal
import socket
import time

from daq_processes import ROOT, free_port, furnace_daq

from furnace_daq.sdnotify import Notifier
from furnace_model.log.read import read_messages
from furnace_model.log.schema import DAQ_STATUS


def test_notify_watchdog_and_sigterm(tmp_path):
    sock_path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(sock_path))
    sock.settimeout(0.2)
    got: list[str] = []
    proc = furnace_daq("run", "--config", str(ROOT / "config" / "gateway.yaml"),
                       "--plc", f"127.0.0.1:{free_port()}", "--log-dir", str(tmp_path / "logs"),
                       "--no-refit",
                       env={"NOTIFY_SOCKET": str(sock_path), "WATCHDOG_USEC": "400000"})
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and sum(m == "WATCHDOG=1" for m in got) < 3:
            try:
                got.append(sock.recv(4096).decode())
            except TimeoutError:
                assert proc.poll() is None, proc.stderr.read()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
        while True:
            try:
                got.append(sock.recv(4096).decode())
            except (TimeoutError, BlockingIOError):
                break
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        sock.close()
    assert proc.returncode == 0, err
    assert got[0].startswith("READY=1")
    assert sum(m == "WATCHDOG=1" for m in got) >= 3, "fed while the PLC is unreachable"
    assert any(m.startswith("STATUS=disconnected") for m in got)
    assert "STOPPING=1" in got
    files = list((tmp_path / "logs").glob("*.mcap*"))  # not the directory lock
    assert len(files) == 1 and files[0].suffix == ".mcap", files
    status = [m for t, m, _, _ in read_messages(files) if t == DAQ_STATUS]
    assert status[-1]["detail"] == "stopping" and status[-1]["connect_attempts"] >= 2


def test_notifier_is_silent_outside_systemd_and_handles_abstract_sockets():
    n = Notifier({})
    assert not n.enabled and not n.send("READY=1")
    a = Notifier({"NOTIFY_SOCKET": "@furnace-test", "WATCHDOG_USEC": "2000000"})
    assert a.address == b"\0furnace-test" and a.watchdog_s == 2.0
    assert Notifier({"NOTIFY_SOCKET": "/x", "WATCHDOG_USEC": "5", "WATCHDOG_PID": "1"}) \
        .watchdog_s is None  # meant for another process
