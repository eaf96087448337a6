"""Raw Modbus words and bits -> engineering values with a quality, and the read plan.

This is where field surprises land (word order, byte order, a sentinel for a broken
thermocouple, a scale of 0.1), so it is pure and exhaustively tested: no socket here.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

OK, STALE, COMM_ERROR, OUT_OF_RANGE, SENSOR_OPEN = (
    "ok", "stale", "comm_error", "out_of_range", "sensor_open")
QUALITIES = (OK, STALE, COMM_ERROR, OUT_OF_RANGE, SENSOR_OPEN)

REGISTER_TABLES = ("input", "holding")
BIT_TABLES = ("discrete", "coil")
TABLES = REGISTER_TABLES + BIT_TABLES
FUNCTION_CODE = {"coil": 1, "discrete": 2, "holding": 3, "input": 4}

MAX_REGISTERS_PER_READ = 125
MAX_BITS_PER_READ = 2000

# data type -> (registers, struct format of the big-endian bytes)
DATA_TYPES: dict[str, tuple[int, str]] = {
    "int16": (1, ">h"), "uint16": (1, ">H"),
    "int32": (2, ">i"), "uint32": (2, ">I"),
    "float32": (2, ">f"),
}
ORDERS = ("big", "little")


def _arrange(words: Sequence[int], word_order: str, byte_order: str) -> bytes:
    """Bytes in big-endian order from words as the PLC lays them out."""
    ws = list(words) if word_order == "big" else list(reversed(words))
    out = bytearray()
    for w in ws:
        hi, lo = (w >> 8) & 0xFF, w & 0xFF
        out += bytes((hi, lo)) if byte_order == "big" else bytes((lo, hi))
    return bytes(out)


def decode(words: Sequence[int], dtype: str, word_order: str = "big",
           byte_order: str = "big") -> int | float:
    """The value held in `words` (each 0..65535) for a data type and word/byte order."""
    n, fmt = DATA_TYPES[dtype]
    if len(words) != n:
        raise ValueError(f"{dtype} needs {n} register(s), got {len(words)}")
    return struct.unpack(fmt, _arrange(words, word_order, byte_order))[0]


def encode(value: int | float, dtype: str, word_order: str = "big",
           byte_order: str = "big") -> list[int]:
    """The words a PLC would hold for `value` (inverse of decode); the simulator uses it."""
    n, fmt = DATA_TYPES[dtype]
    raw = struct.pack(fmt, value)
    words = [(raw[2 * i] << 8) | raw[2 * i + 1] for i in range(n)]
    if byte_order == "little":
        words = [((w & 0xFF) << 8) | (w >> 8) for w in words]
    return words if word_order == "big" else list(reversed(words))


@dataclass(frozen=True)
class Point:
    """One analog value in a PLC's register map, as an engineer writes it down."""

    name: str
    table: str = "input"
    address: int = 0
    dtype: str = "int16"
    word_order: str = "big"
    byte_order: str = "big"
    scale: float = 1.0
    offset: float = 0.0
    sentinels: tuple[float, ...] = ()
    """Raw values (before scale) that mean the sensor is open or broken."""
    lo: float | None = None
    hi: float | None = None
    """Plausible range in engineering units; outside it the value is `out_of_range`."""

    @property
    def count(self) -> int:
        return DATA_TYPES[self.dtype][0]

    def raw(self, words: Sequence[int]) -> int | float:
        return decode(words, self.dtype, self.word_order, self.byte_order)

    def value(self, words: Sequence[int]) -> tuple[float | None, str]:
        """(engineering value or None, quality) from this point's words."""
        raw = self.raw(words)
        if raw != raw or raw in self.sentinels:  # NaN from a float32 counts as open
            return None, SENSOR_OPEN
        v = raw * self.scale + self.offset
        if (self.lo is not None and v < self.lo) or (self.hi is not None and v > self.hi):
            return None, OUT_OF_RANGE
        return round(float(v), 9), OK  # no 400.70000000000005 in the log


@dataclass(frozen=True)
class BitRange:
    """Consecutive on/off states (one zone's burners) in a bit table (discrete or coil)."""

    name: str
    table: str
    address: int
    count: int
    invert: bool = False

    def states(self, bits: Sequence[bool]) -> list[bool]:
        return [bool(b) != self.invert for b in bits]


@dataclass(frozen=True)
class ReadRequest:
    table: str
    address: int
    count: int

    @property
    def end(self) -> int:
        return self.address + self.count


def span(item: Point | BitRange) -> tuple[str, int, int]:
    """(table, first address, one past the last) that an item occupies."""
    return item.table, item.address, item.address + item.count


def plan_reads(items: Iterable[Point | BitRange], max_gap_registers: int = 8,
               max_gap_bits: int = 64) -> list[ReadRequest]:
    """As few requests as the protocol limits allow: neighbours in one table are merged
    when the hole between them is at most the allowed gap (reading a few unused addresses
    costs less than a round trip), never beyond 125 registers / 2000 bits per request."""
    by_table: dict[str, list[tuple[int, int]]] = {}
    for item in items:
        table, a, b = span(item)
        by_table.setdefault(table, []).append((a, b))
    out: list[ReadRequest] = []
    for table in TABLES:
        spans = sorted(by_table.get(table, []))
        if not spans:
            continue
        limit = MAX_REGISTERS_PER_READ if table in REGISTER_TABLES else MAX_BITS_PER_READ
        gap = max_gap_registers if table in REGISTER_TABLES else max_gap_bits
        start, end = spans[0]
        for a, b in spans[1:]:
            if a - end <= gap and max(end, b) - start <= limit:
                end = max(end, b)
            else:
                out.append(ReadRequest(table, start, end - start))
                start, end = a, b
        out.append(ReadRequest(table, start, end - start))
    return out


def overlaps(items: Sequence[Point | BitRange]) -> tuple[int, int] | None:
    """Indices of the first two items that share an address in the same table, if any."""
    spans = sorted((span(it), i) for i, it in enumerate(items))
    for ((t1, _a1, b1), i), ((t2, a2, _b2), j) in zip(spans, spans[1:], strict=False):
        if t1 == t2 and a2 < b1:
            return min(i, j), max(i, j)
    return None


class Image:
    """What one scan read: words/bits by table and address, from a set of responses."""

    def __init__(self) -> None:
        self.data: dict[str, dict[int, int]] = {t: {} for t in TABLES}

    def put(self, request: ReadRequest, values: Sequence[int | bool]) -> None:
        table = self.data[request.table]
        for k in range(request.count):
            table[request.address + k] = int(values[k])

    def words(self, item: Point | BitRange) -> list[int] | None:
        table, a, b = span(item)
        got = self.data[table]
        if any(k not in got for k in range(a, b)):
            return None
        return [got[k] for k in range(a, b)]
