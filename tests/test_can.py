"""Burner flame states over CAN (python-can's virtual bus, in-process) reach the log, and a
disagreement between the PLC and the flame scanners becomes a /daq/events message."""

from __future__ import annotations

import asyncio
import uuid
from itertools import groupby

import can
from daq_processes import SCENARIO, config, messages, sim, start_daemon

from furnace_daq.simplc import SimPLC, flame_frame
from furnace_model.log.schema import BURNERS, DAQ_EVENTS
from furnace_model.simulation.scenario import load_scenario


def burner_messages(log_dir, source):
    return [(m, lt) for t, m, lt in messages(log_dir) if t == BURNERS and m["source"] == source]


def test_flame_states_from_the_sim_plc_agree_with_modbus(tmp_path):
    channel = f"furnace-{uuid.uuid4().hex}"

    async def scenario():
        plc = SimPLC(load_scenario(SCENARIO), speed=600, port=0, scan_s=0.05,
                     can_channel=channel)
        await plc.start()
        cfg = config(plc.port, burners={
            "source": "both", "modbus": {z: {"address": a} for z, a in
                                         (("soak", 0), ("heat", 10), ("preheat", 18))},
            "can": {"interface": "virtual", "channel": channel}})
        _, task = start_daemon(cfg, tmp_path, 2.6)
        counters = await task
        await plc.stop()
        return counters

    counters = asyncio.run(scenario())
    modbus, flame = burner_messages(tmp_path, "modbus"), burner_messages(tmp_path, "can")
    assert counters.can_frames > 10 and len(flame) >= 0.9 * len(modbus) > 10
    # A flame frame trails the registers by up to a PLC scan and a bus delivery, so a step
    # in the run's last polls may reach one source only; a step held for six polls reaches both.
    held = [n for n, polls in groupby(m["count_soak"] for m, _ in modbus)
            if len(list(polls)) >= 6]
    assert {m["count_soak"] for m, _ in flame} <= {m["count_soak"] for m, _ in modbus}
    assert set(held) <= {m["count_soak"] for m, _ in flame} and 2 in held
    assert all(m["quality"] == "ok" for m, _ in flame)
    assert not [m for t, m, _ in messages(tmp_path) if t == DAQ_EVENTS
                and m["kind"] == "burner_disagreement"], "a PLC scan apart at most"


def test_frames_sent_on_the_bus_reach_the_log_and_disagreements_are_events(tmp_path):
    channel = f"furnace-{uuid.uuid4().hex}"

    async def scenario():
        plc = await sim(0)
        cfg = config(plc.port, burners={
            "source": "both", "disagreement_polls": 3,
            "modbus": {"soak": {"address": 0}, "heat": {"address": 10},
                       "preheat": {"address": 18}},
            "can": {"interface": "virtual", "channel": channel}})
        bus = can.Bus(interface="virtual", channel=channel)
        _, task = start_daemon(cfg, tmp_path, 2.4)
        t0 = asyncio.get_running_loop().time()
        sent = []
        while not task.done():
            states = list(plc.states)
            elapsed = asyncio.get_running_loop().time() - t0
            if 0.8 <= elapsed < 1.5:
                states[3] = not states[3]  # soak burner 3: flame disagrees with the PLC
            bus.send(can.Message(arbitration_id=0x180, data=flame_frame(states),
                                 is_extended_id=False))
            sent.append(states)
            await asyncio.sleep(0.02)
        bus.shutdown()
        await plc.stop()
        return sent

    sent = asyncio.run(scenario())
    flame = burner_messages(tmp_path, "can")
    assert len(flame) > 20
    flipped = [m for m, _ in flame if m["soak"][3] != m["soak"][2]]
    assert flipped, "the test's frames reached the log"
    assert any(s[3] != s[2] for s in sent)
    # a busy host may also skip a poll tick (a missed_tick event): not what this test is about
    events = [m for t, m, _ in messages(tmp_path)
              if t == DAQ_EVENTS and m["kind"].startswith("burner_")]
    kinds = [e["kind"] for e in events]
    assert kinds == ["burner_disagreement", "burner_agreement"], events
    assert events[0]["burners"] == ["soak[3]"]
