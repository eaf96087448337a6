"""Bad input on the wire and in the registers: malformed MBAP frames and random bytes thrown
at the simulated PLC over TCP (it stays up and answers the next client with the right
registers), and register decoding of every data type in every word and byte order, for
any 16-bit words a PLC can send."""

from __future__ import annotations

import asyncio
import math
import socket
import struct
import threading
import time

import pytest
from daq_processes import SCENARIO
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from furnace_daq.registers import BYTE_TYPES, DATA_TYPES, ORDERS, Point, decode, encode
from furnace_daq.simplc import SimPLC
from furnace_model.simulation.scenario import load_scenario

# -- register decoding: every type x word order x byte order --------------------------------

COMBINATIONS = [(t, w, b) for t in DATA_TYPES for w in ORDERS for b in ORDERS]
words16 = st.integers(0, 0xFFFF)


def test_every_type_and_order_is_exercised() -> None:
    """The parametrisation below follows the decoder's own tables: a type or order added
    there is tested here without anyone remembering to."""
    assert len(COMBINATIONS) == len(DATA_TYPES) * 4 and set(ORDERS) == {"big", "little"}


@pytest.mark.parametrize("dtype,word_order,byte_order", COMBINATIONS)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_any_words_decode_and_encode_back(data, dtype, word_order, byte_order) -> None:
    n = DATA_TYPES[dtype][0]
    words = data.draw(st.lists(words16, min_size=n, max_size=n))
    value = decode(words, dtype, word_order, byte_order)
    if dtype.startswith("float") and math.isnan(value):
        assert encode(value, dtype, word_order, byte_order) is not None
        return
    if dtype in BYTE_TYPES:  # one byte of the register: the other is not the point's
        again = encode(value, dtype, word_order, byte_order)
        assert decode(again, dtype, word_order, byte_order) == value
        return
    assert encode(value, dtype, word_order, byte_order) == words


@pytest.mark.parametrize("dtype,word_order,byte_order", COMBINATIONS)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_a_point_never_raises_on_what_the_plc_sends(data, dtype, word_order, byte_order) -> None:
    n = DATA_TYPES[dtype][0]
    words = data.draw(st.lists(words16, min_size=n, max_size=n))
    scale = data.draw(st.sampled_from([0.1, 1.0, 1e30, -2.5]))
    p = Point("soak_1", dtype=dtype, word_order=word_order, byte_order=byte_order, scale=scale,
              offset=-5.0, sentinels=(32767.0,), lo=-50.0, hi=1600.0)
    value, quality = p.value(words)
    if value is None:
        assert quality != "ok"
    else:
        assert quality == "ok" and math.isfinite(value) and -50.0 <= value <= 1600.0


@pytest.mark.parametrize("dtype", list(DATA_TYPES))
def test_wrong_word_count_is_a_clear_error(dtype: str) -> None:
    n = DATA_TYPES[dtype][0]
    for count in (0, n + 1):
        with pytest.raises(ValueError, match=f"{dtype} needs {n} register"):
            decode([0] * count, dtype)


# -- the simulated PLC under hostile clients -------------------------------------------------

READ_IR = 4


class ThreadedSimPLC:
    """The simulated PLC on its own event loop, frozen so its registers hold still and every
    correct read must return exactly the same words."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.plc = SimPLC(load_scenario(SCENARIO), speed=600, port=0, scan_s=0.05)

    def __enter__(self) -> ThreadedSimPLC:
        self.thread.start()
        asyncio.run_coroutine_threadsafe(self.plc.start(), self.loop).result(20)
        self.plc.frozen = True
        return self

    def __exit__(self, *exc: object) -> None:
        asyncio.run_coroutine_threadsafe(self.plc.stop(), self.loop).result(20)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


def mbap(pdu: bytes, tid: int = 1, unit: int = 1, protocol: int = 0,
         length: int | None = None) -> bytes:
    return struct.pack(">HHHB", tid, protocol, len(pdu) + 1 if length is None else length,
                       unit) + pdu


def read_input_registers(port: int, address: int = 0, count: int = 10) -> list[int]:
    """A correct client: one FC4 request on a fresh connection, the answer checked."""
    with socket.create_connection(("127.0.0.1", port), timeout=3) as s:
        s.sendall(mbap(struct.pack(">BHH", READ_IR, address, count), tid=0x4242))
        head = _recv(s, 7)
        tid, proto, length, _unit = struct.unpack(">HHHB", head)
        body = _recv(s, length - 1)
    assert (tid, proto) == (0x4242, 0) and body[0] == READ_IR and body[1] == 2 * count, body
    return list(struct.unpack(f">{count}H", body[2:]))


def _recv(s: socket.socket, n: int) -> bytes:
    out = b""
    while len(out) < n:
        chunk = s.recv(n - len(out))
        if not chunk:
            raise ConnectionError(f"closed after {len(out)} of {n} bytes")
        out += chunk
    return out


def throw(port: int, data: bytes, linger_s: float = 0.0) -> None:
    """Send bytes on a fresh connection, read whatever comes back for a moment, close."""
    with socket.create_connection(("127.0.0.1", port), timeout=3) as s:
        try:
            s.sendall(data)
            s.settimeout(linger_s or 0.05)
            while s.recv(4096):
                pass
        except (TimeoutError, ConnectionError):
            pass


MALFORMED = {
    "length zero": mbap(b"", length=0),
    "length one, no pdu": mbap(b"", length=1),
    "length beyond the body": mbap(struct.pack(">BHH", 4, 0, 10), length=250),
    "length 65535": mbap(b"\x04", length=0xFFFF),
    "protocol id not zero": mbap(struct.pack(">BHH", 4, 0, 10), protocol=0xFFFF),
    "unknown function 0": mbap(b"\x00\x00\x00\x00\x01"),
    "unknown function 0x7f": mbap(b"\x7f" + bytes(10)),
    "exception-coded function": mbap(b"\x84\x00\x00\x00\x01"),
    "encapsulated interface": mbap(b"\x2b\x0e\x01\x00"),
    "read zero registers": mbap(struct.pack(">BHH", 4, 0, 0)),
    "read 126 registers": mbap(struct.pack(">BHH", 4, 0, 126)),
    "read 65535 registers": mbap(struct.pack(">BHH", 4, 0, 0xFFFF)),
    "read past the end": mbap(struct.pack(">BHH", 4, 0xFFFF, 10)),
    "read 2001 bits": mbap(struct.pack(">BHH", 2, 0, 2001)),
    "read with no count": mbap(b"\x04\x00\x00"),
    "write coil bad value": mbap(struct.pack(">BHH", 5, 0, 0x1234)),
    "write multiple, byte count lies": mbap(struct.pack(">BHHB", 16, 0, 2, 200) + b"\x00\x01"),
    "write multiple coils, byte count lies": mbap(struct.pack(">BHHB", 15, 0, 26, 1) + b"\xff"),
    "write 123 registers": mbap(struct.pack(">BHHB", 16, 0, 123, 246) + bytes(246)),
    "other unit id": mbap(struct.pack(">BHH", 4, 0, 10), unit=0xF7),
    "half a header": b"\x00\x01\x00",
    "two frames and garbage in one write": (mbap(struct.pack(">BHH", 4, 0, 10)) + b"\xde\xad"
                                            + mbap(struct.pack(">BHH", 4, 0, 10), tid=2)),
    "text": b"GET / HTTP/1.1\r\nHost: plc\r\n\r\n",
    "tls client hello": bytes.fromhex("160301002e010000")[:8] + bytes(40),
    "a megabyte of 0xff": b"\xff" * (1 << 20),
}


@pytest.fixture(scope="module")
def plc():
    with ThreadedSimPLC() as sim:
        yield sim


@pytest.fixture(scope="module")
def baseline(plc) -> list[int]:
    return read_input_registers(plc.plc.port)


@pytest.mark.parametrize("name", list(MALFORMED))
def test_malformed_frames_leave_the_plc_answering(plc, baseline, name: str) -> None:
    throw(plc.plc.port, MALFORMED[name])
    assert read_input_registers(plc.plc.port) == baseline


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(junk=st.binary(min_size=1, max_size=600))
def test_random_bytes_leave_the_plc_answering(plc, baseline, junk: bytes) -> None:
    throw(plc.plc.port, junk)
    assert read_input_registers(plc.plc.port) == baseline


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(fc=st.integers(0, 255), body=st.binary(max_size=260), unit=st.integers(0, 255),
       length_delta=st.integers(-3, 3))
def test_random_mbap_frames_leave_the_plc_answering(plc, baseline, fc, body, unit,
                                                     length_delta) -> None:
    pdu = bytes([fc]) + body
    if fc in (5, 6, 15, 16):  # a write: the registers read below are inputs, never written
        pdu = pdu[:1] + b"\x00\x00" + pdu[3:]
    throw(plc.plc.port, mbap(pdu, unit=unit, length=max(0, len(pdu) + 1 + length_delta)))
    assert read_input_registers(plc.plc.port) == baseline


def test_stuck_and_slow_clients_do_not_block_others(plc, baseline) -> None:
    """Half a frame left hanging, and a client dribbling one byte at a time: the server
    serves a correct client meanwhile."""
    stuck = [socket.create_connection(("127.0.0.1", plc.plc.port), timeout=3) for _ in range(20)]
    try:
        for i, s in enumerate(stuck):
            s.sendall(mbap(b"\x04", length=0xFFFF)[: 1 + i % 7])
        slow = socket.create_connection(("127.0.0.1", plc.plc.port), timeout=3)
        frame = mbap(struct.pack(">BHH", 4, 0, 10))
        t0 = time.monotonic()
        for k, byte in enumerate(frame[:-1]):
            slow.sendall(bytes([byte]))
            if k % 3 == 0:
                assert read_input_registers(plc.plc.port) == baseline
        slow.sendall(frame[-1:])
        slow.settimeout(3)
        assert slow.recv(7)[:2] == b"\x00\x01"  # the dribbled request is answered too
        slow.close()
        assert time.monotonic() - t0 < 30
    finally:
        for s in stuck:
            s.close()
    assert read_input_registers(plc.plc.port) == baseline
