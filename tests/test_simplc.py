"""The simulated PLC: its registers hold the plant at exactly the PLC clock second, simulated
time runs at the requested speed, manual mode follows coil writes, flame states go on CAN."""

from __future__ import annotations

import asyncio
import time
import uuid

import can
import numpy as np
from daq_processes import SCENARIO
from pymodbus.client import AsyncModbusTcpClient

from furnace_daq.registers import decode
from furnace_daq.servedmap import ServedMap
from furnace_daq.simplc import CAN_ID, SimPLC, states_from_counts
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario


async def read_all(client) -> tuple[list[int], list[bool]]:
    ir = await client.read_input_registers(0, count=10, device_id=1)
    di = await client.read_discrete_inputs(0, count=26, device_id=1)
    assert not ir.isError() and not di.isError()
    return ir.registers, di.bits[:26]


def test_registers_are_the_plant_at_the_plc_clock_and_time_runs_at_speed():
    scenario = load_scenario(SCENARIO)
    speed = 1200.0

    async def scenario_run():
        plc = SimPLC(scenario, speed=speed, port=0, scan_s=0.05)
        await plc.start()
        client = AsyncModbusTcpClient("127.0.0.1", port=plc.port)
        await client.connect()
        reads, times = [], []
        for _ in range(6):
            await asyncio.sleep(0.3)
            reads.append(await read_all(client))
            times.append(time.monotonic())
        client.close()
        await plc.stop()
        return reads, times[-1] - times[0]  # the wall time between the first and last read

    reads, wall = asyncio.run(scenario_run())
    seconds = np.array([decode(r[7:9], "uint32", "big") for r, _ in reads])
    assert np.all(np.diff(seconds) > 0)
    rate = (seconds[-1] - seconds[0]) / wall
    assert 0.8 * speed < rate < 1.1 * speed, rate
    heartbeats = [r[9] for r, _ in reads]
    assert np.all(np.diff(heartbeats) >= 4), "0.3 s apart at a 0.05 s scan"
    run = Plant.from_scenario(scenario).run(scenario.inputs(), seconds / 60.0, scenario.initial_c)
    for (regs, bits), tc, s in zip(reads, run.tc, seconds, strict=True):
        assert [decode([w], "int16") for w in regs[:6]] == [tenths(v) for v in tc]
        assert bits == states_from_counts(scenario.burners_at(s / 60.0), PAPER)


def test_manual_mode_follows_coils_and_broadcasts_flames_on_can():
    channel = f"sim-{uuid.uuid4().hex}"
    scenario = load_scenario(SCENARIO)

    async def scenario_run():
        listener = can.Bus(interface="virtual", channel=channel)
        plc = SimPLC(scenario, speed=60, port=0, scan_s=0.05, manual=True, can_channel=channel)
        await plc.start()
        client = AsyncModbusTcpClient("127.0.0.1", port=plc.port)
        await client.connect()
        wanted = [False] * 26
        for i in (0, 4, 9, 12, 25):
            wanted[i] = True
        await client.write_coils(0, wanted, device_id=1)
        await asyncio.sleep(0.3)
        _, bits = await read_all(client)
        counts = plc.source.stepper.burners.tolist()
        frames = []
        while (msg := listener.recv(timeout=0)) is not None:
            frames.append(msg)
        client.close()
        await plc.stop()
        listener.shutdown()
        return wanted, bits, counts, frames

    wanted, bits, counts, frames = asyncio.run(scenario_run())
    assert bits == wanted
    assert counts == [3, 1, 1]
    assert frames and all(f.arbitration_id == CAN_ID for f in frames)
    last = int.from_bytes(bytes(frames[-1].data), "little")
    assert [bool(last >> i & 1) for i in range(26)] == wanted


def tenths(value: float) -> int:
    """CONTRACTS.md section 3's encoding, written out apart from the served map: INT16 in
    0.1 degC, 32767 only for an open circuit (a real reading saturates below it)."""
    if not np.isfinite(value):
        return 32767
    return int(min(max(round(value * 10.0), -32768), 32766))


def test_the_default_map_saturates_below_the_open_sentinel():
    tc = [12.34, -3.26, 1e9, float("nan"), -1e9, 0.05]
    image = ServedMap.default(PAPER).image(tc, 20.0, 7, 1, [False] * 26)
    assert [decode([image["input"][i]], "int16") for i in range(6)] == [tenths(v) for v in tc]
    assert [tenths(v) for v in tc] == [123, -33, 32766, 32767, -32768, 0]
