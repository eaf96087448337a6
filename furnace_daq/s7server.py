"""The simulated PLC served over S7: the same plant, PLC clock and heartbeat as the Modbus
simulated PLC (through itemplc.ItemPLC), each value at its S7 address in the memory of
python-snap7's own server, so the daemon, `furnace-daq check` and the tests can run
against a real S7 server (ISO on TCP).

The memory is a daemon config's S7 map (`sim-plc --protocol s7 --config`), or by default
the map of config/gateway-s7.yaml, derived for any furnace by one rule (`default_items`):
data block 10 holds the PLC clock at DBD0 (DINT, seconds) and from DBD4 on one REAL per
thermocouple in the furnace's order, then the ambient, each rate-fired zone's heat input
and each disturbance (in the description's units); the heartbeat is the marker word MW10
(WORD); the burners' flame states are the inputs from I0.0 on, zone after zone in the
description's order (as their flame relays are wired to a digital input card). An open
thermocouple is served as a REAL NaN (or the item's first sentinel).

Each area is written whole at each scan under the server's lock of that area, so a read
never sees half of one scan and half of the next.
"""

from __future__ import annotations

import asyncio
import logging
import math

from snap7.error import S7Error
from snap7.server import Server
from snap7.type import SrvArea
from snap7.util import (
    set_bool,
    set_byte,
    set_dint,
    set_dword,
    set_int,
    set_real,
    set_sint,
    set_udint,
    set_uint,
    set_word,
)

from furnace_model.simulation.furnace import Furnace
from furnace_model.simulation.scenario import Scenario

from .daqconfig import DISTURBANCES_KEY, HEAT_KEY, Signal, item_name
from .itemplc import ItemPLC
from .s7map import S7Address, S7Bits, S7Point
from .scaling import wrapped
from .servedmap import burner_starts
from .simplc import PlcValues, ValueSource

for _name in ("snap7", "s7"):
    logging.getLogger(_name).setLevel(logging.CRITICAL)

DATA_BLOCK = 10
HEARTBEAT = "MW10"
SERVER_AREAS = {"DB": SrvArea.DB, "I": SrvArea.PE, "Q": SrvArea.PA, "M": SrvArea.MK}
SETTERS = {"byte": set_byte, "sint": set_sint, "word": set_word, "uint": set_uint,
           "int": set_int, "dword": set_dword, "udint": set_udint, "dint": set_dint,
           "real": set_real}
INTEGERS = {"byte": (8, False), "sint": (8, True), "word": (16, False), "uint": (16, False),
            "int": (16, True), "dword": (32, False), "udint": (32, False), "dint": (32, True)}
"""Bits and signedness of each integer type."""


def _db(start: int, width: int = 4) -> S7Address:
    return S7Address("DB", DATA_BLOCK, start, width)


def default_items(furnace: Furnace) -> tuple[S7Point | S7Bits, ...]:
    """The default S7 map of a furnace (the module's docstring)."""
    reals = [*furnace.sensors, "t_air",
             *(item_name(HEAT_KEY, furnace.zones[i]) for i in furnace.rated),
             *(item_name(DISTURBANCES_KEY, d.name) for d in furnace.disturbances)]
    items: list[S7Point | S7Bits] = [S7Point("clock", _db(0), "dint")]
    items += [S7Point(name, _db(4 + 4 * k)) for k, name in enumerate(reals)]
    items.append(S7Point("heartbeat", S7Address("M", 0, 10, 2), "word"))
    for zone, first in burner_starts(furnace).items():
        bit = S7Address("I", 0, first // 8, 0, first % 8)
        run = [bit]
        while len(run) < furnace.burners[furnace.zones.index(zone)]:
            run.append(run[-1].next_bit())
        items.append(S7Bits(zone, tuple(run), len(run)))
    return tuple(items)


def memory_sizes(items) -> dict[tuple[str, int], int]:
    """The bytes each area (area, data block) must hold for `items`."""
    sizes: dict[tuple[str, int], int] = {}
    for item in items:
        for a in item.addresses:
            key = (a.area, a.db)
            sizes[key] = max(sizes.get(key, 0), a.start + a.size)
    return sizes


class S7PLC(ItemPLC):
    """A running simulated PLC on S7: `await start()`, then `port`; `await stop()`.

    `items`: the addresses to serve (default: `default_items`); `signals`: the map's extra
    signals (simulated when the source has no value)."""

    item_types = (S7Point, S7Bits)
    default_items = staticmethod(default_items)

    def __init__(self, source: ValueSource | Scenario, *, items=None,
                 signals: tuple[Signal, ...] = (), port: int = 1102, **kw):
        super().__init__(source, items=items, signals=signals, port=port, **kw)
        self._s7: Server | None = None
        self._memory: dict[tuple[str, int], bytearray] = {}
        """The server's areas, by (area, data block): the server reads these very buffers."""

    # -- life cycle ----------------------------------------------------------------------
    async def start(self) -> None:
        server = Server(log=False)
        for (area, db), size in memory_sizes(self.items).items():
            buffer = bytearray(size)
            server.register_area(SERVER_AREAS[area], db, buffer)
            self._memory[(area, db)] = buffer
        try:
            server.start_to(self.host, tcp_port=self.port)
        except S7Error as exc:  # the bind failed: in use, or a port below 1024 without root
            raise OSError(str(exc)) from None
        if self.port == 0:  # the port the system chose
            self.port = server.server_socket.getsockname()[1]
        self._s7 = server
        await self._start_scanning()

    async def stop(self) -> None:
        await self._stop_scanning()
        if self._s7 is not None:
            server, self._s7 = self._s7, None
            await asyncio.to_thread(server.stop)  # joins the server's threads

    def vanish(self, area: str, db: int = 0) -> None:
        """Remove an area from the server, as a program download that drops a data block
        would (a fault drill): reads of it are refused with 'object does not exist'."""
        assert self._s7 is not None
        self._memory.pop((area, db))
        self._s7.unregister_area(SERVER_AREAS[area], db)

    # -- one scan ------------------------------------------------------------------------
    async def scan(self) -> None:
        self._publish(self.advance())

    def _publish(self, values: PlcValues) -> None:
        server = self._s7
        if server is None:
            return
        shown = self.item_values(values)
        images = {key: bytearray(buffer) for key, buffer in self._memory.items()}
        for item in self.items:
            image = images.get((item.addresses[0].area, item.addresses[0].db))
            if image is None:
                continue  # its area vanished
            value = shown[item.name]
            if isinstance(item, S7Bits):
                assert isinstance(value, list)
                for a, on in zip(item.addresses, value, strict=True):
                    set_bool(image, a.start, a.bit, on)
            else:
                assert isinstance(value, float)
                _encode(item, value, image)
        for (area, db), image in images.items():
            server.lock_area(SERVER_AREAS[area], db)
            try:
                self._memory[(area, db)][:] = image
            finally:
                server.unlock_area(SERVER_AREAS[area], db)
        self.scans += 1


def _encode(item: S7Point, value: float, image: bytearray) -> None:
    """Put the raw value that reads as `value` through the item's scaling at its address:
    an integer rounded and wrapped into its type (counters); an open sensor (NaN) as the
    first sentinel, or NaN for a REAL."""
    if math.isfinite(value):
        raw = item.scaling.raw(value)
    elif item.scaling.sentinels:
        raw = item.scaling.sentinels[0]
    elif item.dtype == "real":
        raw = math.nan
    else:
        return  # an integer has no NaN: the last value stays
    if item.dtype in INTEGERS:
        raw = wrapped(raw, *INTEGERS[item.dtype])
    SETTERS[item.dtype](image, item.address.start, raw)
