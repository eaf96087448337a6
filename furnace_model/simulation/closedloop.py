"""A scenario run in closed loop: the plant stepped one control period at a time, the PLC's
loops reading its thermocouples at each period's start and setting its inputs for the period.

Shared by the plant simulator (`Plant.run_scenario`) and the simulated PLC, so that both run
the very same loop: a PLC scan at a control instant is the scan the loops read (one scan
per instant, whoever asks), and what either logs of the inputs is what was fired.

Zones no loop drives, and the disturbances (slabs charged, a throughput), follow the
scenario's schedule. A pulse-fired zone is fired as pulses at the loop's mean count, as in
an open-loop run.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .control import PIController, output_limit, staged
from .scenario import Scenario, pulse_fired
from .structure import Inputs

if TYPE_CHECKING:
    from .plant import PlantStepper


class ClosedLoop:
    """The loops of `scenario.control` on a plant stepper; `advance(t)` runs every control
    instant up to `t` (minutes, non-decreasing)."""

    def __init__(self, stepper: PlantStepper, scenario: Scenario):
        if scenario.control is None:
            raise ValueError(f"scenario '{scenario.name}' has no control section")
        self.stepper, self.scenario = stepper, scenario
        self.control = control = scenario.control
        furnace = scenario.furnace
        self.controllers = [PIController(loop.kp, loop.ti_min, 0.0, output_limit(loop, furnace))
                            for loop in control.loops]
        self.setpoints = np.full(furnace.n_zones, np.nan)
        """Each controlled zone's setpoint since the last control instant (NaN: no loop)."""
        self.levels = scenario.burners_at(0.0)
        """Each zone's heat input set at the last control instant."""
        self.piece = Inputs(np.array([0.0]), self.levels[None], np.array([scenario.t_air_c]),
                            scenario.disturbances_at(0.0)[None])
        """The inputs fired from the last control instant to the next (pulses included)."""
        self._k = 0
        self._scan: tuple[float, np.ndarray] | None = None

    @property
    def last_min(self) -> float:
        """The last control instant run (0 before the first)."""
        return max(self._k - 1, 0) * self.control.period_min

    @property
    def next_min(self) -> float:
        """The next control instant."""
        return self._k * self.control.period_min

    def advance(self, t_min: float) -> None:
        while self.next_min <= t_min:
            tk = self.next_min
            self.stepper.advance(tk)
            self._act(tk, self.readings())
            self._k += 1
        self.stepper.advance(t_min)

    def readings(self) -> np.ndarray:
        """The thermocouples at the stepper's time: one scan per instant, so that the loops
        and a logger at the same instant read the same values."""
        if self._scan is None or self._scan[0] != self.stepper.t:
            self._scan = (self.stepper.t, self.stepper.readings())
        return self._scan[1].copy()

    def _act(self, tk: float, tc: np.ndarray) -> None:
        scenario, furnace = self.scenario, self.scenario.furnace
        means = furnace.zone_means(tc[None])[0]
        levels = scenario.burners_at(tk)
        for loop, pi in zip(self.control.loops, self.controllers, strict=True):
            setpoint = loop.programme.at(tk)
            measured = means[loop.zone] if loop.sensor is None else tc[loop.sensor]
            u = pi.update(setpoint - measured, self.control.period_min)
            for i, level in staged(u, loop, furnace).items():
                levels[i] = level
            self.setpoints[loop.zone] = setpoint
        self.levels = levels
        self.piece = self._schedule(tk, levels)
        self.stepper.follow(self.piece)

    def _schedule(self, tk: float, levels: np.ndarray) -> Inputs:
        """The inputs from `tk` to the next instant: the loops' levels in the zones they
        drive, the schedule's (steps within the period included) elsewhere."""
        scenario = self.scenario
        end = tk + self.control.period_min
        steps = scenario.steps_t
        t = np.concatenate(([tk], steps[(steps > tk) & (steps < end)]))
        burners = np.array([scenario.burners_at(s) for s in t])
        driven = list(self.control.driven)
        burners[:, driven] = levels[driven]
        dist = np.array([scenario.disturbances_at(s) for s in t]).reshape(t.size, -1)
        return pulse_fired(Inputs(t, burners, np.full(t.size, scenario.t_air_c), dist),
                           scenario.furnace, scenario.pulse_cycle_min, end)
