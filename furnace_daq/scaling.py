"""A number a PLC gives, as an engineering value with its quality: scale, offset, the raw
values that mean an open sensor, and the plausible range.

An item-based protocol (OPC UA, S7) hands over a typed number where Modbus hands over words;
what follows is the same as for a register point (registers.Point.value), with the same
map keys (`scale`, `offset`, `sentinels`, `range`) and the same qualities.
"""

from __future__ import annotations

from dataclasses import dataclass

from furnace_model.config import Node

from .registers import OK, OUT_OF_RANGE, SENSOR_OPEN

SCALING_KEYS = ("scale", "offset", "sentinels", "range")


@dataclass(frozen=True)
class Scaling:
    scale: float = 1.0
    offset: float = 0.0
    sentinels: tuple[float, ...] = ()
    """Raw values (before scale) that mean the sensor is open or broken."""
    lo: float | None = None
    hi: float | None = None
    """Plausible range in engineering units; outside it the value is `out_of_range`."""

    def value(self, raw: float) -> tuple[float | None, str]:
        """(engineering value or None, quality): NaN or a sentinel is an open sensor."""
        if raw != raw or raw in self.sentinels:
            return None, SENSOR_OPEN
        v = raw * self.scale + self.offset
        if (self.lo is not None and v < self.lo) or (self.hi is not None and v > self.hi):
            return None, OUT_OF_RANGE
        return round(float(v), 9), OK

    def raw(self, value: float) -> float:
        """The raw number that reads as `value` (what a simulated PLC serves)."""
        return (value - self.offset) / self.scale


def wrapped(raw: float, bits: int, signed: bool) -> int:
    """`raw` rounded to an integer of `bits` bits, wrapped as the PLC's counter wraps: what
    a simulated PLC serves for a value of an integer type."""
    lo = -(2 ** (bits - 1)) if signed else 0
    return lo + (int(round(raw)) - lo) % 2 ** bits


def parse_scaling(node: Node) -> Scaling:
    """`scale`, `offset`, `sentinels` and `range` of a map entry, checked as a register
    point's are."""
    sentinels = tuple(n.number() for n in node.child("sentinels", []).elements())
    lo = hi = None
    if node.has("range"):
        rng = node.child("range")
        lo, hi = (n.number() for n in rng.elements(2, 2))
        if lo >= hi:
            raise rng.error(f"expected [low, high] with low < high, got [{lo:g}, {hi:g}]")
    scale = node.get_number("scale", 1.0)
    if scale == 0:
        raise node.child("scale").error("must not be 0")
    return Scaling(scale, node.get_number("offset", 0.0), sentinels, lo, hi)
