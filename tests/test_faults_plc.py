"""The daemon against a PLC that is down at start, drops, restarts, freezes, loses a
thermocouple or refuses one block of registers: the loop keeps its period, every change of
state is on /daq/status, and qualities say which values are good."""

from __future__ import annotations

import asyncio
import time
from dataclasses import replace

import numpy as np
import yaml
from daq_processes import (
    ROOT,
    config,
    free_port,
    messages,
    plant_readings,
    sim,
    start_daemon,
    until,
)

from furnace_daq.daqconfig import parse_config
from furnace_model.config import Node
from furnace_model.log.read import read_messages
from furnace_model.log.schema import AMBIENT, BURNERS, DAQ_EVENTS, DAQ_STATUS, THERMOCOUPLES
from furnace_model.simulation.furnace import PAPER


def test_down_at_start_then_dropped_then_back(tmp_path):
    async def scenario():
        port = free_port()
        daemon, task = start_daemon(config(port), tmp_path, None)
        c = daemon.counters
        await asyncio.sleep(1.0)          # PLC not there yet: the daemon keeps dialling
        attempts_while_down = c.connect_attempts
        plc = await sim(port)
        await until(lambda: c.ok_polls >= 10, "10 polls of the PLC once it is up")
        await plc.stop()                  # connection drops
        await asyncio.sleep(0.8)
        plc = await sim(port)             # and comes back
        polled = c.ok_polls
        await until(lambda: c.connects >= 2 and c.ok_polls >= polled + 5,
                    "5 polls of the PLC once it is back")
        daemon.stop()
        counters = await task
        await plc.stop()
        return attempts_while_down, counters

    attempts, counters = asyncio.run(scenario())
    # a refused dial is retried every 0.4 s (retry_s, capped at max_s): within 1 s a dial at
    # once and the retries after it, a handful of attempts, not a storm
    assert 2 <= attempts <= 7, attempts
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


def test_plc_restarted_mid_run(tmp_path):
    """A new PLC process on the same port: its clock starts again from 0. The daemon
    reconnects, says so with a plc_clock_reset event, re-anchors publish time, and logs the
    new PLC's values as they are."""
    async def scenario():
        port = free_port()
        plc = await sim(port)
        daemon, task = start_daemon(config(port), tmp_path, 60.0)
        c = daemon.counters
        await until(lambda: c.ok_polls >= 24, "24 polls of the first PLC")  # its clock > 600 s
        await plc.stop()
        plc = await sim(port)             # restarted at once: PLC clock back to 0
        polled = c.ok_polls
        await until(lambda: c.connects == 2 and c.ok_polls >= polled + 10,
                    "10 polls of the restarted PLC")
        daemon.stop()
        counters = await task
        await plc.stop()
        return counters

    counters = asyncio.run(scenario())
    assert counters.connects == 2 and counters.disconnects == 1
    log = sorted(tmp_path.glob("*.mcap"))
    tc = [(m, lt, pub) for t, m, lt, pub in read_messages(log, [THERMOCOUPLES])
          if m["quality"]["soak_1"] == "ok"]
    seconds = np.array([m["plc_seconds"] for m, _, _ in tc])
    back = np.flatnonzero(np.diff(seconds) < 0)
    assert len(back) == 1, seconds                        # one restart, seen once
    before, after = seconds[:back[0] + 1], seconds[back[0] + 1:]
    assert before[-1] > 300 and after[0] < 300, (before[-1], after[0])
    logged = np.array([[m[s] for s in PAPER.sensors] for m, _, _ in tc], dtype=float)
    np.testing.assert_allclose(logged, plant_readings(seconds), atol=0.1 + 1e-9)

    events = [(m, lt) for t, m, lt in messages(tmp_path) if t == DAQ_EVENTS
              and m["kind"] == "plc_clock_reset"]
    assert len(events) == 1 and "re-anchored" in events[0][0]["detail"]
    # publish time follows the new PLC clock from a new anchor: close to the host clock again
    # (the old anchor would put it ~10 min of plant time in the past)
    first_after = tc[back[0] + 1]
    assert abs(first_after[2] - first_after[1]) / 1e9 < 0.5
    assert all(tc[i + 1][2] >= tc[i][2] for i in range(back[0] + 1, len(tc) - 1))
    assert events[0][1] <= first_after[1]


def test_refused_block_is_comm_error_and_the_rest_stays_ok(tmp_path):
    """The map names two thermocouples at input registers the PLC does not have: the PLC
    answers that block with Modbus exception 2 (illegal address), every poll. Those two are
    comm_error; the other points of the same poll are logged ok, and the link stays up."""
    tc_map = {s: {"table": "input", "address": i, "type": "int16", "scale": 0.1,
                  "sentinels": [32767]} for i, s in enumerate(PAPER.sensors)}
    tc_map["heat_1"]["address"], tc_map["heat_2"]["address"] = 100, 101

    async def scenario():
        plc = await sim(0)
        daemon, task = start_daemon(config(plc.port, thermocouples=tc_map), tmp_path, None)
        await until(lambda: daemon.counters.polls >= 20, "20 polls")
        daemon.stop()
        counters = await task
        await plc.stop()
        return counters

    counters = asyncio.run(scenario())
    assert counters.disconnects == 0 and counters.comm_errors == 0
    msgs = messages(tmp_path)
    tc = [m for t, m, _ in msgs if t == THERMOCOUPLES]
    assert len(tc) >= 20
    for m in tc:
        assert m["error"] == "input 100+2: Modbus exception code 2 (illegal data address)"  # why, in the message
        assert "heat_1" not in m and "heat_2" not in m  # no number: absent
        assert m["quality"]["heat_1"] == m["quality"]["heat_2"] == "comm_error"
        assert {m["quality"][s] for s in ("soak_1", "soak_2", "preheat_1", "preheat_2")} == {"ok"}
    seconds = [m["plc_seconds"] for m in tc]
    want = plant_readings(seconds)
    for s in ("soak_1", "soak_2", "preheat_1", "preheat_2"):
        k = PAPER.sensors.index(s)
        np.testing.assert_allclose([m[s] for m in tc], want[:, k], atol=0.1 + 1e-9)
    assert len([m for t, m, _ in msgs if t == AMBIENT and m["quality"] == "ok"]) == len(tc)
    assert len([m for t, m, _ in msgs if t == BURNERS]) == len(tc)
    states = {m["state"] for t, m, _ in msgs if t == DAQ_STATUS}
    assert states == {"connected", "disconnected"}  # disconnected only at start and stop


def test_frozen_plc_is_stale_and_open_sensor_is_null(tmp_path):
    async def scenario():
        plc = await sim(0)
        daemon, task = start_daemon(config(plc.port), tmp_path, None)
        c = daemon.counters
        await until(lambda: c.ok_polls >= 5, "5 polls of the running PLC")
        plc.open_sensors.add("heat_1")
        scans = plc.heartbeat
        await until(lambda: plc.heartbeat >= scans + 2, "a PLC scan with the sensor open")
        plc.frozen = True
        await until(lambda: daemon.links[0].last_stale, "a poll of the frozen PLC that is stale")
        polled = c.polls
        await until(lambda: c.polls >= polled + 10, "10 polls of the stale PLC")
        daemon.stop()
        await task
        await plc.stop()

    asyncio.run(scenario())
    tc = [(m, lt) for t, m, lt in messages(tmp_path) if t == THERMOCOUPLES]
    (first, _), (last, _) = tc[0], tc[-1]
    assert first["quality"]["heat_1"] == "ok" and first["heat_1"] is not None
    assert "heat_1" not in last and last["quality"]["heat_1"] == "sensor_open"
    assert last["quality"]["soak_1"] == "stale" and last["soak_1"] is not None
    # Stale once the heartbeat has stood still for stale_after_s (0.5 s). It moves with the
    # PLC clock at every scan, so a poll is stale when the poll that last saw the clock move
    # started more than 0.5 s before it, give or take a read and the host's scheduling around
    # the two (0.3 s here); frozen, the PLC stays stale to the end.
    read = [(m, lt) for m, lt in tc if "plc_seconds" in m]  # the polls the PLC answered
    since, moved, clock = [], 0, None
    for m, lt in read:
        if m["plc_seconds"] != clock:
            moved, clock = lt, m["plc_seconds"]
        since.append((lt - moved) / 1e9)
    stale = [m["quality"]["soak_1"] == "stale" for m, _ in read]
    assert all(s for s, d in zip(stale, since, strict=True) if d > 0.5 + 0.3), (stale, since)
    assert not any(s for s, d in zip(stale, since, strict=True) if d < 0.5 - 0.3), \
        (stale, since)
    assert all(stale[stale.index(True):]), stale


def shipped_config(port: int, **plc):
    """config/gateway.yaml as shipped (poll every 1 s, the shipped redial schedule), on
    loopback, without refits; `plc` overrides keys of its plc block."""
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["refit"]["enabled"] = False
    doc["plc"].update(host="127.0.0.1", port=port, **plc)
    return parse_config(Node(doc, "gateway.yaml"))


def test_restarted_plc_is_polled_within_the_retry_interval(tmp_path):
    """The shipped redial schedule: a PLC that refuses is redialled every retry_s (0.5 s),
    and a new connection is polled at once. So once the daemon has seen the connection go
    (the PLC is down here for more than a poll period) and the restarted PLC accepts
    connections, the first good sample comes within retry_s + one connect + one read, each
    of which the daemon waits for at most timeout_s: 0.5 + 2 x 0.5 s here, whatever the
    poll period (the shipped 1 s) and however long the PLC was down within fast_for_s. The
    old schedule (backoff doubling from 0.5 s) was waiting 2 s by then, and then up to a
    period for the next tick."""
    down_s = 2.3
    cfg = shipped_config(free_port(), timeout_s=0.5)
    backoff = cfg.plc.reconnect
    assert (backoff.retry_s, backoff.fast_for_s, cfg.poll_period_s) == (0.5, 120.0, 1.0)
    bound_s = backoff.retry_s + 2 * cfg.plc.timeout_s

    async def scenario():
        plc = await sim(cfg.plc.port)
        # a run long enough that a busy host still reconnects within it: about 4 s after
        # the restart, against a bound of 1.5 s
        daemon, task = start_daemon(cfg, tmp_path, 8.0)
        await asyncio.sleep(1.5)
        await plc.stop()
        attempts_before = daemon.counters.connect_attempts
        await asyncio.sleep(down_s)
        plc = await sim(cfg.plc.port)     # accepting from here (or a little earlier)
        accepting_ns = time.time_ns()
        attempts_down = daemon.counters.connect_attempts - attempts_before
        counters = await task
        await plc.stop()
        return counters, accepting_ns, attempts_down

    counters, accepting_ns, attempts_down = asyncio.run(scenario())
    assert counters.connects == 2 and counters.disconnects == 1
    # not a storm while it was down: one dial per retry_s at most (and one at the edge)
    assert 2 <= attempts_down <= down_s / backoff.retry_s + 2, attempts_down
    ok = [lt for t, m, lt in messages(tmp_path) if t == THERMOCOUPLES
          and all(q == "ok" for q in m["quality"].values())]
    first_back = min(lt for lt in ok if lt > accepting_ns)
    assert (first_back - accepting_ns) / 1e9 <= bound_s, (first_back - accepting_ns) / 1e9
    assert counters.failures.get("connection refused", 0) >= 1, counters.failures


def test_a_plc_down_for_long_is_dialled_with_backoff_after_the_fast_phase(tmp_path):
    """Refused dials are retried every retry_s only for fast_for_s; after that they back off
    to max_s, so a PLC that stays down is not dialled twice a second for days."""
    cfg = config(free_port())
    cfg = replace(cfg, plc=replace(cfg.plc, reconnect=replace(
        cfg.plc.reconnect, retry_s=0.05, fast_for_s=0.5, initial_s=0.2, max_s=0.4)))

    async def scenario():
        daemon, task = start_daemon(cfg, tmp_path, 2.5)
        await asyncio.sleep(0.45)
        fast = daemon.counters.connect_attempts
        await asyncio.sleep(1.0)
        slow = daemon.counters.connect_attempts - fast
        await task
        return fast, slow

    fast, slow = asyncio.run(scenario())
    # 0.45 s at one dial per 0.05 s, then 1 s of 0.2, 0.4, 0.4 ... waits
    assert fast >= 5 and slow <= 5, (fast, slow)
    details = [m["detail"] for t, m, _ in messages(tmp_path) if t == DAQ_STATUS]
    assert details[0].startswith("starting")
