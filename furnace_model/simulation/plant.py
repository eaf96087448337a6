"""The plant simulator: the model with effects switched on, seen through real thermocouples.

A furnace's truth is never measured directly. Each zone has two thermocouples; each reads the
sensed zone temperature plus a small fixed bias of its own plus noise, plus whatever sensor
effects the scenario switches on. Runs are reproducible from a seed.
"""

from __future__ import annotations

import bisect
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.linalg.lapack import dtbtrs

from ..experiment import Experiment
from ..heldmeans import held_means, row_edges
from .closedloop import ClosedLoop
from .control import setpoint_signal
from .furnace import Furnace
from .scenario import Scenario, SensorSpec
from .structure import Inputs, ModelStructure


@dataclass
class PlantRun:
    """One simulated run: the truth, what the sensors read, and the inputs, per sample."""

    t_min: np.ndarray  # (N,)
    zone_true: np.ndarray  # (N, zones) gas temperature of each zone
    tc: np.ndarray  # (N, thermocouples) thermocouple readings
    burners: np.ndarray  # (N, zones) each zone's heat input: burners on, or its rate
    t_air: np.ndarray  # (N,)
    start_time: pd.Timestamp | None = None
    furnace: Furnace = field(kw_only=True)
    disturbances: np.ndarray | None = field(default=None, kw_only=True)  # (N, k)
    setpoints: np.ndarray | None = field(default=None, kw_only=True)
    """(N, zones) each zone's setpoint in a closed-loop run, NaN for a zone no loop
    controls; None for an open-loop run."""

    def to_experiment(self, name: str = "simulated") -> Experiment:
        """The record as logged; a closed-loop run's setpoints are among its signals
        (`setpoint_<zone>`), as a PLC's setpoints are extra points of its register map."""
        return Experiment(name, self.t_min, self.tc, self.burners, self.t_air,
                          self.start_time, name, furnace=self.furnace,
                          disturbances=self.disturbances, signals=self.setpoint_signals())

    def setpoint_signals(self) -> dict[str, np.ndarray]:
        if self.setpoints is None:
            return {}
        return {setpoint_signal(z): self.setpoints[:, i]
                for i, z in enumerate(self.furnace.zones)
                if np.isfinite(self.setpoints[:, i]).any()}

    def to_frame(self) -> pd.DataFrame:
        """The run as the tabular contract (CONTRACTS.md section 1)."""
        return self.to_experiment().to_frame()


class Plant:
    """A furnace: a model structure, its true parameter values, and its thermocouples."""

    def __init__(self, structure: ModelStructure, values: Mapping[str, float],
                 sensors: SensorSpec | None = None, seed: int | None = None):
        self.structure = structure
        self.values = dict(values)
        self.sensors = sensors or SensorSpec()
        self.rng = np.random.default_rng(seed)
        self.furnace = structure.furnace
        self.n_sensors = len(self.furnace.sensors)
        if self.sensors.bias_c is not None:
            self.bias = np.asarray(self.sensors.bias_c, dtype=float)
            if self.bias.size != self.n_sensors:
                raise ValueError(f"bias_c has {self.bias.size} values for the "
                                 f"{self.n_sensors} thermocouples of furnace "
                                 f"'{self.furnace.name}'")
        else:
            self.bias = self.rng.normal(0.0, self.sensors.bias_sd_c, self.n_sensors)
        self._noise: np.ndarray | None = None  # the coloured noise's last value per sensor
        self._noise_t = 0.0

    @classmethod
    def from_scenario(cls, scenario: Scenario, seed: int | None = None) -> Plant:
        return cls(scenario.structure(), scenario.values(), scenario.sensors, seed)

    def read(self, sensed: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Thermocouple readings (N, thermocouples) for sensed zone temperatures (N, zones)
        at times t."""
        offsets = self.structure.sensor_offsets(self.values, t)[0]
        return sensed[:, self.furnace.sensor_zone] + self.bias + offsets + self._draw_noise(np.atleast_1d(t))

    def _draw_noise(self, t: np.ndarray) -> np.ndarray:
        """Noise (N, thermocouples) at times t, continuing the autoregression from the last call, so that
        a stepped plant (one scan at a time) reads the same process as a whole run."""
        spec, shape = self.sensors, (t.size, self.n_sensors)
        u = self.rng.normal(0.0, 1.0, shape)
        if spec.noise_ar_per_min <= 0.0:
            noise = spec.noise_sd_c * u
        else:
            sd = spec.noise_sd_c
            if self._noise is None:
                prev, t_prev = sd * self.rng.normal(0.0, 1.0, self.n_sensors), float(t[0])
            else:
                prev, t_prev = self._noise, self._noise_t
            phi = spec.noise_ar_per_min ** np.maximum(np.diff(t, prepend=t_prev), 0.0)
            gain = sd * np.sqrt(1.0 - phi * phi)
            noise = np.empty(shape)
            noise[0] = prev = phi[0] * prev + gain[0] * u[0]
            if t.size > 1 and np.all(phi[1:] == phi[-1]):  # regular sampling: one solve
                noise[1:] = _autoregressed(gain[1:, None] * u[1:], float(phi[-1]), prev)
            else:
                for k in range(1, t.size):
                    noise[k] = prev = phi[k] * prev + gain[k] * u[k]
            self._noise, self._noise_t = noise[-1].copy(), float(t[-1])
        if spec.white_sd_c > 0.0:
            noise = noise + self.rng.normal(0.0, spec.white_sd_c, shape)
        return noise

    def run(self, inputs: Inputs, t: np.ndarray, x0_zone: np.ndarray,
            start_time: pd.Timestamp | None = None) -> PlantRun:
        t = np.asarray(t, dtype=float)
        run = self.structure.simulate(self.values, inputs, t, x0_zone, states=True)
        nz = self.structure.n_zones
        burners, t_air, dist = logged_inputs(inputs, t, self.furnace)
        return PlantRun(t, run.states[0, :, :nz], self.read(run.zones[0], t), burners,
                        t_air, start_time, furnace=self.furnace, disturbances=dist)

    def run_scenario(self, scenario: Scenario) -> PlantRun:
        """The scenario's run: its schedule, or its loops when it has a `control` section."""
        if scenario.control is not None:
            return self.run_closed_loop(scenario)
        return self.run(scenario.plant_inputs(), scenario.sample_times(), scenario.initial_c,
                        scenario.start_time)

    def run_closed_loop(self, scenario: Scenario) -> PlantRun:
        """The scenario under its PLC's loops (`ClosedLoop`), sampled as an open-loop run is:
        the readings are the scans the loops read where a sample falls on a control
        instant, and the inputs logged are those fired."""
        t = scenario.sample_times()
        stepper = self.stepper(scenario.initial_c, scenario.burners_at(0.0), scenario.t_air_c,
                               disturbances=scenario.disturbances_at(0.0))
        loop = ClosedLoop(stepper, scenario)
        nz = self.structure.n_zones
        zone_true, tc = np.empty((t.size, nz)), np.empty((t.size, self.n_sensors))
        setpoints = np.empty((t.size, nz))
        for k, tk in enumerate(t):
            loop.advance(float(tk))
            zone_true[k], tc[k], setpoints[k] = stepper.zone_true(), loop.readings(), \
                loop.setpoints
        burners, t_air, dist = logged_inputs(stepper.history(), t, self.furnace)
        return PlantRun(t, zone_true, tc, burners, t_air, scenario.start_time,
                        furnace=self.furnace, disturbances=dist, setpoints=setpoints)

    def stepper(self, x0_zone: np.ndarray, burners: np.ndarray, t_air: float,
                t0: float = 0.0, disturbances: np.ndarray | None = None) -> PlantStepper:
        return PlantStepper(self, x0_zone, burners, t_air, t0, disturbances)


def _autoregressed(drive: np.ndarray, phi: float, prev: np.ndarray) -> np.ndarray:
    """y[k] = phi y[k-1] + drive[k] down axis 0 from y[-1] = prev: the recursion is a unit
    lower bidiagonal system, which LAPACK's banded solve runs as that loop (scipy.signal's
    filter would cost its import, a second, at every start of a simulated PLC)."""
    b = np.array(drive, dtype=float, order="F")
    b[0] += phi * prev
    band = np.empty((2, b.shape[0]))
    band[0], band[1] = 1.0, -phi
    y, _ = dtbtrs(band, b, uplo="L", trans="N", diag="U")
    return y


def logged_inputs(inputs: Inputs, t: np.ndarray, furnace: Furnace
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Heat inputs, ambient and disturbances as a logger records them at rows t: whole
    burners as they stand at the sample; an analog input (a rate, a pulse-fired zone's
    count, a disturbance) as its mean over the row."""
    j = np.searchsorted(inputs.t, t, side="right") - 1
    burners = inputs.burners[j].astype(float)
    analog = [i for i, h in enumerate(furnace.heat_inputs) if not h.whole]
    if analog:
        burners[:, analog] = row_means(inputs.t, inputs.burners[:, analog], t)
    return burners, inputs.t_air[j], row_means(inputs.t, inputs.disturbances, t)


def row_means(t_in: np.ndarray, levels: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The mean of piecewise-constant `levels` (J, m), level j from t_in[j], over each row
    [t[i], t[i+1]) (the last row as long as the one before): what a logger resampling to
    the rows records of an analog input."""
    levels = np.asarray(levels, dtype=float).reshape(np.size(t_in), -1)
    t = np.asarray(t, dtype=float)
    return held_means(np.asarray(t_in, dtype=float), levels, row_edges(t, 1.0))


def reach_back(structure: ModelStructure, values: Mapping[str, float]) -> float:
    """How far back (minutes) the inputs still act other than through the state and the
    input in force: what a plant stepped in pieces simulates each piece from (the effects'
    `reach_back_min`, added up, since delays in series add)."""
    theta = structure.theta(values)
    return float(sum(e.reach_back_min(theta) for e in structure.effects))


class PlantStepper:
    """The plant advanced in increments, for a simulated PLC whose burners may be switched
    by hand: the schedule is not known ahead, so it is built up as commands arrive.

    Each advance is exact (same simulator as a whole run). The whole input history is kept
    (`history`: what was fired, for the record), but an advance simulates from the inputs
    the effects can still need (`reach_back`: a dead time sees burner changes made that
    long before the current step), so that a run of many control periods costs each period
    alike instead of the history so far.
    """

    def __init__(self, plant: Plant, x0_zone: np.ndarray, burners: np.ndarray, t_air: float,
                 t0: float = 0.0, disturbances: np.ndarray | None = None):
        self.plant = plant
        self.t = float(t0)
        self.x = plant.structure.full_state(np.asarray(x0_zone, dtype=float))[0]
        self._t = [self.t]
        self._burners = [np.asarray(burners, dtype=float)]
        self._air = [float(t_air)]
        k = len(plant.furnace.disturbances)
        self._dist = [np.zeros(k) if disturbances is None
                      else np.asarray(disturbances, dtype=float).reshape(k)]
        C = plant.structure.system(plant.structure.theta(plant.values)).C[0]
        self._C = C
        self._reach = reach_back(plant.structure, plant.values)

    @property
    def burners(self) -> np.ndarray:
        """Heat input per zone: whole burners as integers, a rate as it is."""
        if self.plant.furnace.modulated:
            return self._burners[-1].copy()
        return self._burners[-1].astype(int)

    @property
    def t_air(self) -> float:
        return self._air[-1]

    @property
    def disturbances(self) -> np.ndarray:
        return self._dist[-1].copy()

    def set_inputs(self, burners: np.ndarray | None = None, t_air: float | None = None,
                   disturbances: np.ndarray | None = None) -> None:
        """Change heat inputs per zone, ambient and/or disturbances from now on."""
        b = self._burners[-1] if burners is None else np.asarray(burners, dtype=float)
        a = self._air[-1] if t_air is None else float(t_air)
        d = self._dist[-1] if disturbances is None else np.asarray(disturbances, dtype=float)
        if (np.array_equal(b, self._burners[-1]) and a == self._air[-1]
                and np.array_equal(d, self._dist[-1])):
            return
        if self._t[-1] == self.t:
            self._burners[-1], self._air[-1], self._dist[-1] = b, a, d
        else:
            self._t.append(self.t)
            self._burners.append(b)
            self._air.append(a)
            self._dist.append(d)

    def follow(self, inputs: Inputs) -> None:
        """Inputs known ahead from now (a control period's, pulses included): they replace
        whatever was set from their first time on, which must not lie in the past."""
        start = float(inputs.t[0])
        if start < self.t:
            raise ValueError(f"inputs from {start:g} min lie before the plant's time "
                             f"{self.t:g} min")
        keep = bisect.bisect_left(self._t, start)
        k = len(self.plant.furnace.disturbances)
        del self._t[keep:], self._burners[keep:], self._air[keep:], self._dist[keep:]
        self._t += [float(v) for v in inputs.t]
        self._burners += [np.asarray(b, dtype=float) for b in inputs.burners]
        self._air += [float(a) for a in inputs.t_air]
        self._dist += [np.asarray(d, dtype=float).reshape(k) for d in inputs.disturbances]

    def history(self, since: float = -np.inf) -> Inputs:
        """Every input set so far, as the model takes them; from the one in force at
        `since` (minutes) on."""
        lo = max(bisect.bisect_right(self._t, since) - 1, 0)
        n = len(self._t) - lo
        return Inputs(np.array(self._t[lo:]), np.array(self._burners[lo:]),
                      np.array(self._air[lo:]), np.array(self._dist[lo:]).reshape(n, -1))

    def advance(self, t_new: float) -> None:
        if t_new <= self.t:
            return
        self.x = self.plant.structure.simulate(self.plant.values,
                                               self.history(since=self.t - self._reach),
                                               np.array([t_new]), self.x[None], t0=self.t,
                                               states=True).final_state[0]
        self.t = float(t_new)

    def zone_true(self) -> np.ndarray:
        return self.x[:self.plant.structure.n_zones].copy()

    def readings(self) -> np.ndarray:
        """One scan of the thermocouples (noise drawn anew)."""
        sensed = (self._C @ self.x)[None]
        return self.plant.read(sensed, np.array([self.t]))[0]


class PlantAhead:
    """The plant over inputs known in full ahead (a scenario's schedule, pulse-fired zones
    burner by burner), read at whole seconds in time order: a simulated PLC's scans.

    Pulse firing switches a zone's inputs every few seconds, thousands of times a day; a
    stepper advanced scan by scan would integrate its growing history at each scan. Here
    each `span_min` is simulated once, exactly, at every second of it, so a scan costs a
    lookup. The state at a span's start carries the past but for what the effects reach
    back to (`reach_back`: a transport delay's length); the span is simulated from the
    inputs since then, or from the whole schedule where an effect sets no bound.
    """

    def __init__(self, plant: Plant, inputs: Inputs, x0_zone: np.ndarray,
                 span_min: float = 60.0):
        self.plant, self.inputs = plant, inputs
        self.span_min = float(span_min)
        self._t0 = float(inputs.t[0])
        self._x = plant.structure.full_state(np.asarray(x0_zone, dtype=float))[0]
        self._C = plant.structure.system(plant.structure.theta(plant.values)).C[0]
        self._first_s = int(round(self._t0 * 60.0))
        self._reach = reach_back(plant.structure, plant.values)
        self._states = self._x[None]  # the span's states at each of its seconds

    def _simulate(self, start_s: int) -> None:
        """The span starting at second `start_s`, from the state there."""
        inputs, t0 = self.inputs, start_s / 60.0
        seconds = np.arange(start_s, start_s + int(round(self.span_min * 60.0)) + 1)
        if np.isfinite(self._reach):
            lo = max(int(np.searchsorted(inputs.t, t0 - self._reach, side="right")) - 1, 0)
            hi = int(np.searchsorted(inputs.t, seconds[-1] / 60.0, side="right"))
            inputs = Inputs(inputs.t[lo:hi], inputs.burners[lo:hi], inputs.t_air[lo:hi],
                            inputs.disturbances[lo:hi])
        run = self.plant.structure.simulate(self.plant.values, inputs, seconds / 60.0,
                                            self._x[None], t0=t0, states=True)
        self._first_s, self._states = start_s, run.states[0]

    def state_at(self, second: int) -> np.ndarray:
        """Every state of the plant at whole second `second` (from the first on, never
        before the last one asked for)."""
        last = self._first_s + self._states.shape[0] - 1
        while second > last:
            self._x = self._states[-1]
            self._simulate(last)
            last = self._first_s + self._states.shape[0] - 1
        return self._states[second - self._first_s]

    def readings(self, second: int) -> np.ndarray:
        """One scan of the thermocouples at whole second `second` (noise drawn anew)."""
        sensed = (self._C @ self.state_at(second))[None]
        return self.plant.read(sensed, np.array([second / 60.0]))[0]
