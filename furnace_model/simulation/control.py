"""The PLC's zone controllers: a PI loop per controlled zone, run every control period.

A loop reads what the PLC reads, the zone's thermocouples with their noise, bias and any
sensor effect (the mean of the zone's, or one named thermocouple), never the zone's true
temperature: a thermocouple drifting low makes its loop fire harder, and the real zone runs
hot by the drift. Its output is the heat input of the zone(s) it drives, within what their
burners can give: whole burners for zones fired by burners switched on and off (the PI
output rounded and staged, zone by zone in the order given when one loop drives several),
a mean count for a pulse-fired zone, a firing rate or fuel flow for a rate-fired zone.

Anti-windup is by clamping (conditional integration): the integral is not advanced when the
output is at a limit and the error would push it further. Chosen over back-calculation
because it needs no tracking time to tune and because the staged output is whole burners:
back-calculation against what is actually fired would feed the rounding back into the
integral and keep it dithering between two counts; clamping judges saturation on the PI's
own output against the burners' limits only.

On a furnace described with every burner heating the first zone (the paper's convention)
the zones' burners all act on the first zone: one loop per zone would fight. There one loop
on the first zone drives every zone's burners (`drives`), as the paper's crews open burners
soaking zone first.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import Node
from .furnace import Furnace
from .programme import Programme, programme_from_node


def setpoint_signal(zone: str) -> str:
    """A controlled zone's setpoint as a logged signal (a column, a point of the map)."""
    return f"setpoint_{zone}"


MEAN = "mean"
"""A loop's `sensor` that reads the mean of its zone's thermocouples."""


@dataclass(frozen=True)
class Loop:
    """One zone's PI loop: what it reads, what it drives, its tuning and its programme."""

    zone: int
    sensor: int | None
    """Index of the thermocouple read (`furnace.sensors`); None: the zone's mean."""
    drives: tuple[int, ...]
    """Zones whose heat input the output sets; several: whole burners staged in this order."""
    kp: float
    """Output units (burners, %, Nm3/h) per °C of error."""
    ti_min: float
    programme: Programme


@dataclass(frozen=True)
class Control:
    """A scenario's `control:` section: the loops, run every `period_min`."""

    period_min: float
    loops: tuple[Loop, ...]

    @property
    def driven(self) -> tuple[int, ...]:
        """Zones whose input a loop sets (the others follow the scenario's schedule)."""
        return tuple(i for loop in self.loops for i in loop.drives)


class PIController:
    """A positional PI, `u = kp (e + I / ti)`, sampled every `dt`, with clamping."""

    def __init__(self, kp: float, ti_min: float, lo: float, hi: float):
        self.kp, self.ti_min, self.lo, self.hi = kp, ti_min, lo, hi
        self.integral = 0.0
        """The integral of the error, °C min."""

    def update(self, error: float, dt_min: float) -> float:
        """The output for this period's error, within [lo, hi]."""
        advanced = self.integral + error * dt_min
        u = self.kp * (error + advanced / self.ti_min)
        if not ((u > self.hi and error > 0.0) or (u < self.lo and error < 0.0)):
            self.integral = advanced
        return float(np.clip(self.kp * (error + self.integral / self.ti_min),
                             self.lo, self.hi))


def output_limit(loop: Loop, furnace: Furnace) -> float:
    """The largest output of a loop: the sum of what its driven zones can give."""
    return float(sum(furnace.heat_inputs[i].max for i in loop.drives))


def staged(u: float, loop: Loop, furnace: Furnace) -> dict[int, float]:
    """The heat input per driven zone for output `u`: whole burners filled zone by zone in
    `drives` order, or the value itself for a zone fired otherwise (a rate, a pulse-fired
    zone's mean count)."""
    if len(loop.drives) == 1 and not furnace.heat_inputs[loop.drives[0]].whole:
        return {loop.drives[0]: float(u)}
    left = int(np.floor(u + 0.5))
    out = {}
    for i in loop.drives:
        out[i] = float(min(left, furnace.burners[i]))
        left -= int(out[i])
    return out


def control_from_node(node: Node, furnace: Furnace, initial_c: np.ndarray,
                      duration_min: float) -> Control:
    """`control`: `period_min` (default 1) and `zones`, per controlled zone `kp`, `ti_min`,
    `setpoint` (a programme), optional `sensor` (`mean` or a thermocouple of the zone) and
    `drives` (zones whose inputs it sets, default its own)."""
    root = node.mapping({"period_min", "zones"})
    period = root.get_number("period_min", 1.0, lo=1.0 / 60.0, hi=duration_min)
    zones_node = root.child("zones")
    zones_node.mapping(set(furnace.zones))
    if not zones_node.keys():
        raise zones_node.error(f"name at least one zone to control ({', '.join(furnace.zones)})")
    loops: list[Loop] = []
    owner: dict[int, str] = {}
    for name, spec in zones_node.items():
        spec.mapping({"sensor", "kp", "ti_min", "setpoint", "drives"})
        zone = furnace.zones.index(name)
        sensor = _sensor(spec, zone, furnace)
        drives = _drives(spec, zone, furnace)
        for i in drives:
            if i in owner:
                raise spec.child("drives" if spec.has("drives") else "kp").error(
                    f"zone {furnace.zones[i]}'s input is already set by the loop of zone "
                    f"{owner[i]}")
            owner[i] = name
        loops.append(Loop(zone, sensor, drives,
                          kp=spec.get_number("kp", lo=1e-9, hi=1e6),
                          ti_min=spec.get_number("ti_min", lo=1e-3, hi=1e6),
                          programme=programme_from_node(spec.child("setpoint"),
                                                        float(initial_c[zone]), duration_min)))
    return Control(period, tuple(loops))


def _sensor(spec: Node, zone: int, furnace: Furnace) -> int | None:
    mine = [s for s, z in zip(furnace.sensors, furnace.sensor_zone, strict=True) if z == zone]
    name = spec.get_string("sensor", MEAN, choices=(MEAN, *mine))
    return None if name == MEAN else furnace.sensors.index(name)


def _drives(spec: Node, zone: int, furnace: Furnace) -> tuple[int, ...]:
    if not spec.has("drives"):
        if furnace.burners[zone] == 0:
            raise spec.error(f"zone {furnace.zones[zone]} has no burners of its own: name "
                             "the zones its loop fires in 'drives'")
        return (zone,)
    node = spec.child("drives")
    out: list[int] = []
    for z in node.elements(min_len=1):
        i = furnace.zones.index(z.string(furnace.zones))
        if i in out:
            raise z.error(f"zone {furnace.zones[i]} appears twice")
        if furnace.burners[i] == 0:
            raise z.error(f"zone {furnace.zones[i]} has no burners to drive")
        out.append(i)
    if len(out) > 1:
        other = [furnace.zones[i] for i in out if not furnace.heat_inputs[i].whole]
        if other:
            raise node.error(f"one loop stages whole burners across several zones; "
                             f"{', '.join(other)} is not fired by whole burners")
    return tuple(out)
