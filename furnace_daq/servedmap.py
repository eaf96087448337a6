"""What a simulated PLC puts on its registers and bits: the values of one second, encoded
through a register map as the daemon would decode them.

The default is the map of CONTRACTS.md section 3, derived for any furnace description by one
rule (`ServedMap.default`, docs/operations.md). Any daemon config's map can be served
instead (`sim-plc --config`), and a log's recorded map (`sim-plc --from-log`): a log taken
from a PLC with floats in swapped words and burner bits packed in a status word is served
again on the same wire, so the same daemon config reads it back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from furnace_model.simulation.furnace import Furnace

from .daqconfig import DISTURBANCES_KEY, HEAT_KEY, Signal, item_name
from .registers import (
    BIT,
    BIT_TABLES,
    DATA_TYPES,
    STRING,
    TABLES,
    BitRange,
    Point,
    encode,
    integer_range,
)

if TYPE_CHECKING:
    from .daqconfig import DaqConfig


def burner_starts(furnace: Furnace) -> dict[str, int]:
    """Where each zone fired by burners begins in the PLC's list of burner states (and in the
    default map's bits): zone after zone, in the description's order."""
    sizes = [furnace.burners[i] for i in furnace.switched]
    return {furnace.zones[i]: sum(sizes[:k]) for k, i in enumerate(furnace.switched)}


@dataclass(frozen=True)
class ServedMap:
    """Where each value goes: thermocouples (the furnace's sensor order), ambient, PLC clock,
    heartbeat, each zone's burner bits (the zones fired by burners), each rate-fired zone's
    heat input, each disturbance and each extra signal. A missing point is not served."""

    thermocouples: tuple[Point, ...]
    ambient: Point | None
    clock: Point | None
    heartbeat: Point | None
    burners: tuple[BitRange, ...]
    furnace: Furnace
    heat: tuple[Point, ...] = ()
    """Named `heat.<zone>`, as the config's points."""
    disturbances: tuple[Point, ...] = ()
    """Named `disturbances.<name>`."""
    signals: tuple[Signal, ...] = ()

    @classmethod
    def default(cls, furnace: Furnace) -> ServedMap:
        """The default map of a furnace with n thermocouples (CONTRACTS.md section 3 for the
        paper's, n = 6): input registers 0..n-1 the thermocouples in the description's order
        (INT16, 0.1 °C, 32767 = open), n the ambient (INT16, 0.1 °C), n+1..n+2 the PLC clock
        (UINT32, high word first), n+3 the heartbeat (UINT16); then two registers each
        (FLOAT32 in the description's unit, high word first) for the heat input of every
        rate-fired zone in zone order, then for every disturbance in the description's order;
        discrete inputs from 0 the burners of the zones fired by burners, zone after zone in
        the description's order, one bit each; coils the same addresses for the burner
        commands."""
        n = len(furnace.sensors)
        tc = tuple(Point(s, "input", i, "int16", scale=0.1, sentinels=(32767.0,))
                   for i, s in enumerate(furnace.sensors))
        starts = burner_starts(furnace)
        names = [item_name(HEAT_KEY, furnace.zones[i]) for i in furnace.rated]
        names += [item_name(DISTURBANCES_KEY, d.name) for d in furnace.disturbances]
        analog = [Point(name, "input", n + 4 + 2 * k, "float32") for k, name in enumerate(names)]
        return cls(tc, Point("t_air", "input", n, "int16", scale=0.1),
                   Point("clock", "input", n + 1, "uint32"),
                   Point("heartbeat", "input", n + 3, "uint16"),
                   tuple(BitRange(z, "discrete", a, furnace.burners[furnace.zones.index(z)])
                         for z, a in starts.items()),
                   furnace, tuple(analog[:len(furnace.rated)]),
                   tuple(analog[len(furnace.rated):]))

    @classmethod
    def of_config(cls, config: DaqConfig, device: str | None = None) -> ServedMap:
        """The map a daemon config reads from `device` (default: its first device)."""
        name = device or config.devices[0].name
        first = config.devices[0].name
        mine = {it.name for it in config.modbus_items() if (it.device or first) == name}
        by_name = {p.name: p for p in config.thermocouples if p.name in mine}
        clock = None if config.clock is None else config.clock.point

        def own(p: Point | None) -> Point | None:
            return p if p is not None and p.name in mine else None

        furnace = config.furnace
        return cls(tuple(by_name[s] for s in furnace.sensors if s in by_name),
                   own(config.ambient), own(clock), own(config.heartbeat),
                   tuple(b for b in config.burner_bits if b.name in mine), furnace,
                   tuple(p for p in config.heat if p.name in mine),
                   tuple(p for p in config.disturbances if p.name in mine),
                   tuple(s for s in config.signals if s.item.name in mine))

    def sizes(self) -> dict[str, int]:
        """Addresses each table needs, at least the default map's (coils mirror the burner
        states at 0.. for manual mode)."""
        furnace = self.furnace
        n_burners = sum(furnace.burners[i] for i in furnace.switched)
        n_analog = 2 * (len(furnace.rated) + len(furnace.disturbances))
        need = {"input": len(furnace.sensors) + 4 + n_analog, "holding": 1,
                "discrete": n_burners, "coil": n_burners}
        for p in (*self.thermocouples, self.ambient, self.clock, self.heartbeat, *self.heat,
                  *self.disturbances, *(s.item for s in self.signals)):
            if isinstance(p, BitRange):
                need[p.table] = max(need[p.table], p.address + p.width)
            elif p is not None:
                need[p.table] = max(need[p.table], p.address + p.count)
        for b in self.burners:
            need[b.table] = max(need[b.table], b.address + b.width)
        return need

    def image(self, thermocouples: list[float], t_air: float, plc_seconds: int, heartbeat: int,
              burners: list[bool], open_sensors: set[str] = frozenset(), *,
              heat: dict[str, float] | None = None,
              disturbances: dict[str, float] | None = None,
              signals: dict[str, float | bool] | None = None
              ) -> dict[str, dict[int, int | bool]]:
        """{table: {address: word or bit}} of one PLC scan. A NaN reading or an open
        sensor is served as the point's first sentinel (NaN for a float point without one).
        `burners`: every burner of the zones fired by burners, zone after zone; `heat` by
        rate-fired zone, `disturbances` and `signals` by name (a bit signal as a boolean)."""
        out: dict[str, dict[int, int | bool]] = {t: {} for t in TABLES}
        furnace = self.furnace
        by_name = dict(zip(furnace.sensors, thermocouples, strict=True))
        for p in self.thermocouples:
            v = math.nan if p.name in open_sensors else by_name[p.name]
            _put(out, p, _words(p, v))
        if self.ambient is not None:
            _put(out, self.ambient, _words(self.ambient, t_air))
        if self.clock is not None:
            _put(out, self.clock, _words(self.clock, plc_seconds, wrap=True))
        if self.heartbeat is not None and self.heartbeat.dtype != STRING:
            _put(out, self.heartbeat, _words(self.heartbeat, heartbeat, wrap=True))
        for points, values, section in ((self.heat, heat, HEAT_KEY),
                                        (self.disturbances, disturbances, DISTURBANCES_KEY)):
            for p in points:
                v = (values or {}).get(p.name.removeprefix(f"{section}."), math.nan)
                _put(out, p, _words(p, v))
        for signal in self.signals:
            v = (signals or {}).get(signal.name, math.nan)
            if isinstance(signal.item, BitRange):
                _put_bits(out, signal.item, [v is True or v == 1])
            else:
                _put(out, signal.item, _words(signal.item, float(v)))
        starts = burner_starts(furnace)
        for b in self.burners:
            _put_bits(out, b, burners[starts[b.name]:starts[b.name] + b.count])
        return out


def _put(out: dict[str, dict[int, int | bool]], p: Point, words: list[int]) -> None:
    out[p.table].update({p.address + i: w for i, w in enumerate(words)})


def _put_bits(out: dict[str, dict[int, int | bool]], b: BitRange, states: list[bool]) -> None:
    """On/off states as `b` reads them: bits of a bit table, or bits packed into registers
    (this range's bits set, the others kept)."""
    states = [s != b.invert for s in states]
    if b.table in BIT_TABLES:
        out[b.table].update({b.address + i: s for i, s in enumerate(states)})
        return
    regs = out[b.table]
    for i, s in enumerate(states):
        k = b.bit + i
        a, mask = b.address + k // 16, 1 << (k % 16)
        regs[a] = (int(regs.get(a, 0)) | mask) if s else (int(regs.get(a, 0)) & ~mask)


def _words(p: Point, value: float, wrap: bool = False) -> list[int]:
    """The words that `p` decodes to `value`: the inverse of scale and offset, rounded and
    kept inside the type (and off a sentinel) for integers; `wrap` for counters."""
    if p.dtype == STRING:
        return encode(f"{value:g}", STRING, p.word_order, p.byte_order, p.length)
    raw = (value - p.offset) * (1.0 / p.scale) if math.isfinite(value) else math.nan
    if math.isfinite(value) and not math.isfinite(raw):
        raise OverflowError(f"{p.name} = {value:g} is beyond any {p.dtype} register")
    if not math.isfinite(raw):
        raw = p.sentinels[0] if p.sentinels else math.nan
    if p.dtype == BIT:  # a coil or discrete input: on from half way
        return [int(math.isfinite(raw) and raw >= 0.5)]
    span = integer_range(p.dtype)
    if span is not None:
        lo, hi = span
        if not math.isfinite(raw):
            raw = hi  # no sentinel to say so: the most an integer register can show
        raw = int(round(raw))
        if wrap:
            raw = lo + (raw - lo) % (hi - lo + 1)
        raw = min(max(raw, lo), hi)
        if raw in p.sentinels and not math.isnan(value):
            raw -= 1 if raw > 0 else -1  # a real reading never shows as open circuit
    assert p.dtype in DATA_TYPES
    return encode(raw, p.dtype, p.word_order, p.byte_order)
