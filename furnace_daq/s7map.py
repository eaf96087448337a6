"""The map of a Siemens S7 PLC and how it is reached: each item of the daemon's map named
by its S7 address (`DB10.DBD4`, `DB10.DBW0`, `DB10.DBX2.3`, `MW20`, `I0.0`), with the S7
type it holds, and the device's `s7:` settings (rack, slot). Checked at load with key-path
errors, as the register map is; no S7 library is needed to read it.

An address is written as in STEP 7, English or German mnemonics, with or without TIA's
`%`: a data block `DB<n>.DBX<byte>.<bit>`, `DB<n>.DBB<byte>`, `.DBW`, `.DBD`; the inputs
`I` (or `E`), the outputs `Q` (or `A`) and the markers `M`: `I0.3`, `IB2`, `IW4`, `ID8`,
`M5.0`, `MB1`, `MW20`, `MD24`. The width letter (X bit, B byte, W word, D double word) is
how much the address spans; the type says how those bytes read and must fit the width.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import ClassVar

from furnace_model.config import Node

from .scaling import SCALING_KEYS, Scaling, parse_scaling

PROTOCOL = "s7"
ADDRESSING = "an S7 address (s7:)"
"""How an item of this protocol is given in the map, as errors name it."""

AREAS = {"DB": "DB", "I": "I", "E": "I", "Q": "Q", "A": "Q", "M": "M"}
"""Mnemonic -> area (data block, process image of inputs, of outputs, markers)."""
WIDTHS = {"X": 0, "B": 1, "W": 2, "D": 4}
"""Width letter -> bytes (0: one bit)."""
LETTERS = {v: k for k, v in WIDTHS.items()}
TYPES: dict[str, int] = {"bool": 0, "byte": 1, "sint": 1, "word": 2, "uint": 2, "int": 2,
                         "dword": 4, "udint": 4, "dint": 4, "real": 4}
"""S7 type -> the width it needs. byte, word, dword (and uint, udint) read unsigned; sint,
int, dint signed; real is IEEE 754 single precision."""
DEFAULT_TYPES = {0: "bool", 1: "byte", 2: "int", 4: "real"}
"""The type of an address that gives none, by its width."""
MAX_OFFSET = 65535

_ADDRESS = re.compile(r"^%?(?:DB(?P<db>\d+)\.DB(?P<dw>[XBWD])(?P<dbyte>\d+)(?:\.(?P<dbit>\d+))?"
                      r"|(?P<area>[IEQAM])(?P<w>[BWD])?(?P<byte>\d+)(?:\.(?P<bit>\d+))?)$")
_EXAMPLES = "DB10.DBD4, DB10.DBW0, DB10.DBX2.3, MW20, M5.0, IB2, I0.3"


@dataclass(frozen=True)
class S7Address:
    """One place in the PLC's memory: its area (DB, I, Q, M), the data block's number, the
    byte it starts at, and the bit (for a bit address) or the width in bytes."""

    area: str
    db: int
    start: int
    width: int
    """Bytes spanned: 1, 2 or 4; 0 for one bit."""
    bit: int = 0

    @property
    def size(self) -> int:
        """Bytes to read for it."""
        return max(self.width, 1)

    @property
    def text(self) -> str:
        letter = LETTERS[self.width]
        if self.area == "DB":
            head = f"DB{self.db}.DB{letter}{self.start}"
        else:
            head = f"{self.area}{'' if self.width == 0 else letter}{self.start}"
        return f"{head}.{self.bit}" if self.width == 0 else head

    def __str__(self) -> str:
        return self.text

    def next_bit(self) -> S7Address:
        """The bit after this one (the next byte's bit 0 after bit 7)."""
        if self.bit < 7:
            return S7Address(self.area, self.db, self.start, 0, self.bit + 1)
        return S7Address(self.area, self.db, self.start + 1, 0, 0)


def parse_address(text: str) -> S7Address | str:
    """The address `text` names, or why it is none (a sentence for the error)."""
    m = _ADDRESS.match(text.strip().upper())
    if m is None:
        return f"'{text}' is not an S7 address: {_EXAMPLES}"
    if m.group("db") is not None:
        area, db = "DB", int(m.group("db"))
        letter, start, bit = m.group("dw"), int(m.group("dbyte")), m.group("dbit")
        if db < 1 or db > 65535:
            return f"'{text}': data block numbers are 1-65535"
    else:
        area, db = AREAS[m.group("area")], 0
        letter, start, bit = m.group("w") or "X", int(m.group("byte")), m.group("bit")
    width = WIDTHS[letter]
    if width == 0 and bit is None:
        return f"'{text}' is a bit address: give the bit after the byte, e.g. {text}.0"
    if width and bit is not None:
        return (f"'{text}' names a whole {_WIDTH_NAMES[width]}, which has no bit; a bit is "
                f"written {S7Address(area, db, start, 0, min(int(bit), 7)).text}")
    if bit is not None and int(bit) > 7:
        return f"'{text}': a bit is 0-7"
    if start + max(width, 1) - 1 > MAX_OFFSET:
        return f"'{text}': byte offsets run to {MAX_OFFSET}"
    return S7Address(area, db, start, width, int(bit or 0))


def address(node: Node) -> S7Address:
    """An address from the map, checked for its form."""
    got = parse_address(node.string())
    if isinstance(got, str):
        raise node.error(got)
    return got


_WIDTH_NAMES = {0: "bit", 1: "byte", 2: "word (2 bytes)", 4: "double word (4 bytes)"}


def _width_text(a: S7Address) -> str:
    return f"a {_WIDTH_NAMES[a.width]}"


@dataclass(frozen=True)
class S7Point:
    """One value of the map read from an S7 address."""

    protocol: ClassVar[str] = PROTOCOL
    name: str
    address: S7Address
    dtype: str = "real"
    scaling: Scaling = Scaling()
    device: str = ""

    @property
    def addresses(self) -> tuple[S7Address, ...]:
        return (self.address,)

    @property
    def nodes(self) -> tuple[str, ...]:
        """How the item is named where it is read (check's table, errors)."""
        return (self.address.text,)

    @property
    def lo(self) -> float | None:
        return self.scaling.lo

    @property
    def hi(self) -> float | None:
        return self.scaling.hi


@dataclass(frozen=True)
class S7Bits:
    """On/off states (one zone's burners, or a bit signal): `count` bits from a first bit
    address on (DB10.DBX20.0, I0.0: the next bits in order, across bytes), or one bit
    address each."""

    protocol: ClassVar[str] = PROTOCOL
    name: str
    addresses: tuple[S7Address, ...]
    count: int
    invert: bool = False
    device: str = ""
    listed: bool = False
    """Given as a list of addresses rather than a first one."""

    @property
    def nodes(self) -> tuple[str, ...]:
        if self.listed or self.count == 1:
            return tuple(a.text for a in self.addresses)
        return (f"{self.addresses[0].text}-{self.addresses[-1].text}",)

    def states(self, values: list[bool]) -> list[bool]:
        return [bool(v) != self.invert for v in values]


def is_s7_entry(node: Node) -> bool:
    """Whether a map entry names an S7 address (`s7:`) rather than a register or a node."""
    return isinstance(node.value, dict) and "s7" in node.value


def is_s7_bit_entry(node: Node) -> bool:
    """Whether a `signals:` entry is one bit (a bit address, or type bool)."""
    if not is_s7_entry(node):
        return False
    value = node.value["s7"]
    if node.value.get("type") == "bool" or isinstance(value, list):
        return True
    got = parse_address(str(value))
    return isinstance(got, S7Address) and got.width == 0


def s7_point(node: Node, name: str, extra: tuple[str, ...] = (),
             numeric: bool = True) -> S7Point:
    """A map entry `{s7: ADDRESS, type: TYPE, scale, offset, sentinels, range}`; the type
    defaults to the address width's (byte, int, real); the caller sets `device`."""
    node.mapping({"s7", "type", "device", *SCALING_KEYS, *extra})
    where = address(node.child("s7"))
    dtype = node.get_string("type", DEFAULT_TYPES[where.width], choices=tuple(TYPES))
    if dtype == "bool":
        raise node.child("type").error(f"{name} is a number; bool is for burner states and bit "
                                       "signals")
    if TYPES[dtype] != where.width:
        fits = ", ".join(t for t, w in TYPES.items() if w == where.width)
        raise node.child("type").error(
            f"{dtype} takes {TYPES[dtype]} bytes, but {where.text} is {_width_text(where)}, "
            f"which reads as {fits}: give an address of width {LETTERS[TYPES[dtype]]} or one "
            "of those types")
    return S7Point(name, where, dtype, parse_scaling(node))


def s7_bits(node: Node, name: str, n: int, extra: tuple[str, ...] = ()) -> S7Bits:
    """`{s7: FIRST_BIT}` (n bits from there on) or `{s7: [BIT_1, ..., BIT_n]}`, with
    `invert` for active-low states; the caller sets `device`."""
    node.mapping({"s7", "type", "invert", "device", *extra})
    node.get_string("type", "bool", choices=("bool",))
    given = node.child("s7")
    listed = isinstance(given.value, list)
    entries = given.elements() if listed else [given]
    bits = tuple(address(e) for e in entries)
    if listed and len(bits) != n:
        raise given.error(f"{name} has {n} burner(s): expected {n} bit addresses, got "
                          f"{len(bits)}")
    for entry, b in zip(entries, bits, strict=True):
        if b.width != 0:
            raise entry.error(f"{b.text} is {_width_text(b)}: give a bit address, e.g. "
                              f"{S7Address(b.area, b.db, b.start, 0).text}")
    if not listed:
        run = [bits[0]]
        while len(run) < n:
            run.append(run[-1].next_bit())
        if run[-1].start > MAX_OFFSET:
            raise given.error(f"{n} bits from {bits[0].text} run past byte {MAX_OFFSET}")
        bits = tuple(run)
    return S7Bits(name, bits, n, node.get_bool("invert", False), listed=listed)


@dataclass(frozen=True)
class S7Settings:
    """A device's `s7:` section."""

    rack: int = 0
    slot: int = 1
    """Where the CPU sits: S7-1200 and S7-1500 rack 0 slot 1, S7-300 rack 0 slot 2, S7-400
    as configured in the hardware."""
    max_gap_bytes: int = 16
    """Addresses of one area this close together are read in one piece; bytes in between
    are read and discarded. A larger gap costs bytes, a smaller one requests."""


S7_KEYS = ("rack", "slot", "max_gap_bytes")


def parse_s7(node: Node) -> S7Settings:
    """A device's `s7:` section."""
    node.mapping(S7_KEYS)
    return S7Settings(rack=node.get_integer("rack", 0, lo=0, hi=7),
                      slot=node.get_integer("slot", 1, lo=0, hi=31),
                      max_gap_bytes=node.get_integer("max_gap_bytes", 16, lo=0, hi=256))
