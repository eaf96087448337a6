"""What a simulated PLC puts on its registers and bits: the values of one second, encoded
through a register map as the daemon would decode them.

The default is the map of CONTRACTS.md section 3. Any daemon config's map can be served
instead (`sim-plc --config`), and a log's recorded map (`sim-plc --from-log`): a log taken
from a PLC with floats in swapped words and burner bits packed in a status word is served
again on the same wire, so the same daemon config reads it back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from furnace_model import BURNERS_PER_ZONE, SENSORS, ZONES

from .registers import (
    BIT_TABLES,
    DATA_TYPES,
    STRING,
    TABLES,
    BitRange,
    Point,
    encode,
)

if TYPE_CHECKING:
    from .daqconfig import DaqConfig

INTEGER_RANGE = {"int16": (-2**15, 2**15 - 1), "uint16": (0, 2**16 - 1),
                 "int32": (-2**31, 2**31 - 1), "uint32": (0, 2**32 - 1),
                 "int64": (-2**63, 2**63 - 1), "uint64": (0, 2**64 - 1)}


@dataclass(frozen=True)
class ServedMap:
    """Where each value goes: thermocouples (SENSORS order), ambient, PLC clock, heartbeat,
    and each zone's burner bits. A missing point is not served."""

    thermocouples: tuple[Point, ...]
    ambient: Point | None
    clock: Point | None
    heartbeat: Point | None
    burners: tuple[BitRange, ...]

    @classmethod
    def default(cls) -> ServedMap:
        """CONTRACTS.md section 3: input registers 0-9, burner states on discrete inputs."""
        tc = tuple(Point(s, "input", i, "int16", scale=0.1, sentinels=(32767.0,))
                   for i, s in enumerate(SENSORS))
        starts = [sum(BURNERS_PER_ZONE[:i]) for i in range(len(ZONES))]
        return cls(tc, Point("t_air", "input", 6, "int16", scale=0.1),
                   Point("clock", "input", 7, "uint32"), Point("heartbeat", "input", 9, "uint16"),
                   tuple(BitRange(z, "discrete", a, n)
                         for z, a, n in zip(ZONES, starts, BURNERS_PER_ZONE, strict=True)))

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

        return cls(tuple(by_name[s] for s in SENSORS if s in by_name), own(config.ambient),
                   own(clock), own(config.heartbeat),
                   tuple(b for b in config.burner_bits if b.name in mine))

    def sizes(self) -> dict[str, int]:
        """Addresses each table needs, at least the default map's (coils mirror the burner
        states at 0-25 for manual mode)."""
        need = {"input": 10, "holding": 1, "discrete": sum(BURNERS_PER_ZONE),
                "coil": sum(BURNERS_PER_ZONE)}
        for p in (*self.thermocouples, self.ambient, self.clock, self.heartbeat):
            if p is not None:
                need[p.table] = max(need[p.table], p.address + p.count)
        for b in self.burners:
            need[b.table] = max(need[b.table], b.address + b.width)
        return need

    def image(self, thermocouples: list[float], t_air: float, plc_seconds: int, heartbeat: int,
              burners: list[bool], open_sensors: set[str] = frozenset()
              ) -> dict[str, dict[int, int | bool]]:
        """{table: {address: word or bit}} of one PLC scan. A NaN reading or an open
        sensor is served as the point's first sentinel (NaN for a float point without one)."""
        out: dict[str, dict[int, int | bool]] = {t: {} for t in TABLES}
        by_name = dict(zip(SENSORS, thermocouples, strict=True))
        for p in self.thermocouples:
            v = math.nan if p.name in open_sensors else by_name[p.name]
            _put(out, p, _words(p, v))
        if self.ambient is not None:
            _put(out, self.ambient, _words(self.ambient, t_air))
        if self.clock is not None:
            _put(out, self.clock, _words(self.clock, plc_seconds, wrap=True))
        if self.heartbeat is not None and self.heartbeat.dtype != STRING:
            _put(out, self.heartbeat, _words(self.heartbeat, heartbeat, wrap=True))
        starts = dict(zip(ZONES, [sum(BURNERS_PER_ZONE[:i]) for i in range(len(ZONES))],
                          strict=True))
        for b in self.burners:
            states = [s != b.invert for s in burners[starts[b.name]:starts[b.name] + b.count]]
            if b.table in BIT_TABLES:
                out[b.table].update({b.address + i: s for i, s in enumerate(states)})
            else:  # packed into registers: set this range's bits, keep the others
                regs = out[b.table]
                for i, s in enumerate(states):
                    k = b.bit + i
                    a, mask = b.address + k // 16, 1 << (k % 16)
                    regs[a] = (int(regs.get(a, 0)) | mask) if s else (int(regs.get(a, 0)) & ~mask)
        return out


def _put(out: dict[str, dict[int, int | bool]], p: Point, words: list[int]) -> None:
    out[p.table].update({p.address + i: w for i, w in enumerate(words)})


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
    if p.dtype in INTEGER_RANGE:
        lo, hi = INTEGER_RANGE[p.dtype]
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
