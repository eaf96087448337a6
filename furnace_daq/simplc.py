"""A simulated furnace PLC: the plant simulator behind a real Modbus TCP server (and optionally
a CAN bus), serving the default register map of CONTRACTS.md section 3.

It lets the daemon, mbpoll and the demo run against the same wire protocol as the plant
without hardware. Simulated time runs `speed` times faster than the wall clock; the PLC clock
registers hold whole simulated seconds and every value is computed at exactly that second, so
a client can recompute what it should have read.
"""

from __future__ import annotations

import asyncio
import contextlib
import time

import can
import numpy as np
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import SimData, SimDevice
from pymodbus.simulator.simdata import DataType

from furnace_model import BURNERS_PER_ZONE, SENSORS
from furnace_model.plant import Plant
from furnace_model.scenario import Scenario

from .registers import FUNCTION_CODE, encode

N_BURNERS = sum(BURNERS_PER_ZONE)
N_INPUT_REGISTERS = 10
SENSOR_OPEN_RAW = 32767
CAN_ID = 0x180
"""Flame states on CAN: one 4-byte frame, bit n (byte n // 8, LSB first) = burner n."""
ZONE_SLICES = tuple(slice(sum(BURNERS_PER_ZONE[:i]), sum(BURNERS_PER_ZONE[:i + 1]))
                    for i in range(len(BURNERS_PER_ZONE)))


def tenths(value: float) -> int:
    """INT16 in 0.1 degC; 32767 is reserved for an open thermocouple, so it saturates below."""
    if not np.isfinite(value):
        return SENSOR_OPEN_RAW
    return int(min(max(round(value * 10.0), -32768), SENSOR_OPEN_RAW - 1))


def states_from_counts(counts: np.ndarray) -> list[bool]:
    """Burner on/off states when `counts` burners fire per zone: the first ones of each zone."""
    out: list[bool] = []
    for n, total in zip(counts, BURNERS_PER_ZONE, strict=True):
        out += [k < int(n) for k in range(total)]
    return out


def counts_from_states(states: list[bool]) -> np.ndarray:
    return np.array([sum(states[s]) for s in ZONE_SLICES])


def flame_frame(states: list[bool]) -> bytes:
    value = sum(1 << i for i, on in enumerate(states) if on)
    return value.to_bytes(4, "little")


class SimPLC:
    """A running simulated PLC; `await start()`, then `port`; `await stop()` releases all."""

    def __init__(self, scenario: Scenario, *, speed: float = 3600.0, host: str = "127.0.0.1",
                 port: int = 5020, manual: bool = False, seed: int = 0, scan_s: float = 0.1,
                 can_channel: str | None = None, can_interface: str = "virtual"):
        if speed <= 0 or scan_s <= 0:
            raise ValueError("speed and scan_s must be positive")
        self.scenario, self.speed, self.host, self.manual = scenario, speed, host, manual
        self.scan_s = scan_s
        self.port = port
        self.plant = Plant.from_scenario(scenario, seed=seed)
        self.stepper = self.plant.stepper(scenario.initial_c, scenario.burners_at(0.0),
                                          scenario.t_air_c)
        self.states = states_from_counts(scenario.burners_at(0.0))
        self.open_sensors: set[str] = set()
        """Sensors to report as open circuit (sentinel), for fault drills."""
        self.frozen = False
        """A PLC whose program stopped: registers keep their last values, heartbeat included."""
        self.plc_seconds = 0
        self.heartbeat = 0
        self.scans = 0
        self._can_args = (can_channel, can_interface)
        self._bus: can.BusABC | None = None
        self._server: ModbusTcpServer | None = None
        self._task: asyncio.Task | None = None
        self._t0 = 0.0

    # -- life cycle ---------------------------------------------------------------------------
    async def start(self) -> None:
        bits = [SimData(0, values=list(self.states), datatype=DataType.BITS)]
        device = SimDevice(0, simdata=(
            [SimData(0, values=list(self.states), datatype=DataType.BITS)],  # coils
            bits,                                                             # discrete inputs
            [SimData(0, values=[0], datatype=DataType.REGISTERS)],            # holding
            [SimData(0, values=[0] * N_INPUT_REGISTERS, datatype=DataType.REGISTERS)],
        ))
        self._server = ModbusTcpServer(device, address=(self.host, self.port))
        await self._server.serve_forever(background=True)
        self.port = self._server.transport.sockets[0].getsockname()[1]
        channel, interface = self._can_args
        if channel is not None:
            self._bus = can.Bus(interface=interface, channel=channel)
        self._t0 = time.monotonic()
        await self.scan()
        self._task = asyncio.create_task(self._run(), name="sim-plc scan")

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        if self._server is not None:
            await self._server.shutdown()
            self._server = None
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    async def _run(self) -> None:
        k = 0
        while True:
            k += 1
            delay = self._t0 + k * self.scan_s - time.monotonic()
            if delay < 0:  # fell behind: skip to the next whole scan, never burst
                k += int(-delay // self.scan_s) + 1
                delay = self._t0 + k * self.scan_s - time.monotonic()
            await asyncio.sleep(delay)
            if not self.frozen:
                await self.scan()

    # -- one PLC scan --------------------------------------------------------------------------
    async def scan(self) -> None:
        """Advance the plant to the current simulated second and publish every register."""
        assert self._server is not None
        sim_s = int((time.monotonic() - self._t0) * self.speed)
        target = sim_s / 60.0
        if self.manual:
            coils = await self._server.async_getValues(0, FUNCTION_CODE["coil"], 0, N_BURNERS)
            self.stepper.advance(target)
            self.states = [bool(c) for c in coils]
            self.stepper.set_inputs(burners=counts_from_states(self.states))
        else:
            steps = self.scenario.steps_t
            for at in steps[(steps > self.stepper.t) & (steps <= target)]:
                self.stepper.advance(float(at))
                self.stepper.set_inputs(burners=self.scenario.burners_at(float(at)))
            self.stepper.advance(target)
            self.states = states_from_counts(self.stepper.burners)
        self.plc_seconds = sim_s
        self.heartbeat = (self.heartbeat + 1) & 0xFFFF
        readings = self.stepper.readings()
        regs = [tenths(np.nan if s in self.open_sensors else v) & 0xFFFF
                for s, v in zip(SENSORS, readings, strict=True)]
        regs.append(tenths(self.stepper.t_air) & 0xFFFF)
        regs += encode(sim_s & 0xFFFFFFFF, "uint32", "big")
        regs.append(self.heartbeat)
        await self._server.async_setValues(0, FUNCTION_CODE["input"], 0, regs)
        await self._server.async_setValues(0, FUNCTION_CODE["discrete"], 0, self.states)
        if not self.manual:
            await self._server.async_setValues(0, FUNCTION_CODE["coil"], 0, self.states)
        if self._bus is not None:
            with contextlib.suppress(can.CanError):  # a full bus must not stop the PLC scan
                self._bus.send(can.Message(arbitration_id=CAN_ID, data=flame_frame(self.states),
                                           is_extended_id=False))
        self.scans += 1
