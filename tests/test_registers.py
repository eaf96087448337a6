"""Register decoding: every data type in every word and byte order, against an independent
encoder (struct on the natural byte string), plus the read plan's protocol limits."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from furnace_daq.registers import (
    COMM_ERROR,
    DATA_TYPES,
    MAX_BITS_PER_READ,
    MAX_REGISTERS_PER_READ,
    OK,
    OUT_OF_RANGE,
    SENSOR_OPEN,
    TELEGRAF_ORDERS,
    BitRange,
    Image,
    Point,
    ReadRequest,
    decode,
    encode,
    integer_range,
    overlaps,
    plan_reads,
    unpack_bits,
)

RANGES = {"int16": (-2**15, 2**15 - 1), "uint16": (0, 2**16 - 1),
          "int32": (-2**31, 2**31 - 1), "uint32": (0, 2**32 - 1)}
FORMATS = {"int16": "h", "uint16": "H", "int32": "i", "uint32": "I", "float32": "f"}
orders = st.sampled_from(["big", "little"])


def plc_words(value, dtype: str, word_order: str, byte_order: str) -> list[int]:
    """How a PLC lays the value out, written the other way round from the decoder: build the
    little-endian byte string and pick bytes by position."""
    le = struct.pack("<" + FORMATS[dtype], value)  # le[0] = least significant byte
    n = len(le) // 2
    regs = []  # register k holds bytes 2k (low) and 2k+1 (high) of the little-endian string
    for k in range(n):
        lo, hi = le[2 * k], le[2 * k + 1]
        regs.append(hi << 8 | lo if byte_order == "big" else lo << 8 | hi)
    return regs[::-1] if word_order == "big" else regs  # big: most significant register first


@st.composite
def typed_values(draw):
    dtype = draw(st.sampled_from(list(FORMATS)))
    if dtype == "float32":
        value = draw(st.floats(width=32, allow_nan=False))
    else:
        value = draw(st.integers(*RANGES[dtype]))
    return dtype, value


@given(typed_values(), orders, orders)
def test_decode_matches_an_independent_layout(tv, word_order, byte_order):
    dtype, value = tv
    words = plc_words(value, dtype, word_order, byte_order)
    assert all(0 <= w <= 0xFFFF for w in words)
    assert decode(words, dtype, word_order, byte_order) == value
    assert encode(value, dtype, word_order, byte_order) == words


@given(typed_values(), orders, orders)
def test_wrong_order_changes_the_value_unless_symmetric(tv, word_order, byte_order):
    dtype, value = tv
    words = plc_words(value, dtype, word_order, byte_order)
    other = "little" if byte_order == "big" else "big"
    swapped = decode(words, dtype, word_order, other)
    same_bytes = all((w >> 8) == (w & 0xFF) for w in words)
    assert (swapped == value) == same_bytes or (dtype == "float32" and value == 0.0)


def test_known_layouts():
    # 0x12345678 as a big-endian PLC and as a word-swapped (Schneider-style) one
    assert decode([0x1234, 0x5678], "uint32", "big") == 0x12345678
    assert decode([0x5678, 0x1234], "uint32", "little") == 0x12345678
    assert decode([0x3412, 0x7856], "uint32", "big", "little") == 0x12345678
    assert decode([0xFFFF], "int16") == -1
    assert decode([0x3F80, 0x0000], "float32") == 1.0
    with pytest.raises(ValueError):
        decode([1], "float32")


@given(st.integers(-2**15, 2**15 - 1))
def test_point_quality(raw):
    p = Point("soak_1", scale=0.1, sentinels=(32767,), lo=-50.0, hi=1600.0)
    value, quality = p.value(encode(raw, "int16"))
    if raw == 32767:
        assert (value, quality) == (None, SENSOR_OPEN)
    elif -500 <= raw <= 16000:
        assert quality == OK and math.isclose(value, raw * 0.1, abs_tol=1e-9)
    else:
        assert (value, quality) == (None, OUT_OF_RANGE)


def test_float_nan_is_an_open_sensor_and_offset_applies():
    p = Point("x", dtype="float32", scale=2.0, offset=-273.15)
    assert p.value(encode(float("nan"), "float32"))[1] == SENSOR_OPEN
    assert p.value(encode(300.0, "float32")) == (pytest.approx(326.85), OK)


spans = st.lists(st.tuples(st.sampled_from(["input", "holding", "discrete", "coil"]),
                           st.integers(0, 3000), st.sampled_from(["int16", "uint32"])),
                 min_size=1, max_size=40)


@given(spans, st.integers(0, 130), st.integers(0, 2100))
def test_plan_covers_everything_within_limits(items, gap_r, gap_b):
    objs = [BitRange(f"b{i}", t, a, 10) if t in ("discrete", "coil")
            else Point(f"p{i}", t, a, d) for i, (t, a, d) in enumerate(items)]
    plan = plan_reads(objs, gap_r, gap_b)
    for o in objs:
        assert any(r.table == o.table and r.address <= o.address and o.address + o.count <= r.end
                   for r in plan), o
    for r in plan:
        limit = MAX_BITS_PER_READ if r.table in ("discrete", "coil") else MAX_REGISTERS_PER_READ
        assert 1 <= r.count <= limit
    tables = {o.table for o in objs}
    assert len(plan) >= len(tables)


def test_plan_merges_within_gap_and_splits_beyond():
    pts = [Point("a", "input", 0), Point("b", "input", 5), Point("c", "input", 20)]
    assert plan_reads(pts, max_gap_registers=3) == [ReadRequest("input", 0, 1),
                                                    ReadRequest("input", 5, 1),
                                                    ReadRequest("input", 20, 1)]
    assert plan_reads(pts, max_gap_registers=14) == [ReadRequest("input", 0, 21)]
    assert plan_reads(pts, max_gap_registers=4)[0] == ReadRequest("input", 0, 6)  # hole of 4
    far = [Point("a", "holding", 0), Point("b", "holding", 124, "uint32")]
    assert len(plan_reads(far, max_gap_registers=200)) == 2  # 126 registers > 125


def test_overlaps_and_image():
    a, b = Point("a", "input", 7, "uint32"), Point("b", "input", 8)
    assert overlaps([a, b]) == (0, 1)
    assert overlaps([a, Point("b", "holding", 8)]) is None
    img = Image()
    img.put(ReadRequest("input", 7, 2), [1, 2])
    assert img.words(a) == [1, 2] and img.words(Point("c", "input", 9)) is None
    assert COMM_ERROR == "comm_error"


# -- the wider types, Telegraf's byte-order names, strings and bits packed in registers -----

FORMATS64 = {**FORMATS, "int64": "q", "uint64": "Q", "float64": "d", "float16": "e"}
RANGES64 = {**RANGES, "int64": (-2**63, 2**63 - 1), "uint64": (0, 2**64 - 1)}
FLOAT_WIDTH = {"float16": 16, "float32": 32, "float64": 64}


def plc_words_any(value, dtype: str, word_order: str, byte_order: str) -> list[int]:
    le = struct.pack("<" + FORMATS64[dtype], value)
    regs = []
    for k in range(len(le) // 2):
        lo, hi = le[2 * k], le[2 * k + 1]
        regs.append(hi << 8 | lo if byte_order == "big" else lo << 8 | hi)
    return regs[::-1] if word_order == "big" else regs


@st.composite
def any_typed_values(draw):
    dtype = draw(st.sampled_from(list(FORMATS64)))
    if dtype in FLOAT_WIDTH:
        return dtype, draw(st.floats(width=FLOAT_WIDTH[dtype], allow_nan=False))
    return dtype, draw(st.integers(*RANGES64[dtype]))


telegraf = st.sampled_from(sorted(TELEGRAF_ORDERS))


@given(any_typed_values(), telegraf)
def test_every_type_round_trips_in_every_telegraf_order(tv, name):
    dtype, value = tv
    word_order, byte_order = TELEGRAF_ORDERS[name]
    words = plc_words_any(value, dtype, word_order, byte_order)
    assert decode(words, dtype, word_order, byte_order) == value
    assert encode(value, dtype, word_order, byte_order) == words


def test_telegraf_names_against_the_byte_letters():
    # 0x0102030405060708 as uint64, and 0x01020304 as uint32, in each named layout
    cases64 = {"ABCDEFGH": [0x0102, 0x0304, 0x0506, 0x0708],
               "HGFEDCBA": [0x0807, 0x0605, 0x0403, 0x0201],
               "BADCFEHG": [0x0201, 0x0403, 0x0605, 0x0807],
               "GHEFCDAB": [0x0708, 0x0506, 0x0304, 0x0102]}
    for name, words in cases64.items():
        assert decode(words, "uint64", *TELEGRAF_ORDERS[name]) == 0x0102030405060708, name
    cases32 = {"ABCD": [0x0102, 0x0304], "DCBA": [0x0403, 0x0201],
               "BADC": [0x0201, 0x0403], "CDAB": [0x0304, 0x0102]}
    for name, words in cases32.items():
        assert decode(words, "uint32", *TELEGRAF_ORDERS[name]) == 0x01020304, name
    assert decode([0x0201], "uint16", *TELEGRAF_ORDERS["BA"]) == 0x0102
    assert decode([0x3C00], "float16") == 1.0
    assert decode([0x3FF0, 0, 0, 0], "float64") == 1.0


text = st.text(st.characters(min_codepoint=0x21, max_codepoint=0xFF), max_size=12)


@given(text, st.integers(6, 10), telegraf)
def test_strings_round_trip_without_their_padding(s, n, name):
    word_order, byte_order = TELEGRAF_ORDERS[name]
    words = encode(s, "string", word_order, byte_order, length=n)
    assert len(words) == n and all(0 <= w <= 0xFFFF for w in words)
    assert decode(words, "string", word_order, byte_order) == s
    padded = encode(s + " " * (n % 2 + 1), "string", word_order, byte_order, length=n + 1)
    assert decode(padded, "string", word_order, byte_order) == s
    p = Point("tag", dtype="string", length=n, word_order=word_order, byte_order=byte_order)
    assert p.count == n and p.value(words) == (s, OK)


def test_string_layout_and_overflow():
    assert decode([0x4142, 0x4300], "string") == "ABC"
    assert decode([0x4241, 0x0043], "string", "big", "little") == "ABC"
    with pytest.raises(ValueError, match="do not fit"):
        encode("ABCDE", "string", length=2)


@given(st.lists(st.booleans(), min_size=1, max_size=40), st.integers(0, 15), st.booleans())
def test_packed_bits_round_trip(states, bit, invert):
    n = len(states)
    item = BitRange("soak", "holding", 3, n, invert=invert, bit=bit)
    words = [0] * item.width
    for k, on in enumerate(states):
        if on != invert:
            words[(bit + k) // 16] |= 1 << ((bit + k) % 16)
    assert item.states(words) == states
    assert unpack_bits(words, bit, n) == [s != invert for s in states]
    img = Image()
    img.put(ReadRequest("holding", 3, item.width), words)
    assert img.words(item) == words


def test_packed_bit_ranges_share_a_register_without_overlapping():
    soak = BitRange("soak", "input", 20, 10, bit=0)
    heat = BitRange("heat", "input", 20, 8, bit=10)  # bits 10-15 of 20, 0-1 of 21
    pre = BitRange("preheat", "input", 21, 8, bit=2)
    assert heat.width == 2 and overlaps([soak, heat, pre]) is None
    assert overlaps([soak, BitRange("x", "input", 20, 1, bit=9)]) == (0, 1)
    assert overlaps([soak, Point("t", "input", 20)]) == (0, 1)
    plan = plan_reads([soak, heat, pre])
    assert plan == [ReadRequest("input", 20, 2)]
    # the same addresses on two devices are two PLCs, not a slip
    assert overlaps([Point("a", "input", 0, device="x"), Point("b", "input", 0, device="y")]) \
        is None


def test_plan_one_request_per_item_and_a_smaller_limit():
    pts = [Point("a", "input", 0), Point("b", "input", 1, "float64"), Point("c", "input", 5)]
    assert plan_reads(pts, one_per_item=True) == [
        ReadRequest("input", 0, 1), ReadRequest("input", 1, 4), ReadRequest("input", 5, 1)]
    assert plan_reads(pts, max_registers=5) == [ReadRequest("input", 0, 5),
                                                ReadRequest("input", 5, 1)]
    assert plan_reads(pts, max_registers=200) == [ReadRequest("input", 0, 6)]


@pytest.mark.parametrize("dtype", sorted(DATA_TYPES))
def test_integer_range_is_what_the_type_encodes(dtype):
    """Every integer type's ends encode and decode to themselves and one beyond them does not
    encode; a floating-point type has no integer range."""
    span = integer_range(dtype)
    if dtype.startswith("float"):
        assert span is None
        return
    lo, hi = span
    for v in (lo, hi):
        assert decode(encode(v, dtype), dtype) == v
    for v in (lo - 1, hi + 1):
        with pytest.raises(struct.error):
            encode(v, dtype)
