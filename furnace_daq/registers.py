"""Raw Modbus words and bits -> engineering values with a quality, and the read plan.

This is where field surprises land (word order, byte order, a sentinel for a broken
thermocouple, a scale of 0.1), so it is pure and exhaustively tested: no socket here.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from furnace_model.log.schema import QUALITIES

OK, STALE, COMM_ERROR, OUT_OF_RANGE, SENSOR_OPEN = QUALITIES

REGISTER_TABLES = ("input", "holding")
BIT_TABLES = ("discrete", "coil")
TABLES = REGISTER_TABLES + BIT_TABLES
FUNCTION_CODE = {"coil": 1, "discrete": 2, "holding": 3, "input": 4}

MAX_REGISTERS_PER_READ = 125
MAX_BITS_PER_READ = 2000

# numeric data type -> (registers, struct format of the big-endian bytes)
DATA_TYPES: dict[str, tuple[int, str]] = {
    "int8h": (1, ">bx"), "int8l": (1, ">xb"), "uint8h": (1, ">Bx"), "uint8l": (1, ">xB"),
    "int16": (1, ">h"), "uint16": (1, ">H"),
    "int32": (2, ">i"), "uint32": (2, ">I"),
    "float32": (2, ">f"),
    "int64": (4, ">q"), "uint64": (4, ">Q"), "float64": (4, ">d"),
    "float16": (1, ">e"),
}


def integer_range(dtype: str) -> tuple[int, int] | None:
    """The raw values an integer type holds; None for a floating-point type. From the
    struct format, so that a type added to DATA_TYPES needs nothing else."""
    code = DATA_TYPES[dtype][1].strip(">x")
    if code in "efd":
        return None
    bits = 8 * struct.calcsize(code)
    return (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1) if code.islower() else (0, 2**bits - 1)


BYTE_TYPES = ("int8h", "int8l", "uint8h", "uint8l")
"""One byte of a register, Telegraf's INT8H, INT8L, UINT8H, UINT8L: h the high (first) byte,
l the low one, after `byte_order` (little swaps them), so that two values packed in one
register read as two points of the same address."""
STRING = "string"
"""Text in `length` registers, two characters per register; trailing NULs and spaces are
padding and dropped. Not a number: no scale, offset, sentinels or range."""
BIT = "bit"
"""One coil or discrete input read as a number, 0 or 1 (before scale and offset), as
Telegraf's UINT16 output of a bit register: a measured on/off disturbance, a life bit."""
POINT_TYPES = (*DATA_TYPES, STRING)
ORDERS = ("big", "little")
TELEGRAF_ORDERS: dict[str, tuple[str, str]] = {
    "AB": ("big", "big"), "BA": ("big", "little"),
    "ABCD": ("big", "big"), "DCBA": ("little", "little"),
    "BADC": ("big", "little"), "CDAB": ("little", "big"),
    "ABCDEFGH": ("big", "big"), "HGFEDCBA": ("little", "little"),
    "BADCFEHG": ("big", "little"), "GHEFCDAB": ("little", "big"),
}
"""Byte orders as Telegraf's Modbus input names them (A = most significant byte), as
(word_order, byte_order): the four-letter names apply to values of any length, as they do
in Telegraf's request-based configuration."""


def _arrange(words: Sequence[int], word_order: str, byte_order: str) -> bytes:
    """Bytes in big-endian order from words as the PLC lays them out."""
    ws = list(words) if word_order == "big" else list(reversed(words))
    out = bytearray()
    for w in ws:
        hi, lo = (w >> 8) & 0xFF, w & 0xFF
        out += bytes((hi, lo)) if byte_order == "big" else bytes((lo, hi))
    return bytes(out)


def _words(raw: bytes, word_order: str, byte_order: str) -> list[int]:
    """Inverse of `_arrange`: big-endian bytes -> words as the PLC lays them out."""
    words = [(raw[2 * i] << 8) | raw[2 * i + 1] for i in range(len(raw) // 2)]
    if byte_order == "little":
        words = [((w & 0xFF) << 8) | (w >> 8) for w in words]
    return words if word_order == "big" else list(reversed(words))


def decode(words: Sequence[int], dtype: str, word_order: str = "big",
           byte_order: str = "big") -> int | float | str:
    """The value held in `words` (each 0..65535) for a data type and word/byte order; a
    string takes as many words as it is given."""
    if dtype == STRING:
        text = _arrange(words, word_order, byte_order).decode("latin-1")
        return text.rstrip("\x00 ")
    if dtype == BIT:
        if len(words) != 1:
            raise ValueError(f"a bit is one address, got {len(words)}")
        return int(bool(words[0]))
    n, fmt = DATA_TYPES[dtype]
    if len(words) != n:
        raise ValueError(f"{dtype} needs {n} register(s), got {len(words)}")
    return struct.unpack(fmt, _arrange(words, word_order, byte_order))[0]


def encode(value: int | float | str, dtype: str, word_order: str = "big",
           byte_order: str = "big", length: int | None = None) -> list[int]:
    """The words a PLC would hold for `value` (inverse of decode); the simulator uses it.
    A string is padded with NULs to `length` registers (default: just long enough)."""
    if dtype == STRING:
        raw = str(value).encode("latin-1")
        n = (len(raw) + 1) // 2 if length is None else length
        if len(raw) > 2 * n:
            raise ValueError(f"{len(raw)} characters do not fit in {n} register(s)")
        return _words(raw.ljust(2 * n, b"\x00"), word_order, byte_order)
    if dtype == BIT:
        return [int(bool(value))]
    n, fmt = DATA_TYPES[dtype]
    return _words(struct.pack(fmt, value), word_order, byte_order)


def register_count(dtype: str, length: int = 0) -> int:
    """Registers a value of `dtype` occupies (`length` for a string; a bit, one address of
    its bit table)."""
    if dtype == STRING:
        return length
    return 1 if dtype == BIT else DATA_TYPES[dtype][0]


@dataclass(frozen=True)
class Point:
    """One value in a PLC's register map, as an engineer writes it down: a number or text in
    registers, or a number (0 or 1) that is one bit of a coil or discrete input table."""

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
    length: int = 0
    """Registers of a string point (other types have a fixed size)."""
    device: str = ""
    """The device (config `devices:`) this point is read from; "" = the only one."""

    @property
    def count(self) -> int:
        return register_count(self.dtype, self.length)

    def raw(self, words: Sequence[int]) -> int | float | str:
        return decode(words, self.dtype, self.word_order, self.byte_order)

    def value(self, words: Sequence[int]) -> tuple[float | None, str]:
        """(engineering value or None, quality) from this point's words; a string point
        gives its text, always ok."""
        raw = self.raw(words)
        if isinstance(raw, str):
            return raw, OK  # type: ignore[return-value]
        if raw != raw or raw in self.sentinels:  # NaN from a float32 counts as open
            return None, SENSOR_OPEN
        v = raw * self.scale + self.offset
        if (self.lo is not None and v < self.lo) or (self.hi is not None and v > self.hi):
            return None, OUT_OF_RANGE
        return round(float(v), 9), OK  # no 400.70000000000005 in the log


@dataclass(frozen=True)
class BitRange:
    """Consecutive on/off states (one zone's burners) in a bit table (discrete or coil), or
    packed into registers (holding or input) from bit `bit` of register `address` on, bit 0
    the least significant, bit 16 bit 0 of the next register: PLCs that pack burner states
    into a status word."""

    name: str
    table: str
    address: int
    count: int
    invert: bool = False
    bit: int = 0
    device: str = ""
    """As Point.device."""

    @property
    def packed(self) -> bool:
        return self.table in REGISTER_TABLES

    @property
    def width(self) -> int:
        """Addresses occupied: bits in a bit table, registers when packed."""
        return (self.bit + self.count + 15) // 16 if self.packed else self.count

    def states(self, bits: Sequence[int | bool]) -> list[bool]:
        """On/off states from the bits read, or from the registers read when packed."""
        if self.packed:
            bits = unpack_bits(bits, self.bit, self.count)
        return [bool(b) != self.invert for b in bits]


def unpack_bits(words: Sequence[int], bit: int, count: int) -> list[bool]:
    """`count` bits from bit `bit` of `words` on (LSB first, then the next register)."""
    return [bool(words[k // 16] >> (k % 16) & 1) for k in range(bit, bit + count)]


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
    n = item.width if isinstance(item, BitRange) else item.count
    return item.table, item.address, item.address + n


def plan_reads(items: Iterable[Point | BitRange], max_gap_registers: int = 8,
               max_gap_bits: int = 64, max_registers: int = MAX_REGISTERS_PER_READ,
               one_per_item: bool = False, coils_from_zero: bool = False) -> list[ReadRequest]:
    """As few requests as the protocol limits allow: neighbours in one table are merged
    when the hole between them is at most the allowed gap (reading a few unused addresses
    costs less than a round trip), never beyond `max_registers` (at most 125) registers /
    2000 bits per request. Devices that choke on merged reads (Telegraf's
    `optimization = "none"`, or a gateway with a smaller buffer) get one request per item
    or a smaller `max_registers`; an item is never split over two requests. Devices that
    refuse a coil read not starting at address 0 (Telegraf's `read_coils_starting_at_zero`)
    get their first coil request stretched down to 0."""
    by_table: dict[str, list[tuple[int, int]]] = {}
    for item in items:
        table, a, b = span(item)
        by_table.setdefault(table, []).append((a, b))
    out: list[ReadRequest] = []
    for table in TABLES:
        spans = sorted(set(by_table.get(table, [])))
        if not spans:
            continue
        if coils_from_zero and table == "coil":
            spans[0] = (0, spans[0][1])
        if one_per_item:
            out += [ReadRequest(table, a, b - a) for a, b in spans]
            continue
        limit = min(max_registers, MAX_REGISTERS_PER_READ) if table in REGISTER_TABLES \
            else MAX_BITS_PER_READ
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
    """Indices of the first two items that share an address in the same table of the same
    device, if any. Bits packed into one register, and the two bytes of one, overlap only if
    they share a bit."""
    spans = sorted(((getattr(it, "device", ""), *_bit_span(it)), i) for i, it in enumerate(items))
    for ((d1, t1, _a1, b1), i), ((d2, t2, a2, _b2), j) in zip(spans, spans[1:], strict=False):
        if d1 == d2 and t1 == t2 and a2 < b1:
            return min(i, j), max(i, j)
    return None


def _bit_span(item: Point | BitRange) -> tuple[str, int, int]:
    """span() in bits for register tables (16 per register), so packed bit ranges can
    share a register; addresses for bit tables."""
    table, a, b = span(item)
    if table not in REGISTER_TABLES:
        return table, a, b
    if isinstance(item, BitRange):
        start = 16 * a + item.bit
        return table, start, start + item.count
    if item.dtype in BYTE_TYPES:  # the high byte is bits 8-15
        start = 16 * a + (8 if item.dtype.endswith("h") else 0)
        return table, start, start + 8
    return table, 16 * a, 16 * b


class Image:
    """What one scan read: words/bits by table and address, from a set of responses."""

    def __init__(self) -> None:
        self.data: dict[str, dict[int, int]] = {t: {} for t in TABLES}

    def put(self, request: ReadRequest, values: Sequence[int | bool]) -> None:
        table = self.data[request.table]
        for k in range(request.count):
            table[request.address + k] = int(values[k])

    def words(self, item: Point | BitRange) -> list[int] | None:
        """The item's words (its bits; its registers when packed), None if not all read."""
        table, a, b = span(item)
        got = self.data[table]
        if any(k not in got for k in range(a, b)):
            return None
        return [got[k] for k in range(a, b)]
