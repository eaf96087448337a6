"""Where samples come from: one narrow interface (connect, read one sample, close) with a
Modbus TCP PLC and a CAN bus of flame scanners behind it, so the daemon does not care which
protocol delivered a value. Everything behind `read()` is plain data.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import socket
import time
from abc import ABC, abstractmethod
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

import can
from pymodbus import FramerType
from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from .daqconfig import CanConfig, DaqConfig
from .deviceconfig import SERIAL_TRANSPORTS, PlcConfig
from .modbusline import SharedLine, shared_line
from .registers import (
    BIT_TABLES,
    COMM_ERROR,
    OK,
    STALE,
    BitRange,
    Image,
    Point,
    ReadRequest,
    plan_reads,
)

CONNECT_FAILURES = frozenset({"connection refused", "connect timeout", "host unreachable",
                              "network unreachable", "name not resolved", "cannot connect"})
"""Kinds of failure where the device never accepted the TCP connection: a dial that costs
it nothing (no session), so the daemon may retry these at a short fixed interval."""

BUSY = 6
"""Modbus exception code 6, server device busy: the one refusal worth asking again."""
FRAMERS = {"tcp": FramerType.SOCKET, "rtu-over-tcp": FramerType.RTU, "rtu": FramerType.RTU,
           "ascii-over-tcp": FramerType.ASCII, "ascii": FramerType.ASCII}
"""The pymodbus framing of each transport of the config."""

EXCEPTION_NAMES = {1: "illegal function", 2: "illegal data address", 3: "illegal data value",
                   4: "server device failure", 5: "acknowledge", 6: "server device busy",
                   8: "memory parity error", 10: "gateway path unavailable",
                   11: "gateway target device failed to respond"}
"""Modbus exception codes as the protocol specification names them."""


def exception_text(code: int | None) -> str:
    """'Modbus exception code 2 (illegal data address)': the code a PLC manual lists, and
    what it means for whoever reads the journal without the manual."""
    name = EXCEPTION_NAMES.get(code) if code is not None else None
    return f"Modbus exception code {'?' if code is None else code}" + (f" ({name})" if name else "")


def failure_kind(exc: BaseException) -> str:
    """A short, stable class of a failed dial or poll ('connection refused', 'poll timeout'):
    what the journal is rate-limited by and what the final count is grouped by, where the
    full message would make every occurrence unique."""
    if isinstance(exc, SourceError):
        return exc.kind
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused"
    if isinstance(exc, socket.gaierror):
        return "name not resolved"
    if isinstance(exc, TimeoutError):
        return "poll timeout"
    if isinstance(exc, ConnectionException):
        return "connection lost"
    if isinstance(exc, ModbusIOException):
        return "no response"
    if isinstance(exc, OSError):
        named = {errno.EHOSTUNREACH: "host unreachable", errno.ENETUNREACH: "network unreachable",
                 errno.ECONNRESET: "connection reset", errno.EPIPE: "connection lost",
                 errno.ETIMEDOUT: "connect timeout", errno.ENOENT: "no such device",
                 errno.EACCES: "permission denied", errno.EBUSY: "device busy"}
        return named.get(exc.errno or 0, (exc.strerror or type(exc).__name__).lower())
    if isinstance(exc, ModbusException):
        return "Modbus error"
    return "malformed reply"


class SourceError(Exception):
    """The source could not deliver: connection refused or lost, timeout, Modbus exception.

    `kind` is its class (see `failure_kind`); the message says the rest."""

    def __init__(self, message: str, kind: str = "error"):
        super().__init__(message)
        self.kind = kind


class AllRefused(SourceError):
    """The device answered every request of a read with a Modbus exception: `refused` holds
    the exception code of each block."""

    def __init__(self, refused: dict[ReadRequest, int | None]):
        super().__init__("; ".join(_refused_text(r, c) for r, c in refused.items()),
                         "all blocks refused")
        self.refused = refused


@dataclass
class Sample:
    """One read of a source; absent parts are None."""

    values: dict[str, float | bool | None] = field(default_factory=dict)
    """By item name: thermocouples, `t_air`, and the points of `heat:`, `disturbances:` and
    `signals:` by their key paths (a bit signal as a boolean)."""
    quality: dict[str, str] = field(default_factory=dict)
    plc_seconds: float | None = None
    heartbeat: float | str | None = None
    burners: dict[str, list[bool]] | None = None
    burner_quality: str = OK
    errors: list[str] = field(default_factory=list)
    """What the PLC answered without a value in this read, as the log's `error` field says
    it (their points are comm_error)."""
    unread: list[Unread] = field(default_factory=list)
    """The same, each with the items it leaves without a value: what the journal tells."""


@dataclass(frozen=True)
class Unread:
    """A part of the map a device answered without a value, whatever its protocol: a block
    refused with a Modbus exception, an S7 area the PLC has not got, an OPC UA node the
    server does not know."""

    what: str
    """What and why, as the journal says it."""
    kind: str
    """Its short form, which the `incomplete` counts group by."""
    items: tuple[str, ...]
    """Names of the items left without a value."""


class Source(ABC):
    """A device the daemon polls, after python-can's BusABC: a narrow hardware boundary."""

    name: str = "source"

    @abstractmethod
    async def connect(self) -> None:
        """Open the connection; raise SourceError when the device cannot be reached."""

    @abstractmethod
    async def read(self) -> Sample:
        """One sample; raise SourceError on a failed read."""

    @abstractmethod
    async def close(self) -> None:
        """Release the connection; safe to call twice."""

    @property
    @abstractmethod
    def connected(self) -> bool: ...


class ModbusSource(Source):
    """One Modbus device (TCP; RTU or ASCII over TCP; RTU or ASCII on a serial line), read
    in as few requests as its map and workarounds allow.

    pymodbus' own reconnect is switched off (reconnect_delay=0): the daemon owns the
    connection state, so every drop and redial is visible in the log. With the workaround
    `close_connection_after_gather` the source stays "connected" between polls while the
    line is closed, and each read dials again: the daemon sees a device that answers.
    Devices on one serial bus share its one client (modbusline), one read at a time."""

    name = "modbus"

    def __init__(self, config: DaqConfig, host: str | None = None, port: int | None = None,
                 device: PlcConfig | None = None, items: list[Point | BitRange] | None = None):
        self.config = config
        self.device = device if device is not None else config.devices[0]
        self.host = host or self.device.host
        self.port = port or self.device.port
        if items is None:
            items = device_items(config, self.device)
        self.items = items
        """What is read: the config's points on this device (or the caller's own)."""
        self._names = {it.name for it in self.items}
        self.requests = plan_device_reads(self.items, self.device)
        self._client: AsyncModbusTcpClient | AsyncModbusSerialClient | None = None
        self._line: SharedLine | None = None  # while attached
        self._session = False  # connected as the daemon sees it (close-after-gather)
        self._neighbours = [d for d in config.devices if d.line is not None
                            and d.line == self.device.line and d.name != self.device.name]
        """The other devices on this device's serial bus, whose reads it takes turns with."""

    @property
    def connected(self) -> bool:
        if self.device.workarounds.close_connection_after_gather:
            return self._session
        return self._client is not None and self._client.connected

    @property
    def where(self) -> str:
        if self.device.transport in SERIAL_TRANSPORTS:
            return self.device.where
        return f"{self.host}:{self.port}"

    @property
    def transport_text(self) -> str:
        """How the device is reached, as `furnace-daq check` lists it."""
        d = self.device
        framing = d.transport.split("-")[0].upper()
        if d.transport in SERIAL_TRANSPORTS and d.serial is not None:
            s = d.serial
            return f"Modbus {framing} {s.port} {s.baudrate} {s.bytesize}{s.parity}{s.stopbits}"
        return (f"Modbus {framing} over TCP " if d.transport != "tcp" else "Modbus TCP ") \
            + self.where

    @property
    def line_wait_s(self) -> float:
        """How long a read may wait for the other devices on its serial bus to finish
        theirs: the sum of their read budgets (0 for a device on its own)."""
        return sum(d.read_budget_s(len(plan_device_reads(device_items(self.config, d), d)))
                   for d in self._neighbours)

    def _new_client(self) -> AsyncModbusTcpClient | AsyncModbusSerialClient:
        d = self.device
        # a shared client waits as long as its slowest device; each read keeps its own
        timeout = max([d.timeout_s, *(n.timeout_s for n in self._neighbours)])
        framer = FRAMERS[d.transport]
        if d.transport in SERIAL_TRANSPORTS:
            s = d.serial
            assert s is not None
            return AsyncModbusSerialClient(s.port, framer=framer, baudrate=s.baudrate,
                                           bytesize=s.bytesize, parity=s.parity,
                                           stopbits=s.stopbits, timeout=timeout,
                                           retries=0, reconnect_delay=0)
        client = AsyncModbusTcpClient(self.host, port=self.port, framer=framer,
                                      timeout=timeout, retries=0, reconnect_delay=0)
        if self._neighbours:
            # pymodbus hangs up after a few unanswered requests in a row; on a converter
            # shared by several devices one silent device must not cut off the others
            client.set_max_no_responses(1_000_000)
        return client

    async def connect(self) -> None:
        await self.close()
        await self._dial()
        self._session = True

    async def _dial(self) -> None:
        key = self.device.line
        line = shared_line(key) if key is not None and self._neighbours else SharedLine(self)
        client, fresh = await line.attach(self, self._open)
        self._line, self._client = line, client
        pause = self.device.workarounds.pause_after_connect_s
        if fresh and pause > 0:  # a gateway that drops the first request sent too soon
            await asyncio.sleep(pause)

    async def _open(self) -> AsyncModbusTcpClient | AsyncModbusSerialClient:
        timeout = self.device.timeout_s
        try:
            client = self._new_client()
        except RuntimeError as exc:  # pymodbus without pyserial: a serial line cannot open
            raise SourceError(f"cannot open {self.where}: {exc}", "serial unavailable") from None
        failed = _note_connect_failure(client)
        t0 = time.monotonic()
        try:
            ok = await asyncio.wait_for(client.connect(), timeout)
        except (TimeoutError, OSError, ModbusException) as exc:
            client.close()
            kind = "connect timeout" if isinstance(exc, TimeoutError) else failure_kind(exc)
            raise SourceError(f"cannot connect to {self.where}: {exc or 'timeout'}",
                              kind) from None
        if not ok:
            client.close()
            if failed:  # why the client gave up, which it keeps to itself
                exc = failed[0]
                kind = failure_kind(exc)
                why = os.strerror(exc.errno) if exc.errno else str(exc)
            elif time.monotonic() - t0 >= 0.9 * timeout:
                kind, why = "connect timeout", f"no answer within {timeout:g} s"
            else:
                kind, why = "cannot connect", "refused or unreachable"
            raise SourceError(f"cannot connect to {self.where}: {why}", kind)
        return client

    async def close(self) -> None:
        self._session = False
        self._drop()

    def _drop(self) -> None:
        if self._line is not None:
            self._line.detach(self)
        self._line = self._client = None

    async def read_image(self) -> tuple[Image, dict[ReadRequest, int | None]]:
        """Every planned request once: the words and bits read, and the blocks the PLC
        refused (with the exception code it gave). Raises SourceError when the link fails
        or every block is refused."""
        async with self._gathering():
            return await self._read_requests()

    async def read_block(self, req: ReadRequest) -> tuple[list[int] | None, int | None]:
        """One request on its own, in the device's turn on its line: (values, None), or
        (None, the exception code) when the device refuses it. `furnace-daq check` splits a
        refused block with it."""
        async with self._gathering():
            if self._line is None:
                raise SourceError("not connected", "connection lost")
            async with self._line.turn:
                return await self._request(req)

    @contextlib.asynccontextmanager
    async def _gathering(self) -> AsyncIterator[None]:
        """A read on the open line; with `close_connection_after_gather`, dialled for it
        and hung up after it."""
        w = self.device.workarounds
        if w.close_connection_after_gather and self._session and self._client is None:
            await self._dial()
        try:
            yield
        finally:
            if w.close_connection_after_gather:
                self._drop()

    async def _read_requests(self) -> tuple[Image, dict[ReadRequest, int | None]]:
        line = self._line
        if line is None:
            raise SourceError("not connected", "connection lost")
        image = Image()
        pause = self.device.workarounds.pause_between_requests_s
        refused: dict[ReadRequest, int | None] = {}
        async with line.turn:  # the other devices of a shared bus wait for this read
            for k, req in enumerate(self.requests):
                if k and pause > 0:
                    await asyncio.sleep(pause)
                values, code = await self._request(req)
                if values is None:
                    # The PLC answered, refusing one block: the link is fine and the other
                    # blocks stay good; this block's points decode as comm_error.
                    refused[req] = code
                    continue
                image.put(req, values)
        if refused and len(refused) == len(self.requests):
            raise AllRefused(refused)
        return image, refused

    async def _request(self, req: ReadRequest) -> tuple[list[int] | None, int | None]:
        """One request, sent again while the device says it is busy (exception 6), at most
        `busy_retries` times."""
        client = self._client
        if client is None or not client.connected:
            raise SourceError("not connected", "connection lost")
        d = self.device
        methods = {"input": client.read_input_registers, "holding": client.read_holding_registers,
                   "discrete": client.read_discrete_inputs, "coil": client.read_coils}
        code: int | None = None
        for attempt in range(d.busy_retries + 1):
            if attempt:
                await asyncio.sleep(d.busy_retries_wait_s)
            try:
                rr = await asyncio.wait_for(
                    methods[req.table](req.address, count=req.count, device_id=d.device_id),
                    d.timeout_s + 0.05)  # the shared client's own timeout may be longer
            except TimeoutError:
                raise SourceError(f"{req.table} {req.address}+{req.count}: no response within "
                                  f"{d.timeout_s:g} s", "no response") from None
            except ModbusException as exc:
                raise SourceError(f"{req.table} {req.address}+{req.count}: {exc}",
                                  failure_kind(exc)) from None
            if not rr.isError():
                values = rr.bits if req.table in BIT_TABLES else rr.registers
                if len(values) < req.count:
                    raise SourceError(f"{req.table} {req.address}+{req.count}: short response "
                                      f"({len(values)} values)", "short response")
                return [int(v) for v in values[:req.count]], None
            code = getattr(rr, "exception_code", None)
            if code != BUSY:
                break
        return None, code

    async def read(self) -> Sample:
        image, refused = await self.read_image()
        sample = self.decode(image)
        sample.errors = [_refused_text(r, c) for r, c in refused.items()]
        sample.unread = [Unread(f"{_block_text(r)} refused with {exception_text(c)}",
                                f"{_block_text(r)} refused with exception code "
                                f"{'?' if c is None else c}",
                                tuple(it.name for it in self.items if it.table == r.table
                                      and r.address <= it.address < r.end))
                         for r, c in refused.items()]
        return sample

    def decode(self, image: Image) -> Sample:
        """Engineering values and qualities from one scan's words and bits."""
        cfg = self.config
        mine = self._names
        sample = Sample()
        for point in (*cfg.thermocouples, *([cfg.ambient] if cfg.ambient else []),
                      *cfg.heat, *cfg.disturbances, *(s.item for s in cfg.signals)):
            if point.name not in mine:
                continue  # another device's
            words = image.words(point)
            if words is None:
                value, quality = None, COMM_ERROR
            elif isinstance(point, BitRange):  # a bit signal
                value, quality = point.states(words)[0], OK
            else:
                value, quality = point.value(words)
            sample.values[point.name] = value
            sample.quality[point.name] = quality
        if cfg.clock is not None and "clock" in mine:
            words = image.words(cfg.clock.point)
            if words is not None:
                sample.plc_seconds = float(cfg.clock.point.raw(words)) * cfg.clock.point.scale \
                    + cfg.clock.point.offset
        if cfg.heartbeat is not None and "heartbeat" in mine:
            words = image.words(cfg.heartbeat)
            if words is not None:
                raw = cfg.heartbeat.raw(words)
                sample.heartbeat = raw if isinstance(raw, str) else float(raw)
        if cfg.burner_source in ("modbus", "both") and any(b.name in mine
                                                             for b in cfg.burner_bits):
            burners = {}
            for bits in cfg.burner_bits:
                if bits.name not in mine:
                    continue  # several devices: the daemon merges the zones
                got = image.words(bits)
                if got is None:
                    sample.burner_quality = COMM_ERROR
                    break
                burners[bits.name] = bits.states(got)
            else:
                sample.burners = burners
        return sample


def _block_text(req: ReadRequest) -> str:
    return f"{req.table} {req.address}+{req.count}"


def _refused_text(req: ReadRequest, code: int | None) -> str:
    return f"{_block_text(req)}: {exception_text(code)}"


def device_items(config: DaqConfig, device: PlcConfig) -> list[Point | BitRange]:
    """The config's points read from `device`."""
    return config.device_items(device) if config.several_devices else config.modbus_items()


def plan_device_reads(items: list[Point | BitRange], device: PlcConfig) -> list[ReadRequest]:
    """The requests that read `items` from `device`, under its limits and workarounds."""
    w = device.workarounds
    return plan_reads(items, device.max_gap_registers, device.max_gap_bits,
                      w.max_registers_per_request, w.one_request_per_field,
                      w.read_coils_starting_at_zero)


def _note_connect_failure(client: AsyncModbusTcpClient | AsyncModbusSerialClient
                          ) -> list[OSError]:
    """The OSError behind a failed connect (refused, unreachable), which pymodbus catches
    and reduces to False. Wraps the client's connection factory; if a pymodbus version
    lays its transport out differently the list stays empty and the reason is generic."""
    failed: list[OSError] = []
    ctx = getattr(client, "ctx", None)
    create = getattr(ctx, "call_create", None)
    if create is None:
        return failed

    async def create_noting_failure():
        try:
            return await create()
        except OSError as exc:
            failed.append(exc)
            raise

    ctx.call_create = create_noting_failure
    return failed


class CanSource(Source):
    """Flame scanners broadcasting burner states on a CAN bus. Frames arrive on their own
    schedule; `read()` returns the latest state of each zone, `stale` when a zone has been
    silent for longer than the configured timeout."""

    name = "can"

    def __init__(self, config: CanConfig):
        self.config = config
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._latest: dict[str, tuple[list[bool], float]] = {}
        self.frames = 0
        self.last_data: dict[tuple[int, bool], bytes] = {}
        """The latest payload of each frame id (what `furnace-daq check` shows raw)."""
        self._by_id: dict[tuple[int, bool], list[tuple[str, int, int]]] = {}
        for zone, f in config.frames.items():
            self._by_id.setdefault((f.can_id, f.extended), []).append(
                (zone, f.start_bit, f.burners))

    @property
    def connected(self) -> bool:
        return self._bus is not None

    async def connect(self) -> None:
        await self.close()
        kwargs = {} if self.config.bitrate is None else {"bitrate": self.config.bitrate}
        try:
            bus = can.Bus(interface=self.config.interface, channel=self.config.channel, **kwargs)
        except (can.CanError, OSError, ValueError, ImportError) as exc:
            raise SourceError(f"cannot open CAN {self.config.interface}:{self.config.channel}: "
                              f"{exc}", "CAN unavailable") from None
        self._bus = bus
        self._notifier = can.Notifier(bus, [self.on_message], loop=asyncio.get_running_loop())

    def on_message(self, msg: can.Message) -> None:
        zones = self._by_id.get((msg.arbitration_id, bool(msg.is_extended_id)))
        if not zones or msg.is_error_frame or msg.is_remote_frame:
            return
        self.last_data[(msg.arbitration_id, bool(msg.is_extended_id))] = bytes(msg.data)
        value = int.from_bytes(bytes(msg.data), "little")
        now = time.monotonic()
        for zone, start, n in zones:
            if start + n <= 8 * len(msg.data):
                self._latest[zone] = ([bool(value >> (start + k) & 1) for k in range(n)], now)
        self.frames += 1

    def latest(self, zone: str) -> list[bool] | None:
        """The zone's burner states of its latest frame; None before one came."""
        got = self._latest.get(zone)
        return None if got is None else list(got[0])

    async def read(self) -> Sample:
        if self._bus is None:
            raise SourceError("CAN bus not open", "CAN unavailable")
        if len(self._latest) < len(self.config.frames):
            return Sample(burners=None, burner_quality=COMM_ERROR)
        now = time.monotonic()
        oldest = min(t for _, t in self._latest.values())
        quality = STALE if now - oldest > self.config.timeout_s else OK
        return Sample(burners={z: list(self._latest[z][0]) for z in self.config.frames},
                      burner_quality=quality)

    async def close(self) -> None:
        if self._notifier is not None:
            self._notifier.stop()
            self._notifier = None
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None
