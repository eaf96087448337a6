"""A simulated furnace PLC: a real Modbus TCP server (and optionally a CAN bus) serving the
default register map of CONTRACTS.md section 3 (or the one derived from another furnace's
description by the same rule, `ServedMap.default`) from a value source.

It lets the daemon, mbpoll and the demo run against the same wire protocol as the plant
without hardware. Two sources feed the same server: the plant simulator running a scenario
(`PlantSource`), and a recorded log (`furnace_daq.logplayer.LogPlayer`). Simulated time runs
`speed` times faster than the wall clock; the PLC clock registers hold whole simulated seconds
and every value is the source's at exactly that second, so a client can recompute what it
should have read.

A furnace fired otherwise than by whole burners is served as its PLC would show it: a
rate-fired zone's rate and each disturbance as the scenario sets them, a pulse-fired zone's
burners each on for its duty of every pulse cycle (`pulse_states`), the plant fired by those
very pulses. The map's extra signals that the source has no value for are simulated
(`simulated_signal`), so that a config with signals can be tried end to end.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from dataclasses import dataclass, field
from typing import Protocol

import can
import numpy as np
from pymodbus import FramerType
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import SimData, SimDevice
from pymodbus.simulator.simdata import DataType

from furnace_model.simulation.closedloop import ClosedLoop
from furnace_model.simulation.control import setpoint_signal
from furnace_model.simulation.furnace import Furnace
from furnace_model.simulation.plant import Plant, PlantAhead
from furnace_model.simulation.scenario import Scenario

from .daqconfig import Signal
from .registers import FUNCTION_CODE
from .servedmap import ServedMap

CAN_ID = 0x180
"""Flame states on CAN: one frame (4 bytes, more for a furnace of more than 32 burners), bit
n (byte n // 8, LSB first) = burner n."""


def zone_slices(furnace: Furnace) -> tuple[slice, ...]:
    """Each zone's burners in the PLC's list of states, for the zones fired by burners
    (`furnace.switched`): zone after zone."""
    sizes = [furnace.burners[i] for i in furnace.switched]
    return tuple(slice(sum(sizes[:k]), sum(sizes[:k + 1])) for k in range(len(sizes)))


def n_states(furnace: Furnace) -> int:
    """Burners whose states the PLC shows: those of the zones fired by burners."""
    return sum(furnace.burners[i] for i in furnace.switched)


def pulse_states(mean: float, burners: int, since_min: float, cycle_min: float) -> list[bool]:
    """Each burner of a pulse-fired zone firing `mean` burners on average, `since_min` after
    that level was set: burner k fires for its duty mean / burners of every cycle, the
    burners' windows laid end to end around the cycle, so that floor(mean) + 1 fire for the
    fraction mean - floor(mean) of each cycle (from its start) and floor(mean) for the rest:
    the count `furnace_model.simulation.scenario.pulse_fired` fires the plant with."""
    duty = min(max(float(mean) / burners, 0.0), 1.0) if burners else 0.0
    cycles = float(since_min) / cycle_min
    # an instant at a cycle's start may come out a hair short of it: count it in
    phase = max(cycles - math.floor(cycles + 1e-9), 0.0)
    on = [False] * burners
    if duty <= 0.0:
        return on
    # Lap j of the windows laid end to end passes the phase in burner floor((phase + j) /
    # duty)'s window: one burner per lap, so a window's edge is never counted twice.
    for lap in range(burners):
        k = math.floor((phase + lap) / duty)
        if k >= burners:
            break
        on[k] = True
    return on


def simulated_signal(signal: Signal, firing: float, plc_seconds: int,
                     rng: np.random.Generator) -> float | bool:
    """A plausible value of an extra signal the source knows nothing of. A bit is on for
    the first two minutes of every hour (a door opened to charge); a number lies in its
    `range` (0 to 100 without one), at three quarters of it with nothing firing and one
    quarter at full fire (as a flue's O2 falls when the burners fire harder), with noise of
    half a percent of the range. `firing`: the furnace's heat input as a fraction of its
    maximum."""
    if signal.bit:
        return plc_seconds % 3600 < 120
    lo = 0.0 if signal.item.lo is None else signal.item.lo
    hi = 100.0 if signal.item.hi is None else signal.item.hi
    value = lo + (hi - lo) * (0.75 - 0.5 * firing) + rng.normal(0.0, 0.005 * (hi - lo))
    return float(min(max(value, lo), hi))


def _padded(states: list[bool], n: int) -> list[bool]:
    return states[:n] + [False] * (n - len(states))


def _runs(cells: dict[int, int | bool]) -> list[tuple[int, list]]:
    """Consecutive addresses as (start, values): one write per run."""
    runs: list[tuple[int, list]] = []
    for a in sorted(cells):
        if runs and runs[-1][0] + len(runs[-1][1]) == a:
            runs[-1][1].append(cells[a])
        else:
            runs.append((a, [cells[a]]))
    return runs


def states_from_counts(counts: np.ndarray, furnace: Furnace) -> list[bool]:
    """Burner on/off states when `counts` burners fire per zone fired by burners
    (`furnace.switched`): the first ones of each zone."""
    out: list[bool] = []
    for n, i in zip(counts, furnace.switched, strict=True):
        out += [k < int(n) for k in range(furnace.burners[i])]
    return out


def counts_from_states(states: list[bool], furnace: Furnace) -> np.ndarray:
    """Burners on per zone fired by burners."""
    return np.array([sum(states[s]) for s in zone_slices(furnace)])


def firing_fraction(values: PlcValues, furnace: Furnace) -> float:
    """The furnace's heat input as a fraction of its maximum: each zone's share of its own
    maximum, averaged over the zones."""
    shares = [sum(values.burners[s]) / furnace.burners[i]
              for s, i in zip(zone_slices(furnace), furnace.switched, strict=True)]
    shares += [values.heat.get(furnace.zones[i], 0.0) / furnace.heat_inputs[i].max
               for i in furnace.rated]
    return float(np.clip(np.mean(shares), 0.0, 1.0)) if shares else 0.0


def flame_frame(states: list[bool]) -> bytes:
    value = sum(1 << i for i, on in enumerate(states) if on)
    return value.to_bytes(max(4, (len(states) + 7) // 8), "little")


@dataclass
class PlcValues:
    """What the PLC shows at one second, in engineering units."""

    thermocouples: list[float]
    """One reading per thermocouple in the furnace's order (the paper's six), degC; NaN =
    open circuit (served as 32767)."""
    t_air: float
    burners: list[bool]
    """Flame-on state of every burner of the zones fired by burners, zone after zone (the
    paper's: soak 0-9, heat 10-17, preheat 18-25)."""
    heat: dict[str, float] = field(default_factory=dict)
    """The heat input of each rate-fired zone, by zone, in its unit."""
    disturbances: dict[str, float] = field(default_factory=dict)
    """Each disturbance the furnace declares, by name, in its unit."""
    signals: dict[str, float | bool] = field(default_factory=dict)
    """Extra signals the source has values for, by name (the others are simulated)."""


class ValueSource(Protocol):
    """Where the simulated PLC's values come from; the server adds clock and heartbeat."""

    end_s: int | None
    """The last PLC second with values of its own (None: never ends)."""
    furnace: Furnace
    """The furnace the values are of: its thermocouples and burners in order."""

    def values_at(self, plc_seconds: int) -> PlcValues:
        """The values at `plc_seconds`; called with non-decreasing seconds."""
        ...


class PlantSource:
    """The plant simulator running a scenario: burners follow its schedule or, in manual
    mode, the commands the server passes on from the coils (rate-fired zones and
    disturbances keep the schedule's, taken at each scan). A scenario with a `control`
    section runs in closed loop: the PLC runs its loops at its own clock, each control
    period on the scan of that instant, and serves what they fire and their setpoints
    (`setpoint_<zone>`, for a map that declares them as signals)."""

    end_s: int | None = None

    def __init__(self, scenario: Scenario, *, seed: int = 0, manual: bool = False):
        if manual and scenario.control is not None:
            raise ValueError(f"scenario '{scenario.name}' runs in closed loop: its loops "
                             "set the burners, not commands by hand")
        self.scenario, self.manual = scenario, manual
        self.furnace = furnace = scenario.furnace
        self.plant = Plant.from_scenario(scenario, seed=seed)
        self._commands: list[bool] | None = None
        self._switched = list(furnace.switched)
        self._rated = list(furnace.rated)
        self.loop: ClosedLoop | None = None
        if scenario.control is not None:
            self.stepper = self.plant.stepper(scenario.initial_c, scenario.burners_at(0.0),
                                              scenario.t_air_c,
                                              disturbances=scenario.disturbances_at(0.0))
            self.loop = ClosedLoop(self.stepper, scenario)
        elif manual:  # the schedule is not known ahead: the plant is stepped as commands come
            self.stepper = self.plant.stepper(scenario.initial_c, scenario.burners_at(0.0),
                                              scenario.t_air_c,
                                              disturbances=scenario.disturbances_at(0.0))
        else:
            self.ahead = PlantAhead(self.plant, scenario.plant_inputs(), scenario.initial_c)

    def command(self, states: list[bool]) -> None:
        """Burner commands written by a client, applied from the next second served."""
        self._commands = [bool(s) for s in states]

    def values_at(self, plc_seconds: int) -> PlcValues:
        t = plc_seconds / 60.0
        scenario, furnace = self.scenario, self.furnace
        levels = scenario.burners_at(t)
        disturbances = scenario.disturbances_at(t)
        signals: dict[str, float | bool] = {}
        if self.loop is not None:
            loop = self.loop
            loop.advance(t)
            readings = loop.readings()
            driven = list(loop.control.driven)
            levels[driven] = loop.levels[driven]
            since = max(loop.last_min, float(scenario.steps_t[scenario.step_index(t)]))
            states = self._states(levels, t, since)
            signals = {setpoint_signal(z): float(v)
                       for z, v in zip(furnace.zones, loop.setpoints, strict=True)
                       if np.isfinite(v)}
        elif self.manual:
            self.stepper.advance(t)
            inputs = self.stepper.burners.astype(float)
            if self._commands is not None:
                inputs[self._switched] = counts_from_states(self._commands, furnace)
            inputs[self._rated] = levels[self._rated]
            self.stepper.set_inputs(burners=inputs, disturbances=disturbances)
            readings = self.stepper.readings()
            states = (list(self._commands) if self._commands is not None
                      else states_from_counts(inputs[self._switched], furnace))
            levels = inputs
        else:
            readings = self.ahead.readings(plc_seconds)
            states = self._states(levels, t, float(scenario.steps_t[scenario.step_index(t)]))
        return PlcValues(list(readings), scenario.t_air_c, states,
                         {furnace.zones[i]: float(levels[i]) for i in self._rated},
                         {d.name: float(v) for d, v in zip(furnace.disturbances, disturbances,
                                                           strict=True)}, signals)

    def _states(self, levels: np.ndarray, t: float, set_at: float) -> list[bool]:
        """Every burner of the zones fired by burners at `levels`, set at minute `set_at`:
        whole burners the first ones of their zone, a pulse-fired zone's pulsing as it fires
        in the middle of the second shown (pulses of a few seconds, judged at the second's
        start, would show the zone's extra burner for the whole second its pulse begins in:
        a duty too high by half a second per cycle on average)."""
        scenario, furnace = self.scenario, self.furnace
        since = t + 0.5 / 60.0 - set_at
        out: list[bool] = []
        for i in self._switched:
            n = furnace.burners[i]
            if furnace.heat_inputs[i].kind == "pulse":
                out += pulse_states(float(levels[i]), n, since, scenario.pulse_cycle_min)
            else:
                out += [k < int(levels[i]) for k in range(n)]
        return out


class SimPLC:
    """A running simulated PLC; `await start()`, then `port`; `await stop()` releases all.

    `source` is a ValueSource, or a Scenario for the plant simulator (then `seed` and `manual`
    apply). When a source ends (a log played to its end) the PLC stops: registers keep their
    last values, clock and heartbeat included, and `ended` is set."""

    def __init__(self, source: ValueSource | Scenario, *, speed: float = 3600.0,
                 host: str = "127.0.0.1", port: int = 5020, manual: bool = False, seed: int = 0,
                 scan_s: float = 0.1, can_channel: str | None = None,
                 can_interface: str = "virtual", holding_registers: int = 1,
                 transport: str = "tcp", serial_port: str | None = None,
                 baudrate: int = 19200, served: ServedMap | None = None):
        if speed <= 0 or scan_s <= 0:
            raise ValueError("speed and scan_s must be positive")
        if isinstance(source, Scenario):
            source = PlantSource(source, seed=seed, manual=manual)
        self.source = source
        self.manual = bool(getattr(source, "manual", False))
        self.speed, self.host, self.port, self.scan_s = speed, host, port, scan_s
        self.holding_registers = holding_registers
        furnace = source.furnace
        self.served = served or ServedMap.default(furnace)
        """The register map the values are served through."""
        if self.served.furnace != furnace:
            raise ValueError(f"the values are of furnace '{furnace.name}', the register map "
                             f"is of furnace '{self.served.furnace.name}'")
        if transport not in ("tcp", "rtu-over-tcp", "rtu") or \
                (transport == "rtu") != (serial_port is not None):
            raise ValueError("transport is tcp, rtu-over-tcp, or rtu with a serial_port")
        self.transport, self.serial_port, self.baudrate = transport, serial_port, baudrate
        """How the PLC is reached: Modbus TCP, RTU frames over TCP (a serial-to-Ethernet
        converter), or RTU on a serial line (`serial_port`, e.g. one end of a socat pty
        pair)."""
        """Holding registers 0.. the PLC offers for writing (model write-back drills)."""
        self.values = source.values_at(0)
        self.open_sensors: set[str] = set()
        """Sensors to report as open circuit (sentinel), for fault drills."""
        self.frozen = False
        """A PLC whose program stopped: registers keep their last values, heartbeat included."""
        self.ended = asyncio.Event()
        """Set once the source has no more values (end of a log)."""
        self.plc_seconds = 0
        self.heartbeat = 0
        self.scans = 0
        self._rng = np.random.default_rng(seed)
        self._can_args = (can_channel, can_interface)
        self._bus: can.BusABC | None = None
        self._server: ModbusTcpServer | ModbusSerialServer | None = None
        self._task: asyncio.Task | None = None
        self._t0 = 0.0

    @property
    def states(self) -> list[bool]:
        return self.values.burners

    # -- life cycle ---------------------------------------------------------------------------
    async def start(self) -> None:
        size = self.served.sizes()
        size["holding"] = max(size["holding"], self.holding_registers)
        states = list(self.values.burners)
        device = SimDevice(0, simdata=(
            [SimData(0, values=_padded(states, size["coil"]), datatype=DataType.BITS)],
            [SimData(0, values=_padded(states, size["discrete"]), datatype=DataType.BITS)],
            [SimData(0, values=[0] * size["holding"], datatype=DataType.REGISTERS)],
            [SimData(0, values=[0] * size["input"], datatype=DataType.REGISTERS)],
        ))
        if self.transport == "rtu":
            self._server = ModbusSerialServer(device, port=self.serial_port,
                                              baudrate=self.baudrate)
            await self._server.serve_forever(background=True)
        else:
            framer = FramerType.RTU if self.transport == "rtu-over-tcp" else FramerType.SOCKET
            self._server = ModbusTcpServer(device, framer=framer, address=(self.host, self.port))
            await self._server.serve_forever(background=True)
            self.port = self._server.transport.sockets[0].getsockname()[1]
        channel, interface = self._can_args
        if channel is not None:
            self._bus = can.Bus(interface=interface, channel=channel)
        await self._start_scanning()

    async def _start_scanning(self) -> None:
        """The first scan now, then one every scan_s on the PLC's own clock: what every
        served protocol starts once its server listens."""
        self._t0 = time.monotonic()
        await self.scan()
        self._task = asyncio.create_task(self._run(), name="sim-plc scan")

    async def _stop_scanning(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None

    async def stop(self) -> None:
        await self._stop_scanning()
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
            if not self.frozen and not self.ended.is_set():
                await self.scan()

    # -- one PLC scan --------------------------------------------------------------------------
    def advance(self) -> PlcValues:
        """The values of this scan, whatever protocol serves them: the source's at the
        current simulated second (past its end, its last second, and `ended` set), the PLC
        clock and heartbeat moved on, and the map's signals the source has no value for
        simulated."""
        sim_s = int((time.monotonic() - self._t0) * self.speed)
        end = self.source.end_s
        if end is not None and sim_s >= end:
            sim_s = end
            self.ended.set()
        self.values = values = self.source.values_at(sim_s)
        self.plc_seconds = sim_s
        self.heartbeat = (self.heartbeat + 1) & 0xFFFF
        missing = [s for s in self.served.signals if s.name not in values.signals]
        if missing:
            firing = firing_fraction(values, self.served.furnace)
            values.signals.update({s.name: simulated_signal(s, firing, sim_s, self._rng)
                                   for s in missing})
        return values

    async def scan(self) -> None:
        """Take the source's values at the current simulated second and publish every
        register; past the source's end, publish its last second once and stop."""
        assert self._server is not None
        furnace = self.served.furnace
        if self.manual:
            coils = await self._server.async_getValues(0, FUNCTION_CODE["coil"], 0,
                                                       n_states(furnace))
            self.source.command([bool(c) for c in coils])
        values = self.advance()
        sim_s = self.plc_seconds
        states = list(values.burners)
        image = self.served.image(values.thermocouples, values.t_air, sim_s,
                                  self.heartbeat, states, self.open_sensors, heat=values.heat,
                                  disturbances=values.disturbances, signals=values.signals)
        if self.manual:
            image["coil"] = {}  # the operator's commands stay on the coils
        elif not image["coil"]:
            image["coil"] = dict(enumerate(states))  # coils follow the flames
        for table, cells in image.items():
            for start, values in _runs(cells):
                await self._server.async_setValues(0, FUNCTION_CODE[table], start, values)
        if self._bus is not None:
            with contextlib.suppress(can.CanError):  # a full bus must not stop the PLC scan
                self._bus.send(can.Message(arbitration_id=CAN_ID, data=flame_frame(states),
                                           is_extended_id=False))
        self.scans += 1
