"""A simulated PLC whose map names each item on its own (an OPC UA node, an S7 address)
rather than by register: the plant, PLC clock and heartbeat of the Modbus simulated PLC
(simplc.SimPLC, whose scan and `advance()` it reuses), and what each item of the map
shows at one scan. The protocol's server, which puts those values on the wire, is the
subclass's.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

from furnace_model.simulation.furnace import Furnace
from furnace_model.simulation.scenario import Scenario

from .daqconfig import DISTURBANCES_KEY, HEAT_KEY, SIGNALS_KEY, DaqConfig, Signal
from .servedmap import ServedMap
from .simplc import PlcValues, SimPLC, ValueSource, zone_slices


class ItemPLC(SimPLC):
    """`items`: the map to serve (default: the protocol's `default_items`); `signals`: the
    map's extra signals (simulated when the source has no value for them)."""

    item_types: ClassVar[tuple[type, ...]] = ()
    """The item classes of the protocol's map (which items of a config it serves)."""

    def __init__(self, source: ValueSource | Scenario, *, items=None,
                 signals: tuple[Signal, ...] = (), **kw):
        super().__init__(source, **kw)
        furnace = self.source.furnace
        self.served = ServedMap((), None, None, None, (), furnace, signals=signals)
        self.items = tuple(items) if items is not None else self.default_items(furnace)

    @staticmethod
    def default_items(furnace: Furnace) -> tuple:
        """The protocol's default map of `furnace`."""
        raise NotImplementedError

    @classmethod
    def of_config(cls, source, config: DaqConfig, device: str | None = None,
                  **kw: Any) -> ItemPLC:
        """The items a daemon config reads from `device` (default: its first)."""
        name = device or config.devices[0].name
        first = config.devices[0].name
        items = [it for it in config.plc_items() if (it.device or first) == name
                 and isinstance(it, cls.item_types)]
        return cls(source, items=items, signals=tuple(
            s for s in config.signals if s.item in items), **kw)

    def item_values(self, values: PlcValues) -> dict[str, float | list[bool]]:
        """What each item shows at this scan, by name: a number in engineering units (NaN
        for an open thermocouple), or the states of its bits as on the wire (`invert`
        applied)."""
        furnace = self.served.furnace
        by_sensor = dict(zip(furnace.sensors, values.thermocouples, strict=True))
        slices = dict(zip(furnace.switched_zones, zone_slices(furnace), strict=True))
        out: dict[str, float | list[bool]] = {}
        for item in self.items:
            if hasattr(item, "count"):  # bits
                if item.name in slices:
                    states = list(values.burners[slices[item.name]])
                else:  # a bit signal
                    v = values.signals.get(item.name.removeprefix(f"{SIGNALS_KEY}."), False)
                    states = [v is True or v == 1]
                out[item.name] = [s != item.invert for s in states]
            else:
                out[item.name] = self._value_of(item.name, values, by_sensor)
        return out

    def _value_of(self, name: str, values: PlcValues, by_sensor: dict[str, float]) -> float:
        if name in by_sensor:
            return math.nan if name in self.open_sensors else by_sensor[name]
        if name == "t_air":
            return values.t_air
        if name == "clock":
            return float(self.plc_seconds)
        if name == "heartbeat":
            return float(self.heartbeat)
        section, _, key = name.partition(".")
        got = {HEAT_KEY: values.heat, DISTURBANCES_KEY: values.disturbances,
               SIGNALS_KEY: values.signals}.get(section, {})
        return float(got.get(key, math.nan))
