"""Samples as the typed messages the log holds (furnace_model.log.messages), and the
events of PLC and flame scanners disagreeing about the burners.

A reading that is not there is left out of its message, never written as null: the schema
declares numbers, and the quality beside it says why it is missing. Timestamps are the
caller's: the builder is told the PLC clock's time, so it works on plain samples.
"""

from __future__ import annotations

from collections.abc import Sequence

from furnace_model.log.messages import (
    Ambient,
    Burners,
    DaqEvent,
    DaqEventKind,
    Disturbances,
    Heat,
    NamedReadings,
    Signals,
    Thermocouples,
)

from .daqconfig import DISTURBANCES_KEY, HEAT_KEY, DaqConfig, item_name
from .registers import COMM_ERROR, OK
from .sources import Sample

Reading = Thermocouples | Ambient | Burners | Heat | Disturbances | Signals


class MessageBuilder:
    def __init__(self, config: DaqConfig):
        furnace = config.furnace
        self.sensors = furnace.sensors
        self.zones = furnace.switched_zones
        self.ambient_measured = config.ambient is not None
        self.ambient_default_c = config.ambient_default_c
        # (name in the message, item name in the sample, unit) of each value carried by name
        self.heat = [(furnace.zones[i], item_name(HEAT_KEY, furnace.zones[i]),
                      furnace.heat_inputs[i].unit) for i in furnace.rated]
        self.disturbances = [(d.name, item_name(DISTURBANCES_KEY, d.name), d.unit)
                             for d in furnace.disturbances]
        self.signals = [(s.name, s.item.name, s.unit) for s in config.signals]

    def readings(self, sample: Sample, pub_ns: int) -> list[Reading]:
        """The thermocouples, the ambient, the rate-fired zones' heat inputs, the
        disturbances and the signals the map has, and (when the sample has them) the burner
        states of a merged PLC sample; `pub_ns` is the PLC clock's time, written into each
        when the sample carries that clock."""
        quality = sample.quality  # each device's staleness is in its qualities already (merge)
        tc = Thermocouples({s: v for s in self.sensors if (v := sample.values.get(s)) is not None},
                           {s: quality.get(s, COMM_ERROR) for s in self.sensors})
        stamp: int | None = None  # the PLC's clock, when it has one
        if sample.plc_seconds is not None:
            stamp = pub_ns
            tc.plc_seconds, tc.plc_time = sample.plc_seconds, stamp
        if sample.errors:  # blocks the PLC refused: why some points are comm_error
            tc.error = "; ".join(sample.errors)
        if self.ambient_measured:
            amb = Ambient(sample.values.get("t_air"), quality.get("t_air", COMM_ERROR),
                          plc_time=stamp)
        else:
            amb = Ambient(self.ambient_default_c, OK, True, stamp)
        out: list[Reading] = [tc, amb]
        for cls, named in ((Heat, self.heat), (Disturbances, self.disturbances),
                           (Signals, self.signals)):
            if named:
                out.append(_named(cls, named, sample, stamp))
        if sample.burners is not None:
            out.append(self.burners(sample, "modbus", stamp))
        return out

    def no_reading(self, why: list[str]) -> Thermocouples:
        """Every sensor comm_error, with why no device delivered."""
        return Thermocouples({}, {s: COMM_ERROR for s in self.sensors}, error="; ".join(why))

    def burners(self, sample: Sample, source: str, stamp: int | None = None) -> Burners:
        assert sample.burners is not None
        states = {z: sample.burners[z] for z in self.zones}
        return Burners.from_states(states, source, sample.burner_quality, stamp)


def _named(cls: type[NamedReadings], named: list[tuple[str, str, str]], sample: Sample,
           stamp: int | None) -> NamedReadings:
    """A message of values carried by name: a value that is not there is left out, its
    quality says why (comm_error when its device gave nothing)."""
    return cls({n: v for n, item, _ in named if (v := sample.values.get(item)) is not None},
               {n: sample.quality.get(item, COMM_ERROR) for n, item, _ in named},
               {n: unit for n, _, unit in named}, stamp)


class FlameComparison:
    """PLC burner states against the flame scanners: a burner commanded on whose flame is
    out (or the reverse) is what an operator must see, but one poll's difference is a
    burner switching between the two reads, so only `polls` in a row count."""

    def __init__(self, zones: Sequence[str], polls: int):
        self.zones, self.polls = zones, polls
        self._seen: tuple[frozenset[str], int] = (frozenset(), 0)
        self._reported: frozenset[str] = frozenset()

    def compare(self, plc: Sample, flame: Sample) -> DaqEvent | None:
        """The event when the set of burners they disagree on has held for `polls` polls
        and differs from the one last reported (the empty set: they agree again)."""
        if plc.burners is None or flame.burners is None or plc.burner_quality != OK \
                or flame.burner_quality != OK:
            return None
        diff = frozenset(f"{z}[{i}]" for z in self.zones
                         for i, (a, b) in enumerate(zip(plc.burners[z], flame.burners[z],
                                                        strict=True)) if a != b)
        seen, n = self._seen
        n = n + 1 if diff == seen else 1
        self._seen = (diff, n)
        if diff == self._reported or n < self.polls:
            return None
        self._reported = diff
        if diff:
            detail = f"PLC and flame scanners disagree on {', '.join(sorted(diff))}"
            kind = DaqEventKind.BURNER_DISAGREEMENT
        else:
            detail, kind = "PLC and flame scanners agree again", DaqEventKind.BURNER_AGREEMENT
        return DaqEvent(kind, detail, burners=sorted(diff), plc=plc.burners,
                        flame=flame.burners)
