"""A Siemens S7 PLC as a source (python-snap7's asyncio client, ISO on TCP): the map's
addresses read in as few requests as the PLC's PDU allows, decoded into the same `Sample`
as a Modbus PLC's.

The addresses of one area (a data block, the inputs, the outputs, the markers) that lie
close together are read as one piece (`S7Block`); the pieces go out several to one request
(the S7 protocol's read of several variables), as many as fit the PDU size the PLC
agreed on at connection. The PLC answers each piece with its own return code, so a data
block it has not got (a program download that dropped it, a typo in the map) makes only
that piece's items comm_error, named with the PLC's reason, while the other items stay ok.

The connection is the daemon's, as for Modbus: snap7 has no reconnect of its own here,
so every loss and redial shows on /daq/status and follows the device's backoff.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import struct
from collections.abc import Sequence
from dataclasses import dataclass

from snap7 import AsyncClient
from snap7.error import S7ConnectionError, S7Error, S7TimeoutError
from snap7.s7protocol import get_return_code_description
from snap7.util import (
    get_bool,
    get_byte,
    get_dint,
    get_dword,
    get_int,
    get_real,
    get_sint,
    get_udint,
    get_uint,
    get_word,
)

from .daqconfig import DaqConfig
from .deviceconfig import PlcConfig
from .itemsample import Reading, build_sample
from .registers import COMM_ERROR, OK
from .s7map import S7Address, S7Bits, S7Point, S7Settings
from .sources import Sample, Source, SourceError, failure_kind

for _name in ("snap7", "s7"):
    # Connection trouble is the daemon's to report, once and rate-limited.
    logging.getLogger(_name).setLevel(logging.CRITICAL)

AREA_CODES = {"I": 0x81, "Q": 0x82, "M": 0x83, "DB": 0x84}
"""The S7 protocol's code of each area."""
MAX_ITEMS = 20
"""Pieces in one request at most: what S7-300/400 CPUs accept."""
SUCCESS = 0xFF
GETTERS = {"byte": get_byte, "sint": get_sint, "word": get_word, "uint": get_uint,
           "int": get_int, "dword": get_dword, "udint": get_udint, "dint": get_dint,
           "real": get_real}


@dataclass(frozen=True)
class S7Block:
    """Consecutive bytes of one area, read as one piece."""

    area: str
    db: int
    start: int
    size: int

    @property
    def end(self) -> int:
        return self.start + self.size

    @property
    def text(self) -> str:
        where = f"DB{self.db}" if self.area == "DB" else self.area
        return f"{where} bytes {self.start}-{self.end - 1}"

    def holds(self, a: S7Address) -> bool:
        return a.area == self.area and a.db == self.db and \
            self.start <= a.start and a.start + a.size <= self.end


def plan_blocks(addresses: Sequence[S7Address], max_gap: int, max_size: int) -> list[S7Block]:
    """The pieces that cover `addresses`: per area, addresses at most `max_gap` bytes apart
    joined, none longer than `max_size` bytes."""
    blocks: list[S7Block] = []
    for a in sorted(addresses, key=lambda a: (a.area, a.db, a.start)):
        last = blocks[-1] if blocks else None
        end = a.start + a.size
        if last is not None and last.area == a.area and last.db == a.db \
                and a.start - last.end <= max_gap and max(end, last.end) - last.start <= max_size:
            blocks[-1] = S7Block(a.area, a.db, last.start, max(end, last.end) - last.start)
        else:
            blocks.append(S7Block(a.area, a.db, a.start, a.size))
    return blocks


def plan_requests(blocks: Sequence[S7Block], pdu: int) -> list[list[S7Block]]:
    """The pieces packed into requests: a request of k pieces takes 14 + 12 k bytes, its
    reply 14 + the pieces' data with 4 bytes of header each (and a fill byte after an odd
    one), and both must fit the PDU; at most MAX_ITEMS pieces each."""
    requests: list[list[S7Block]] = []
    asked = answered = 0
    for b in blocks:
        cost = 4 + b.size + b.size % 2
        if not requests or len(requests[-1]) >= MAX_ITEMS or asked + 12 > pdu \
                or answered + cost > pdu:
            requests.append([])
            asked = answered = 14
        requests[-1].append(b)
        asked += 12
        answered += cost
    return requests


def parse_reply(raw: bytes, count: int) -> list[bytes | int]:
    """Each piece of a read's reply: its bytes, or the return code the PLC refused it with."""
    out: list[bytes | int] = []
    offset = 0
    for k in range(count):
        if offset + 4 > len(raw):
            raise SourceError(f"reply truncated at piece {k + 1} of {count}", "malformed reply")
        code, transport, length = raw[offset], raw[offset + 1], \
            struct.unpack(">H", raw[offset + 2:offset + 4])[0]
        offset += 4
        if code != SUCCESS:
            out.append(code)
            continue
        size = length // 8 if transport in (0x03, 0x04, 0x05) else length
        if offset + size > len(raw):
            raise SourceError(f"reply truncated in piece {k + 1} of {count}", "malformed reply")
        out.append(bytes(raw[offset:offset + size]))
        offset += size + (size % 2 if k < count - 1 else 0)
    return out


def refusal_text(block: S7Block, code: int) -> str:
    """'DB12 bytes 0-3: object does not exist (return code 0x0A)'."""
    return f"{block.text}: {get_return_code_description(code).lower()} (return code " \
           f"0x{code:02X})"


def connect_failure(exc: BaseException) -> tuple[str, str]:
    """(kind, why) of a failed dial: the socket's failure as Modbus names it (snap7 wraps it
    in its own error), no answer in time, or a PLC that took the TCP connection and refused
    the ISO or S7 session (wrong rack or slot, no free connection)."""
    if isinstance(exc, TimeoutError | S7TimeoutError):
        return "connect timeout", "no answer"
    cause: BaseException | None = exc
    while cause is not None:
        if isinstance(cause, OSError):
            return failure_kind(cause), cause.strerror or str(cause)
        cause = cause.__cause__ or cause.__context__
    return "session refused", str(exc) or type(exc).__name__


class S7Source(Source):
    """One S7 CPU (S7-300/400/1200/1500; a 1200 or 1500 with PUT/GET access allowed and
    the data blocks read not optimized)."""

    name = "s7"

    def __init__(self, config: DaqConfig, host: str | None = None, port: int | None = None,
                 device: PlcConfig | None = None, items: list | None = None):
        self.config = config
        self.device = device if device is not None else config.devices[0]
        self.host = host or self.device.host
        self.port = port or self.device.port
        self.settings = self.device.s7 or S7Settings()
        self.items: list[S7Point | S7Bits] = items if items is not None \
            else config.device_items(self.device)
        self.addresses: tuple[S7Address, ...] = tuple(dict.fromkeys(
            a for it in self.items for a in it.addresses))
        """Every address of the map on this device, once, in the order of the config."""
        self.pdu = 240
        """The PDU size agreed at connection (240, the least any S7 CPU offers, before)."""
        self.requests = self._plan()
        self._client: AsyncClient | None = None

    def _plan(self) -> list[list[S7Block]]:
        # a piece alone in a reply: 12 header + 2 parameter + 4 piece header
        blocks = plan_blocks(self.addresses, self.settings.max_gap_bytes, self.pdu - 18)
        return plan_requests(blocks, self.pdu)

    # -- where -----------------------------------------------------------------------------
    @property
    def where(self) -> str:
        return f"{self.host}:{self.port}"

    @property
    def transport_text(self) -> str:
        return f"S7 {self.where} rack {self.settings.rack} slot {self.settings.slot}"

    @property
    def plan_text(self) -> str:
        """What one read covers, as `furnace-daq check` says it (after connecting: the
        plan follows the PDU size the PLC agreed on)."""
        pieces = sum(len(r) for r in self.requests)
        return f"{len(self.addresses)} address(es) in {pieces} piece(s), " \
               f"{len(self.requests)} request(s) of PDU {self.pdu} bytes"

    @property
    def connected(self) -> bool:
        return self._client is not None and self._client.get_connected()

    # -- connection ------------------------------------------------------------------------
    async def connect(self) -> None:
        await self.close()
        client = AsyncClient()
        s = self.settings
        try:
            await asyncio.wait_for(client.connect(self.host, s.rack, s.slot,
                                                  tcp_port=self.port), self.device.timeout_s)
        except (TimeoutError, OSError, S7Error) as exc:
            await _quietly_disconnect(client)
            kind, why = connect_failure(exc)
            raise SourceError(f"cannot connect to {self.where}: {why}", kind) from None
        if client.connection is not None:  # a reply the PLC owes times out with the read
            client.connection.timeout = self.device.timeout_s
        self._client = client
        self.pdu = client.pdu_length
        self.requests = self._plan()

    async def close(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            await _quietly_disconnect(client)

    # -- reading ---------------------------------------------------------------------------
    async def read_blocks(self) -> dict[S7Block, bytes | int]:
        """Each piece of the plan: its bytes, or the return code the PLC refused it with.
        Raises SourceError when the connection fails. The read is bounded by nine tenths of
        the timeout, so that a slow PLC is named here rather than cut off by the daemon's
        budget."""
        client = self._client
        if client is None or not client.get_connected():
            raise SourceError(f"{self.where}: connection lost", "connection lost")
        budget = 0.9 * self.device.timeout_s
        try:
            return await asyncio.wait_for(self._read_all(client), budget)
        except TimeoutError:
            n = sum(len(r) for r in self.requests)
            raise SourceError(f"read of {n} piece(s) at {self.where}: no answer within "
                              f"{budget:.3g} s", "poll timeout") from None
        except S7ConnectionError as exc:
            raise SourceError(f"{self.where}: {exc or 'connection lost'}",
                              "connection lost") from None
        except S7Error as exc:
            raise SourceError(f"{self.where}: {exc}", "malformed reply") from None

    async def _read_all(self, client: AsyncClient) -> dict[S7Block, bytes | int]:
        out: dict[S7Block, bytes | int] = {}
        for request in self.requests:
            pdu = client.protocol.build_multi_read_request(
                [(AREA_CODES[b.area], b.db, b.start, b.size) for b in request])
            reply = await client._send_receive(pdu)
            raw = reply.get("raw_data", b"")
            for block, got in zip(request, parse_reply(raw, len(request)), strict=True):
                if isinstance(got, bytes) and len(got) != block.size:
                    raise SourceError(f"{block.text}: {len(got)} byte(s) in the reply",
                                      "short response")
                out[block] = got
        return out

    async def read(self) -> Sample:
        return self.sample(await self.read_blocks())

    def sample(self, blocks: dict[S7Block, bytes | int]) -> Sample:
        """The sample of one read: each item's reading from its address(es)."""
        got = {it.name: _reading(it, blocks) for it in self.items}
        return build_sample(self.config, self.items, got)


def _reading(item: S7Point | S7Bits, blocks: dict[S7Block, bytes | int]) -> Reading:
    """An item's reading: one address's number, or the states of its bits."""
    values: list[float | int | bool] = []
    for a in item.addresses:
        block = next((b for b in blocks if b.holds(a)), None)
        if block is None:
            return Reading(None, COMM_ERROR, f"{a.text}: not read")
        data = blocks[block]
        if isinstance(data, int):
            return Reading(None, COMM_ERROR, refusal_text(block, data))
        offset = a.start - block.start
        if isinstance(item, S7Bits):
            values.append(get_bool(bytearray(data), offset, a.bit))
        else:
            values.append(GETTERS[item.dtype](bytearray(data), offset))
    if isinstance(item, S7Bits):
        return Reading(values if item.count > 1 else values[0], OK)
    return Reading(values[0], OK)


async def _quietly_disconnect(client: AsyncClient) -> None:
    """Close a connection that may be dead already."""
    with contextlib.suppress(Exception):
        await asyncio.wait_for(client.disconnect(), 1.0)
