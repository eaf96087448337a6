"""A sample from values read item by item (an OPC UA node, an S7 address), each with its
own quality: the item-based protocols' counterpart of `ModbusSource.decode`, giving the
same `Sample` so that the daemon, the log and the refit do not care which protocol
delivered it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from .daqconfig import DaqConfig
from .registers import COMM_ERROR, OK, STALE
from .sources import Sample, Unread


@dataclass(frozen=True)
class Reading:
    """What the PLC gave for one item: a number, a boolean, a text, the states of a bit
    range, or None; `quality` is the protocol's verdict on it (ok, stale for a value the
    PLC itself doubts, comm_error when there is none), `error` why it is not ok."""

    raw: object = None
    quality: str = OK
    error: str = ""


def _number(raw: object) -> float | None:
    if isinstance(raw, bool) or not isinstance(raw, int | float):
        return None
    return float(raw)


def _value(item, r: Reading) -> tuple[float | bool | str | None, str, str]:
    """(value, quality, error) of an analog item or a one-bit signal."""
    if r.raw is None or r.quality == COMM_ERROR:
        return None, COMM_ERROR if r.quality in (OK, COMM_ERROR) else r.quality, r.error
    if hasattr(item, "count"):  # a bit signal
        states = _states(item, r.raw)
        if states is None:
            return None, COMM_ERROR, f"{item.name}: expected {item.count} boolean(s), got {r.raw!r}"
        return states[0], r.quality, r.error
    number = _number(r.raw)
    if number is None:
        return None, COMM_ERROR, f"{item.name}: expected a number, got {r.raw!r}"
    value, quality = item.scaling.value(number)
    return value, (r.quality if quality == OK else quality), r.error


def _states(item, raw: object) -> list[bool] | None:
    values = raw if isinstance(raw, list | tuple) else [raw]
    if len(values) != item.count or not all(isinstance(v, bool | int) for v in values):
        return None
    return item.states(list(values))


def build_sample(config: DaqConfig, items: Iterable, got: dict[str, Reading]) -> Sample:
    """The sample of `items` (one device's) from what was read of each, by item name.
    Items that failed are comm_error (or the quality their reading says) and their errors
    are the sample's, one per failure."""
    mine = {it.name: it for it in items}
    sample = Sample()
    errors: dict[str, list[str]] = {}  # why -> the items it leaves without a value

    def note(r: Reading, name: str) -> None:
        if r.error:
            errors.setdefault(r.error, []).append(name)

    for point in (*config.thermocouples, *([config.ambient] if config.ambient else []),
                  *config.heat, *config.disturbances, *(s.item for s in config.signals)):
        if point.name not in mine:
            continue  # another device's
        r = got.get(point.name, Reading(None, COMM_ERROR, f"{point.name}: not read"))
        value, quality, error = _value(point, r)
        note(Reading(error=error), point.name)
        sample.values[point.name] = value
        sample.quality[point.name] = quality
    if config.clock is not None and "clock" in mine:
        r = got.get("clock", Reading(None, COMM_ERROR))
        value, quality, error = _value(mine["clock"], r)
        note(Reading(error=error), "clock")
        if value is not None and quality in (OK, STALE) and math.isfinite(value):
            sample.plc_seconds = float(value)
    if config.heartbeat is not None and "heartbeat" in mine:
        r = got.get("heartbeat", Reading(None, COMM_ERROR))
        note(r, "heartbeat")
        if isinstance(r.raw, str):
            sample.heartbeat = r.raw
        elif r.quality == OK and (n := _number(r.raw)) is not None:
            sample.heartbeat = n
    if config.burner_source in ("modbus", "both") and any(b.name in mine
                                                         for b in config.burner_bits):
        burners: dict[str, list[bool]] = {}
        quality = OK
        for bits in config.burner_bits:
            if bits.name not in mine:
                continue  # several devices: the daemon merges the zones
            r = got.get(bits.name, Reading(None, COMM_ERROR))
            states = None if r.raw is None or r.quality == COMM_ERROR \
                else _states(mine[bits.name], r.raw)
            if states is None:
                note(r if r.error or r.raw is None else
                     Reading(error=f"{bits.name}: expected {bits.count} booleans, got {r.raw!r}"),
                     bits.name)
                quality = COMM_ERROR
                break
            note(r, bits.name)
            burners[bits.name] = states
            if r.quality != OK:
                quality = r.quality
        sample.burner_quality = quality
        sample.burners = burners if quality != COMM_ERROR else None
    sample.errors = list(errors)
    sample.unread = [Unread(why, why, tuple(names)) for why, names in errors.items()]
    return sample
