"""A zone's setpoint programme: what temperature the PLC asks of a zone, minute by minute.

A furnace in production runs a programme per zone: a start-up ramp from cold at a rate the
refractory tolerates, holds, and steps as the product mix changes. Every part of it is one
kind of step: from `at_min` on, the setpoint moves to `target_c`, at `ramp_c_per_min` when
given (a ramp) or at once (a step), and holds there until the next step. A hold is the
absence of a step; a ramp not finished when the next step comes is left where it stands.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import Node

MAX_C = 2000.0
"""The highest setpoint a programme may ask for, °C."""


@dataclass(frozen=True)
class ProgrammeStep:
    at_min: float
    target_c: float
    ramp_c_per_min: float | None = None
    """None: the setpoint jumps to the target."""


@dataclass(frozen=True)
class Programme:
    """A setpoint from `start_c` at minute 0, moved by `steps` in time order."""

    start_c: float
    steps: tuple[ProgrammeStep, ...]

    def at(self, t_min: float) -> float:
        """The setpoint at `t_min`."""
        value = self.start_c
        for k, step in enumerate(self.steps):
            if step.at_min > t_min:
                break
            # the time this step has to act: until t, or until the next step takes over
            until = t_min if k + 1 == len(self.steps) else min(t_min, self.steps[k + 1].at_min)
            value = _moved(value, step, until - step.at_min)
        return value

    def values(self, t_min: np.ndarray) -> np.ndarray:
        return np.array([self.at(float(t)) for t in np.atleast_1d(t_min)])


def _moved(value: float, step: ProgrammeStep, elapsed: float) -> float:
    if step.ramp_c_per_min is None:
        return step.target_c
    reach = step.ramp_c_per_min * max(elapsed, 0.0)
    if step.target_c >= value:
        return min(value + reach, step.target_c)
    return max(value - reach, step.target_c)


def programme_from_node(node: Node, start_c: float, duration_min: float) -> Programme:
    """`setpoint`: optional `start_c` (default `start_c`: the zone's initial temperature)
    and `steps`, each {at_min, target_c, ramp_c_per_min (optional, > 0)}, in time order."""
    node.mapping({"start_c", "steps"})
    start = node.get_number("start_c", start_c, lo=-60.0, hi=MAX_C)
    steps: list[ProgrammeStep] = []
    for step in node.child("steps").elements(min_len=1):
        step.mapping({"at_min", "target_c", "ramp_c_per_min"})
        at = step.get_number("at_min", lo=0.0, hi=duration_min)
        if steps and at <= steps[-1].at_min:
            raise step.child("at_min").error(
                f"steps must be in time order; {at:g} follows {steps[-1].at_min:g}")
        ramp = (step.get_number("ramp_c_per_min", lo=1e-6, hi=1000.0)
                if step.has("ramp_c_per_min") else None)
        steps.append(ProgrammeStep(at, step.get_number("target_c", lo=-60.0, hi=MAX_C), ramp))
    return Programme(start, tuple(steps))
