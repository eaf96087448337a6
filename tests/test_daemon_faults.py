"""The daemon against a PLC that is down, drops, stalls, freezes or loses a thermocouple:
the loop keeps its period, every change of state is on /daq/status, qualities say why."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import time
from pathlib import Path

import yaml
from daq_processes import ROOT, SCENARIO

from furnace_daq.daemon import Daemon
from furnace_daq.daqconfig import parse_config
from furnace_daq.logschema import DAQ_EVENTS, DAQ_STATUS, THERMOCOUPLES
from furnace_daq.mcaplog import LogWriter, read_messages
from furnace_daq.simplc import SimPLC
from furnace_daq.sources import ModbusSource
from furnace_model.config import Node
from furnace_model.scenario import load_scenario


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def config(port: int, **changes):
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["poll_period_s"] = 0.05
    doc["stale_after_s"] = 0.5
    doc["plc"].update(host="127.0.0.1", port=port, timeout_s=0.2, max_consecutive_errors=2,
                      reconnect={"initial_s": 0.1, "max_s": 0.4, "factor": 2.0})
    doc.update(changes)
    return parse_config(Node(doc, "test.yaml"))


def start_daemon(cfg, log_dir: Path, duration: float) -> tuple[Daemon, asyncio.Task]:
    daemon = Daemon(cfg, LogWriter(log_dir, flush_interval_s=0.5), plc=ModbusSource(cfg))
    return daemon, asyncio.create_task(daemon.run(duration))


def messages(log_dir: Path) -> list[tuple[str, dict, int]]:
    return [(t, m, lt) for t, m, lt, _ in read_messages(sorted(log_dir.glob("*.mcap")))]


async def sim(port: int) -> SimPLC:
    plc = SimPLC(load_scenario(SCENARIO), speed=600, port=port, scan_s=0.05)
    await plc.start()
    return plc


def test_down_at_start_then_dropped_then_back(tmp_path):
    async def scenario():
        port = free_port()
        daemon, task = start_daemon(config(port), tmp_path, 4.5)
        await asyncio.sleep(1.0)          # PLC not there yet: the daemon keeps dialling
        attempts_while_down = daemon.counters.connect_attempts
        plc = await sim(port)
        await asyncio.sleep(1.2)
        await plc.stop()                  # connection drops
        await asyncio.sleep(0.8)
        plc = await sim(port)             # and comes back
        counters = await task
        await plc.stop()
        return attempts_while_down, counters

    attempts, counters = asyncio.run(scenario())
    # backoff 0.1, 0.2, 0.4, 0.4 ... within 1 s: a handful of attempts, not a storm
    assert 3 <= attempts <= 7, attempts
    assert counters.connects == 2 and counters.disconnects == 1
    msgs = messages(tmp_path)
    status = [(m["state"], m["detail"]) for t, m, _ in msgs if t == DAQ_STATUS]
    changes = [s for i, s in enumerate(status) if i == 0 or s[0] != status[i - 1][0]]
    assert [s for s, _ in changes] == ["disconnected", "connected", "disconnected", "connected",
                                       "disconnected"], status
    assert changes[-1][1] == "stopping"
    # no data between the drop and the reconnect: the gap sits between two status messages
    t_drop = next(lt for t, m, lt in msgs if t == DAQ_STATUS and m["state"] == "disconnected"
                  and m["detail"] not in ("stopping",) and not m["detail"].startswith("starting"))
    t_back = [lt for t, m, lt in msgs if t == DAQ_STATUS and m["state"] == "connected"][1]
    ok_in_gap = [lt for t, m, lt in msgs if t == THERMOCOUPLES and t_drop < lt < t_back
                 and m["quality"]["soak_1"] == "ok"]
    assert not ok_in_gap
    assert (t_back - t_drop) / 1e9 > 0.5


class StallingProxy:
    """TCP proxy on loopback that can stop forwarding (a PLC that hangs mid-conversation)."""

    def __init__(self, target: int):
        self.target, self.stalled, self.port = target, False, 0
        self._server: asyncio.Server | None = None
        self._writers: list[asyncio.StreamWriter] = []

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._handle, "127.0.0.1", 0)
        self.port = self._server.sockets[0].getsockname()[1]

    async def _pipe(self, r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        with contextlib.suppress(OSError, asyncio.IncompleteReadError):
            while data := await r.read(4096):
                if self.stalled:
                    continue  # swallowed: the request never gets an answer
                w.write(data)
                await w.drain()
        w.close()

    async def _handle(self, reader, writer) -> None:
        up_r, up_w = await asyncio.open_connection("127.0.0.1", self.target)
        self._writers += [writer, up_w]
        await asyncio.gather(self._pipe(reader, up_w), self._pipe(up_r, writer))

    async def stop(self) -> None:
        for w in self._writers:
            w.close()
        self._server.close()
        await self._server.wait_closed()


def test_stalled_plc_never_stalls_the_loop(tmp_path):
    async def scenario():
        plc = await sim(free_port())
        proxy = StallingProxy(plc.port)
        await proxy.start()
        daemon, task = start_daemon(config(proxy.port), tmp_path, 3.0)
        await asyncio.sleep(0.8)
        proxy.stalled = True
        t_stall = time.time_ns()
        await asyncio.sleep(1.2)
        proxy.stalled = False
        counters = await task
        await proxy.stop()
        await plc.stop()
        return t_stall, counters

    t_stall, counters = asyncio.run(scenario())
    assert counters.comm_errors >= 2 and counters.disconnects >= 1
    assert counters.skipped_ticks >= 2, "a 0.2 s timeout at a 0.05 s period skips ticks"
    msgs = messages(tmp_path)
    errors = [lt for t, m, lt in msgs if t == THERMOCOUPLES
              and m["quality"]["soak_1"] == "comm_error"]
    assert errors and (errors[0] - t_stall) / 1e9 < 0.2 + 0.05 + 0.15
    tc_times = [lt for t, m, lt in msgs if t == THERMOCOUPLES]
    # between stall and recovery, no silence longer than timeout + period (+ scheduling slack)
    during = [b - a for a, b in zip(tc_times, tc_times[1:], strict=False) if a >= t_stall]
    assert during and max(during[:2]) / 1e9 < 0.2 + 0.05 + 0.1
    missed = [m for t, m, _ in msgs if t == DAQ_EVENTS and m["kind"] == "missed_tick"]
    assert len(missed) == 1 and missed[0]["skipped"] >= 1, "one event per status interval"
    states = [m["state"] for t, m, _ in msgs if t == DAQ_STATUS]
    assert "disconnected" in states[2:] and states[-2] == "connected", states
    assert msgs[-1][1]["detail"] == "stopping"
    ok_after = [m for t, m, lt in msgs if t == THERMOCOUPLES and lt > t_stall + 1.3e9
                and m["quality"]["soak_1"] == "ok"]
    assert ok_after, "data flows again once the PLC answers"


def test_frozen_plc_is_stale_and_open_sensor_is_null(tmp_path):
    async def scenario():
        plc = await sim(free_port())
        daemon, task = start_daemon(config(plc.port), tmp_path, 2.0)
        await asyncio.sleep(0.5)
        plc.open_sensors.add("heat_1")
        await asyncio.sleep(0.3)
        plc.frozen = True
        await task
        await plc.stop()

    asyncio.run(scenario())
    tc = [m for t, m, _ in messages(tmp_path) if t == THERMOCOUPLES]
    first, last = tc[0], tc[-1]
    assert first["quality"]["heat_1"] == "ok" and first["heat_1"] is not None
    assert last["heat_1"] is None and last["quality"]["heat_1"] == "sensor_open"
    assert last["quality"]["soak_1"] == "stale" and last["soak_1"] is not None
    n_stale = sum(m["quality"]["soak_1"] == "stale" for m in tc)
    # frozen for ~1.2 s, stale after 0.5 s without a heartbeat change: ~14 of 20 Hz ticks
    assert 8 <= n_stale <= 16, n_stale
