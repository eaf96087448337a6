"""Write-back: the latest identified model parameters written to PLC holding registers, so
a PLC program can use them (a model-based setpoint, an alarm on drift).

This is the only code in the product that writes to a PLC, and a gateway that writes is a
risk an acquisition gateway otherwise does not carry. So: it is off unless the config has a
`write_back:` block with `enabled: true`; it then needs an explicit `allow` list of holding
registers, and a map that names any register not on that list is refused at load, with the
key that names it. At run time every request is checked against the list once more before
it is sent, and only "write multiple registers" (FC16) is ever used. Only parameters from a
fit whose status is `ok` are written; a failed or unexcited window leaves the PLC's values
as they were.

    write_back:
      enabled: true
      allow: [[100, 112]]          # holding registers 100..112; single addresses work too
      params:                      # parameter -> register(s); float32 unless typed otherwise
        a: {address: 100}
        b: {address: 102, type: float32, word_order: little}
        c: {address: 104, type: int16, scale: 0.001}   # raw = value / scale, rounded
      counter: {address: 112}      # uint16, incremented after each complete write
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import re
from collections.abc import Callable
from dataclasses import dataclass

from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ModbusException

from furnace_model.config import Node
from furnace_model.log.messages import DaqEvent, DaqEventKind, ModelParameters

from .registers import DATA_TYPES, ORDERS, encode, integer_range

WRITE_FUNCTION_CODE = 16
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


class WriteBackError(Exception):
    """A write that was not done: refused by the allow-list, unencodable, or failed."""


@dataclass(frozen=True)
class WritePoint:
    """One parameter's place in the PLC's holding registers."""

    name: str
    address: int
    dtype: str = "float32"
    word_order: str = "big"
    byte_order: str = "big"
    scale: float = 1.0

    @property
    def count(self) -> int:
        return DATA_TYPES[self.dtype][0]

    def registers(self, value: float) -> list[int]:
        raw = float(value) / self.scale
        if not math.isfinite(raw):
            raise WriteBackError(f"{self.name} = {value!r} is not a finite number")
        span = integer_range(self.dtype)
        if span is not None:
            lo, hi = span
            if not lo <= round(raw) <= hi:
                raise WriteBackError(f"{self.name} = {value:g} does not fit {self.dtype} "
                                     f"with scale {self.scale:g}")
            raw = round(raw)
        return encode(raw, self.dtype, self.word_order, self.byte_order)


@dataclass(frozen=True)
class WriteBackConfig:
    allow: frozenset[int]
    points: tuple[WritePoint, ...]
    counter: int | None = None
    """Address of a uint16 the PLC can watch: incremented after every complete write."""

    def refused(self, address: int, count: int) -> list[int]:
        """The registers of a request that are not on the allow-list."""
        return [a for a in range(address, address + count) if a not in self.allow]


def _allow(node: Node) -> frozenset[int]:
    out: set[int] = set()
    for item in node.elements(1):
        if isinstance(item.value, list):
            lo, hi = (n.integer(lo=0, hi=65535) for n in item.elements(2, 2))
            if lo > hi:
                raise item.error(f"expected [first, last] with first <= last, got [{lo}, {hi}]")
            out.update(range(lo, hi + 1))
        else:
            out.add(item.integer(lo=0, hi=65535))
    return frozenset(out)


def parse_write_back(node: Node) -> WriteBackConfig | None:
    """The `write_back:` block (None when absent or not enabled). The whole block is checked
    even when disabled, so a typo does not wait for the day it is switched on."""
    if node.value is None:
        return None
    node.mapping({"enabled", "allow", "params", "counter"})
    enabled = node.get_bool("enabled", False)
    if not node.has("allow"):
        if enabled:
            raise node.error("allow: required when write_back is enabled: list every holding "
                             "register the daemon may write, e.g. allow: [[100, 111]]")
        allow: frozenset[int] = frozenset()
    else:
        allow = _allow(node.child("allow"))
    points: list[WritePoint] = []
    taken: dict[int, str] = {}

    def check(where: Node, name: str, address: int, count: int) -> None:
        off = [a for a in range(address, address + count) if a not in allow]
        if off:
            raise where.error(f"holding register {off[0]} of {name} is not on write_back.allow; "
                              "the daemon writes only to listed registers")
        for a in range(address, address + count):
            if a in taken:
                raise where.error(f"holding register {a} of {name} is also written for "
                                  f"{taken[a]}")
            taken[a] = name

    params = node.child("params", {}).mapping()
    for name, pn in params.items():
        if not _NAME.fullmatch(name):
            raise pn.error("expected a model parameter name such as a, b ... f")
        pn.mapping({"address", "type", "word_order", "byte_order", "scale"})
        dtype = pn.get_string("type", "float32", choices=tuple(DATA_TYPES))
        count = DATA_TYPES[dtype][0]
        address = pn.get_integer("address", lo=0, hi=65536 - count)
        scale = pn.get_number("scale", 1.0)
        if scale == 0:
            raise pn.child("scale").error("must not be 0")
        check(pn.child("address"), name, address, count)
        points.append(WritePoint(name, address, dtype,
                                 pn.get_string("word_order", "big", choices=ORDERS),
                                 pn.get_string("byte_order", "big", choices=ORDERS), scale))
    counter = None
    if node.has("counter"):
        cn = node.child("counter").mapping({"address"})
        counter = cn.get_integer("address", lo=0, hi=65535)
        check(cn.child("address"), "the counter", counter, 1)
    if enabled and not points:
        raise node.error("params: name at least one parameter to write when write_back is "
                         "enabled")
    return WriteBackConfig(allow, tuple(points), counter) if enabled else None


Events = Callable[[DaqEvent], None]


class WriteBack:
    """Writes each `ok` model to the PLC on its own connection (the poll connection is never
    held up by a write). `on_model` is the Daemon's callback: it only remembers the newest
    model and wakes the writer, so a slow PLC never delays a poll and a backlog never
    builds up; only the newest parameters matter."""

    def __init__(self, config: WriteBackConfig, host: str, port: int, *, device_id: int = 1,
                 timeout_s: float = 1.0, events: Events | None = None):
        self.config = config
        self.host, self.port, self.device_id, self.timeout_s = host, port, device_id, timeout_s
        self.events = events
        self.writes = 0
        self.counter = 0
        self.error: str | None = None
        self._client: AsyncModbusTcpClient | None = None
        self._latest: ModelParameters | None = None
        self._task: asyncio.Task | None = None

    def on_model(self, message: dict) -> None:
        """The daemon's callback, with the /model/parameters message as logged."""
        model = ModelParameters.from_json(message)
        if not model.fitted:
            return
        self._latest = model
        if self._task is None or self._task.done():
            self._task = asyncio.get_running_loop().create_task(self._drain(),
                                                                name="write-back")

    async def _drain(self) -> None:
        while self._latest is not None:
            message, self._latest = self._latest, None
            try:
                await self.write(message)
            except WriteBackError as exc:
                self._event(DaqEventKind.WRITE_BACK_FAILED, str(exc))

    def plan(self, message: ModelParameters | dict) -> list[tuple[int, list[int]]]:
        """(address, registers) of each request for a model message (or its JSON), in
        address order, neighbouring points merged into one request. All or nothing: a PLC
        must never run on a mix of two models' parameters."""
        model = message if isinstance(message, ModelParameters) else \
            ModelParameters.from_json(message)
        words: dict[int, int] = {}
        for p in self.config.points:
            value = model.params.get(p.name)
            if value is None:
                raise WriteBackError(f"the model has no value for {p.name}: nothing written")
            for k, w in enumerate(p.registers(value)):
                words[p.address + k] = w
        requests: list[tuple[int, list[int]]] = []
        for a in sorted(words):
            if requests and requests[-1][0] + len(requests[-1][1]) == a \
                    and len(requests[-1][1]) < 123:
                requests[-1][1].append(words[a])
            else:
                requests.append((a, [words[a]]))
        return requests

    async def write(self, message: ModelParameters | dict) -> int:
        """Write one model's parameters (then the counter); the number of registers written."""
        requests = self.plan(message)
        if self.config.counter is not None:
            requests.append((self.config.counter, [(self.counter + 1) & 0xFFFF]))
        for address, values in requests:  # all checked before the first is sent
            off = self.config.refused(address, len(values))
            if off:
                raise WriteBackError(f"refused: holding register {off[0]} is not on "
                                     "write_back.allow")
        client = await self._connect()
        for address, values in requests:
            try:
                rr = await asyncio.wait_for(
                    client.write_registers(address, values, device_id=self.device_id),
                    self.timeout_s)
            except (ModbusException, TimeoutError, OSError) as exc:
                self._drop()
                raise WriteBackError(f"writing holding registers {address}+{len(values)} to "
                                     f"{self.host}:{self.port}: {exc or 'timeout'}") from None
            if rr.isError():
                raise WriteBackError(f"the PLC refused holding registers {address}+"
                                     f"{len(values)}: Modbus exception code "
                                     f"{getattr(rr, 'exception_code', '?')}")
        if self.config.counter is not None:
            self.counter = (self.counter + 1) & 0xFFFF
        self.writes += 1
        if self.error is not None:
            self._event(DaqEventKind.WRITE_BACK_OK,
                        "writing model parameters to the PLC works again")
        self.error = None
        return sum(len(v) for _, v in requests)

    async def _connect(self) -> AsyncModbusTcpClient:
        if self._client is not None and self._client.connected:
            return self._client
        self._drop()
        client = AsyncModbusTcpClient(self.host, port=self.port, timeout=self.timeout_s,
                                      retries=0, reconnect_delay=0)
        try:
            ok = await asyncio.wait_for(client.connect(), self.timeout_s)
        except (TimeoutError, OSError, ModbusException):
            ok = False
        if not ok:
            client.close()
            raise WriteBackError(f"cannot connect to {self.host}:{self.port} to write the model")
        self._client = client
        return client

    async def close(self) -> None:
        """Finish a write in progress (bounded by the timeout), then drop the connection."""
        task, self._task = self._task, None
        if task is not None and not task.done():
            with contextlib.suppress(asyncio.CancelledError, TimeoutError):
                await asyncio.wait_for(task, 2 * self.timeout_s)
        self._drop()

    def _drop(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None

    def _event(self, kind: DaqEventKind, detail: str) -> None:
        if kind is DaqEventKind.WRITE_BACK_FAILED:
            if detail == self.error:
                return  # said once, not at every model
            self.error = detail
        if self.events is not None:
            self.events(DaqEvent(kind, detail))
