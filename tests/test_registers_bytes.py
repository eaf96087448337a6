"""The byte types (Telegraf's INT8L, INT8H, UINT8L, UINT8H), strings and bits as map points,
and the coil plan of `read_coils_starting_at_zero`: pure decoding and planning, against an
independent layout."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from furnace_daq.registers import (
    BIT,
    BYTE_TYPES,
    MAX_BITS_PER_READ,
    OK,
    BitRange,
    Point,
    ReadRequest,
    decode,
    encode,
    integer_range,
    plan_reads,
)

orders = st.sampled_from(["big", "little"])


@given(hi=st.integers(0, 255), lo=st.integers(0, 255), byte_order=orders)
def test_byte_types_pick_their_byte_of_the_register(hi, lo, byte_order):
    """A register holding bytes (hi, lo) on the wire: H is the first byte, L the second, and
    byte_order little swaps them first (Telegraf's DCBA)."""
    word = hi << 8 | lo
    first, second = (hi, lo) if byte_order == "big" else (lo, hi)
    signed = {b: b - 256 if b > 127 else b for b in (hi, lo)}
    assert decode([word], "uint8h", byte_order=byte_order) == first
    assert decode([word], "uint8l", byte_order=byte_order) == second
    assert decode([word], "int8h", byte_order=byte_order) == signed[first]
    assert decode([word], "int8l", byte_order=byte_order) == signed[second]


@pytest.mark.parametrize("dtype, lo, hi", [("int8h", -128, 127), ("int8l", -128, 127),
                                           ("uint8h", 0, 255), ("uint8l", 0, 255)])
def test_byte_types_range_and_round_trip(dtype, lo, hi):
    assert dtype in BYTE_TYPES and integer_range(dtype) == (lo, hi)
    for v in (lo, -1 if lo else 1, 0, hi):
        for order in ("big", "little"):
            words = encode(v, dtype, byte_order=order)
            assert len(words) == 1 and decode(words, dtype, byte_order=order) == v


def test_two_bytes_of_one_register_are_two_points():
    """A status register whose high byte is a mode and low byte a signed trim, as one PLC
    exports them."""
    word = 0x03FE  # mode 3, trim -2
    mode = Point("mode", "holding", 40, "uint8h")
    trim = Point("trim", "holding", 40, "int8l", scale=0.5)
    assert mode.value([word]) == (3.0, OK)
    assert trim.value([word]) == (-1.0, OK)


@given(text=st.text(st.characters(min_codepoint=33, max_codepoint=126), min_size=1,
                    max_size=16), byte_order=orders, word_order=orders)
def test_a_string_point_is_text_in_any_order(text, byte_order, word_order):
    n = (len(text) + 1) // 2 + 1
    p = Point("recipe", "holding", 0, "string", word_order, byte_order, length=n)
    assert p.value(encode(text, "string", word_order, byte_order, n)) == (text, OK)


def test_a_bit_point_is_zero_or_one_scaled():
    door = Point("door", "discrete", 7, BIT)
    assert door.count == 1
    assert [door.value([b]) for b in (0, 1)] == [(0.0, OK), (1.0, OK)]
    charging = Point("charging", "coil", 3, BIT, scale=120.0)  # 120 t/h while the bit is on
    assert charging.value([1]) == (120.0, OK)


def test_coils_from_zero_stretch_the_first_coil_request_only():
    items = [BitRange("a", "coil", 10, 4), BitRange("b", "coil", 300, 2),
             BitRange("c", "discrete", 10, 4), Point("t", "input", 5)]
    plain = plan_reads(items)
    assert ReadRequest("coil", 10, 4) in plain and ReadRequest("discrete", 10, 4) in plain
    fixed = plan_reads(items, coils_from_zero=True)
    assert ReadRequest("coil", 0, 14) in fixed and ReadRequest("coil", 300, 2) in fixed
    assert ReadRequest("discrete", 10, 4) in fixed  # discrete inputs are not coils
    one = plan_reads(items, one_per_item=True, coils_from_zero=True)
    assert [r for r in one if r.table == "coil"] == [ReadRequest("coil", 0, 14),
                                                    ReadRequest("coil", 300, 2)]


@given(first=st.integers(0, MAX_BITS_PER_READ - 8), gap=st.integers(0, 200))
def test_coils_from_zero_stay_within_the_protocol_limit(first, gap):
    items = [BitRange("a", "coil", first, 8), BitRange("b", "coil", first + 8 + gap, 8)]
    plan = plan_reads(items, coils_from_zero=True)
    assert plan[0].address == 0 and all(r.count <= MAX_BITS_PER_READ for r in plan)
    covered = {a for r in plan for a in range(r.address, r.end)}
    assert all(a in covered for it in items for a in range(it.address, it.address + 8))
