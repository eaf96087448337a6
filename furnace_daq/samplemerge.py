"""Several devices' samples as one, as if one PLC held every point, and each device's
staleness judged from its heartbeat.

A device whose program has stopped still answers polls, with values that no longer move:
only its heartbeat register tells. Its points are then marked stale, and only its points:
the other devices' readings stay ok. A device that gave nothing this tick leaves its points
out (they are comm_error downstream), with the reason among the merged sample's errors.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from .registers import COMM_ERROR, OK, STALE
from .sources import Sample


class Heartbeat:
    """A device's heartbeat as last seen: the value and since when it has not changed."""

    def __init__(self) -> None:
        self._last: tuple[float | str, float] | None = None

    def reset(self) -> None:
        """Forget the last value: a new connection may find a restarted program."""
        self._last = None

    def stale(self, value: float | str | None, now: float, after_s: float) -> bool:
        """Whether `value` (None: the device has no heartbeat) has stood still for longer
        than `after_s` at `now` (monotonic seconds)."""
        if value is None:
            return False
        if self._last is None or value != self._last[0]:
            self._last = (value, now)
            return False
        return now - self._last[1] > after_s


class Device(Protocol):
    """What the merger needs of a device: whether its heartbeat is stale, and how its
    errors are named."""

    last_stale: bool

    def named(self, text: str) -> str: ...


def merge(good: Sequence[tuple[Device, Sample]], missing: Sequence[str], zones: Sequence[str],
          burner_source: str) -> Sample:
    """One sample from the devices that delivered, each device's staleness marking its own
    points only. `missing` is why the others gave nothing. Burner states are taken from the
    devices only when `burner_source` includes Modbus, and only when every zone of `zones`
    (those fired by burners) is there."""
    out = Sample()
    burners: dict[str, list[bool]] = {}
    burner_quality = OK
    for device, s in good:
        stale = device.last_stale
        out.values.update(s.values)
        out.quality.update({k: STALE if stale and q == OK else q for k, q in s.quality.items()})
        if s.plc_seconds is not None:
            out.plc_seconds = s.plc_seconds
        if s.burners is not None:
            burners.update(s.burners)
            if stale and s.burner_quality == OK:
                burner_quality = STALE
        if s.burner_quality != OK:
            burner_quality = s.burner_quality
        out.errors += [device.named(e) for e in s.errors]
        out.unread += s.unread
    out.errors += missing
    if burner_source in ("modbus", "both") and zones:
        if all(z in burners for z in zones):
            out.burners = burners
        else:
            burner_quality = COMM_ERROR
    out.burner_quality = burner_quality
    return out
