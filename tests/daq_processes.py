"""Starting and stopping the real `furnace-daq` pieces from tests: the CLI processes, and
the daemon and simulated PLC inside the test's own event loop (fast, on loopback)."""

from __future__ import annotations

import asyncio
import os
import re
import select
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import IO

import numpy as np
import yaml

from furnace_daq.daemon import EVENT_PRIORITY, Daemon
from furnace_daq.daqconfig import DaqConfig, parse_config
from furnace_daq.logmeta import build_metadata
from furnace_daq.mcaplog import LogWriter
from furnace_daq.simplc import SimPLC
from furnace_daq.sources import ModbusSource
from furnace_model.config import Node
from furnace_model.log.read import read_messages
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data"
SCENARIO = DATA / "daq_steps.yaml"


def furnace_daq(*args: str, **kw) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1", **kw.pop("env", {})}
    return subprocess.Popen([sys.executable, "-m", "furnace_daq.cli", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            **kw)


def start_simplc(*args: str, timeout: float = 20.0) -> tuple[subprocess.Popen, int]:
    """Start `furnace-daq sim-plc` on a free port; return once it prints where it listens."""
    return listening(furnace_daq("sim-plc", "--scenario", str(SCENARIO), "--port", "0", *args),
                     timeout)


def listening(proc: subprocess.Popen, timeout: float = 20.0) -> tuple[subprocess.Popen, int]:
    """`proc` and its port once a `sim-plc` says where it listens; stopped if it never does."""
    try:
        line = wait_for_line(proc, r"^listening on ", timeout, stream="stdout")[-1]
    except AssertionError as exc:
        proc.kill()
        _, err = proc.communicate(timeout=10)
        raise RuntimeError(f"sim-plc did not start: {exc}; stderr {err!r}") from None
    return proc, int(line.rsplit(":", 1)[1])


def read_line(stream: IO[str], deadline: float) -> str | None:
    """The next line of a child's pipe, '' at its end, None at `deadline`. Read a byte at a
    time: a buffered readline takes the lines after it into its buffer, where select no
    longer sees them, and a wait for one of them would wait in vain while the child is
    idle. Nothing past the line is taken, so a later read() or communicate() gets the rest."""
    fd, line = stream.fileno(), bytearray()
    while (left := deadline - time.monotonic()) > 0 and select.select([fd], [], [], left)[0]:
        byte = os.read(fd, 1)
        line += byte
        if byte in (b"\n", b""):
            return line.decode(errors="replace")
    return None


def wait_for_line(proc: subprocess.Popen, pattern: str, timeout: float = 30.0,
                  stream: str = "stderr") -> list[str]:
    """The lines of `proc`'s `stream` up to the first one that `pattern` matches (re.search);
    AssertionError with the lines seen if none comes within `timeout` or the pipe ends."""
    lines: list[str] = []
    deadline = time.monotonic() + timeout
    while (line := read_line(getattr(proc, stream), deadline)):
        lines.append(line)
        if re.search(pattern, line):
            return lines
    end = "the pipe ended" if line == "" else f"{timeout} s passed"
    raise AssertionError(f"no {stream} line like {pattern!r} before {end}: {lines}")


def stop(proc: subprocess.Popen, timeout: float = 10.0) -> int:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    for stream in (proc.stdout, proc.stderr):
        if stream:
            stream.close()
    return proc.returncode


# -- in-process daemon and simulated PLC ----------------------------------------------------

def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def config(port: int, **changes) -> DaqConfig:
    """The shipped gateway map, sped up: 20 Hz polls, 0.2 s timeout, backoff capped at 0.4 s."""
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["poll_period_s"] = 0.05
    doc["stale_after_s"] = 0.5
    doc["refit"]["enabled"] = False  # polling and logging only: no refit worker
    doc["plc"].update(host="127.0.0.1", port=port, timeout_s=0.2, max_consecutive_errors=2,
                      reconnect={"initial_s": 0.1, "max_s": 0.4, "factor": 2.0})
    doc.update(changes)
    return parse_config(Node(doc, "test.yaml"))


def start_daemon(cfg: DaqConfig, log_dir: Path, duration: float | None, **kw
                 ) -> tuple[Daemon, asyncio.Task]:
    """The daemon polling for `duration` seconds, or until stopped (None)."""
    log = LogWriter(log_dir, flush_interval_s=0.5, metadata=build_metadata(cfg),
                    event_priority=EVENT_PRIORITY)
    daemon = Daemon(cfg, log, plc=ModbusSource(cfg), **kw)
    return daemon, asyncio.create_task(daemon.run(duration))


async def until(condition, what: str = "", within_s: float = 30.0) -> None:
    """Until `condition()` holds: a busy host takes longer than a fixed sleep to start, to
    connect or to poll, so a test waits for what it needs; only a hang reaches the bound."""
    t_end = time.monotonic() + within_s
    while not condition():
        assert time.monotonic() < t_end, f"not within {within_s} s: {what}"
        await asyncio.sleep(0.02)


def messages(log_dir: Path) -> list[tuple[str, dict, int]]:
    """(topic, message, log_time_ns) of every file in `log_dir`, in log-time order."""
    return [(t, m, lt) for t, m, lt, _ in read_messages(sorted(log_dir.glob("*.mcap")))]


async def sim(port: int, **kw) -> SimPLC:
    """The noise-free test plant at 600x, scanned every 0.05 s. Port 0: a free port, chosen
    when it binds (`plc.port`); a port from `free_port` is only for a test that must know it
    before the PLC is there, since another process may take it meanwhile."""
    plc = SimPLC(load_scenario(SCENARIO), speed=600, port=port, scan_s=0.05, **kw)
    await plc.start()
    return plc


def plant_readings(plc_seconds) -> np.ndarray:
    """What the noise-free test plant's six thermocouple registers hold at each PLC second,
    in degC (0.1 degC counts), so a test can check every logged value."""
    scenario = load_scenario(SCENARIO)
    seconds, back = np.unique(np.asarray(plc_seconds, dtype=float), return_inverse=True)
    run = Plant.from_scenario(scenario).run(scenario.inputs(), seconds / 60.0, scenario.initial_c)
    return (np.round(run.tc * 10) / 10)[back]
