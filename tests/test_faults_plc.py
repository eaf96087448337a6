"""The daemon against a PLC that is down at start, drops, restarts, freezes, loses a
thermocouple or refuses one block of registers: the loop keeps its period, every change of
state is on /daq/status, and qualities say which values are good."""

from __future__ import annotations

import asyncio

import numpy as np
from daq_processes import config, free_port, messages, plant_readings, sim, start_daemon

from furnace_model import SENSORS
from furnace_model.logread import read_messages
from furnace_model.logschema import AMBIENT, BURNERS, DAQ_EVENTS, DAQ_STATUS, THERMOCOUPLES


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


def test_plc_restarted_mid_run(tmp_path):
    """A new PLC process on the same port: its clock starts again from 0. The daemon
    reconnects, says so with a plc_clock_reset event, re-anchors publish time, and logs the
    new PLC's values as they are."""
    async def scenario():
        port = free_port()
        plc = await sim(port)
        daemon, task = start_daemon(config(port), tmp_path, 2.6)
        await asyncio.sleep(1.2)
        await plc.stop()
        plc = await sim(port)             # restarted at once: PLC clock back to 0
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
    logged = np.array([[m[s] for s in SENSORS] for m, _, _ in tc], dtype=float)
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
                  "sentinels": [32767]} for i, s in enumerate(SENSORS)}
    tc_map["heat_1"]["address"], tc_map["heat_2"]["address"] = 100, 101

    async def scenario():
        plc = await sim(0)
        daemon, task = start_daemon(config(plc.port, thermocouples=tc_map), tmp_path, 1.5)
        counters = await task
        await plc.stop()
        return counters

    counters = asyncio.run(scenario())
    assert counters.disconnects == 0 and counters.comm_errors == 0
    msgs = messages(tmp_path)
    tc = [m for t, m, _ in msgs if t == THERMOCOUPLES]
    assert len(tc) >= 20
    for m in tc:
        assert m["error"] == "input 100+2: Modbus exception code 2"  # why, in the message
        assert m["heat_1"] is None and m["heat_2"] is None
        assert m["quality"]["heat_1"] == m["quality"]["heat_2"] == "comm_error"
        assert {m["quality"][s] for s in ("soak_1", "soak_2", "preheat_1", "preheat_2")} == {"ok"}
    seconds = [m["plc_seconds"] for m in tc]
    want = plant_readings(seconds)
    for s in ("soak_1", "soak_2", "preheat_1", "preheat_2"):
        k = SENSORS.index(s)
        np.testing.assert_allclose([m[s] for m in tc], want[:, k], atol=0.1 + 1e-9)
    assert len([m for t, m, _ in msgs if t == AMBIENT and m["quality"] == "ok"]) == len(tc)
    assert len([m for t, m, _ in msgs if t == BURNERS]) == len(tc)
    states = {m["state"] for t, m, _ in msgs if t == DAQ_STATUS}
    assert states == {"connected", "disconnected"}  # disconnected only at start and stop


def test_frozen_plc_is_stale_and_open_sensor_is_null(tmp_path):
    async def scenario():
        plc = await sim(0)
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
