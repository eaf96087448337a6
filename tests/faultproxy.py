"""A fault-injecting Modbus TCP proxy on loopback, between the daemon and a simulated PLC.

A network and a PLC fail in a handful of ways the daemon must survive; this proxy makes each
one happen on purpose, switchable while traffic flows:

- `pass`: forward both ways.
- `drop`: open connections are closed (FIN); new ones are accepted, then closed at once.
- `refuse`: the listening socket is closed too, so a dial is refused; it listens again on
  the same port when the mode changes.
- `stall`: nothing passes either way and the connections stay up: whatever arrives while
  stalled is held back for good (a PLC that hung and lost its queue), so no stale answer
  reaches a client after its request timed out.
- `delay`: every response waits `delay_s` before it is forwarded (a slow link or PLC).
- `truncate`: the next response is cut to its first `keep_bytes` bytes (default: half),
  then both connections are closed.
- `reset`: open connections are reset (RST, SO_LINGER 0); new ones are accepted and reset.
- `garbage`: every response is replaced by random bytes of the same length.

The proxy parses Modbus TCP (MBAP) frames, so it acts on whole responses and keeps an
account: `requests` holds every request frame a client sent (whatever the mode; it proves
which function codes a client uses) and `answered` every (request, response) pair forwarded
to the client intact. A test compares the log with `answered`.

Use it inside an asyncio test (`await proxy.start()`, `await proxy.set_mode(...)`,
`await proxy.stop()`), or from synchronous code with `ThreadedFaultProxy`, which runs it on
an event loop of its own (for a daemon or PLC in a subprocess).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import random
import socket
import struct
import threading
import time
from collections import Counter
from dataclasses import dataclass, field, replace

MODES = ("pass", "drop", "refuse", "stall", "delay", "truncate", "reset", "garbage")
READ_FUNCTION_CODES = frozenset({1, 2, 3, 4})
MBAP = struct.Struct(">HHHB")  # transaction id, protocol id, length (unit id + PDU), unit id


@dataclass(frozen=True)
class Frame:
    """One Modbus TCP frame as it crossed the proxy."""

    conn: int
    tid: int
    unit: int
    pdu: bytes
    raw: bytes
    at: float = 0.0
    """Monotonic time it reached the proxy (a response: when it was forwarded)."""

    @property
    def function_code(self) -> int:
        return self.pdu[0] if self.pdu else -1

    @property
    def address_count(self) -> tuple[int, int] | None:
        """(start address, quantity) of a read or multiple-write request."""
        if len(self.pdu) >= 5:
            return struct.unpack(">HH", self.pdu[1:5])
        return None

    @property
    def registers(self) -> list[int]:
        """The words of a register-read response (FC3/FC4)."""
        if self.function_code not in (3, 4) or len(self.pdu) < 2:
            return []
        n = self.pdu[1] // 2
        return list(struct.unpack(f">{n}H", self.pdu[2:2 + 2 * n]))


@dataclass
class _Conn:
    id: int
    client: asyncio.StreamWriter
    client_reader: asyncio.StreamReader
    plc: asyncio.StreamWriter | None = None
    pending: dict[int, Frame] = field(default_factory=dict)
    closed: bool = False


async def _read_frame(reader: asyncio.StreamReader, conn: int) -> Frame | None:
    """The next MBAP frame, or None at the end of the stream."""
    try:
        head = await reader.readexactly(MBAP.size)
        tid, _pid, length, unit = MBAP.unpack(head)
        body = await reader.readexactly(max(length - 1, 0))
    except (asyncio.IncompleteReadError, ConnectionError, OSError):
        return None
    return Frame(conn, tid, unit, body, head + body, time.monotonic())


def _reset(writer: asyncio.StreamWriter) -> None:
    """Close with RST instead of FIN: SO_LINGER on, timeout 0."""
    sock = writer.get_extra_info("socket")
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    writer.transport.abort()


class FaultProxy:
    """Listen on `host:port` (0 = any free port) and forward to the PLC at `target`."""

    def __init__(self, target_port: int, *, target_host: str = "127.0.0.1",
                 host: str = "127.0.0.1", port: int = 0, seed: int = 0):
        self.target = (target_host, target_port)
        self.host, self.port = host, port
        self.mode = "pass"
        self.delay_s = 0.0
        self.keep_bytes: int | None = None
        self.requests: list[Frame] = []
        self.answered: list[tuple[Frame, Frame]] = []
        self.counts = {"connections": 0, "forwarded": 0, "garbled": 0, "truncated": 0,
                       "discarded": 0}
        self._rng = random.Random(seed)
        self._ids = itertools.count(1)
        self._conns: dict[int, _Conn] = {}
        self._tasks: set[asyncio.Task] = set()
        self._server: asyncio.Server | None = None

    # -- life cycle ---------------------------------------------------------------------------
    async def start(self) -> None:
        await self._listen()

    async def stop(self) -> None:
        await self._unlisten()
        for conn in list(self._conns.values()):
            self._close(conn, rst=False)
        for task in list(self._tasks):
            task.cancel()
        for task in list(self._tasks):
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task

    async def __aenter__(self) -> FaultProxy:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    async def set_mode(self, mode: str, *, delay_s: float | None = None,
                       keep_bytes: int | None = None) -> None:
        """Switch the fault; takes effect on open connections at once."""
        if mode not in MODES:
            raise ValueError(f"unknown mode {mode!r}; one of {', '.join(MODES)}")
        if delay_s is not None:
            self.delay_s = delay_s
        self.keep_bytes = keep_bytes
        self.mode = mode
        if mode in ("drop", "reset", "refuse"):
            for conn in list(self._conns.values()):
                self._close(conn, rst=mode == "reset")
        if mode == "refuse":
            await self._unlisten()
        elif self._server is None:
            await self._listen()

    # -- what passed --------------------------------------------------------------------------
    @property
    def function_codes(self) -> set[int]:
        """Every function code a client sent, in any mode."""
        return {f.function_code for f in self.requests}

    def answered_registers(self, function_code: int = 4, address: int = 0,
                           within_s: float = float("inf")) -> list[list[int]]:
        """The words of each intact response to a register read starting at `address` that
        was forwarded within `within_s` of its request (a later one the client gave up on)."""
        return [resp.registers for req, resp in self.answered
                if req.function_code == function_code and req.address_count is not None
                and req.address_count[0] == address and resp.function_code == function_code
                and resp.at - req.at <= within_s]

    def answered_polls(self, within_s: float) -> Counter:
        """PLC seconds (input registers 7-8 of the default map) of every poll whose two reads,
        input registers 0-9 and then the burner bits, reached the client intact within
        `within_s` of the first request: the samples a daemon must have logged."""
        pairs = {(req.conn, req.tid): (req, resp) for req, resp in self.answered[:]}
        out: Counter = Counter()
        for (conn, tid), (req, resp) in pairs.items():
            bits = pairs.get((conn, tid + 1))
            if req.function_code == 4 and req.address_count == (0, 10) and bits is not None \
                    and bits[0].function_code == 2 and bits[1].at - req.at <= within_s:
                regs = resp.registers
                out[(regs[7] << 16) | regs[8]] += 1
        return out

    # -- internals ----------------------------------------------------------------------------
    async def _listen(self) -> None:
        self._server = await asyncio.start_server(self._accept, self.host, self.port,
                                                  reuse_address=True)
        self.port = self._server.sockets[0].getsockname()[1]

    async def _unlisten(self) -> None:
        if self._server is not None:
            self._server.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._server.wait_closed(), 1.0)
            self._server = None

    def _close(self, conn: _Conn, rst: bool) -> None:
        conn.closed = True
        self._conns.pop(conn.id, None)
        for w in (conn.client, conn.plc):
            if w is None:
                continue
            if rst:
                _reset(w)
            else:
                with contextlib.suppress(Exception):
                    w.close()

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        self._tasks.add(task)
        try:
            await self._serve(reader, writer)
        except asyncio.CancelledError:
            pass  # stop(): asyncio's stream callback would report a cancelled handler
        finally:
            self._tasks.discard(task)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.counts["connections"] += 1
        conn = _Conn(next(self._ids), writer, reader)
        if self.mode in ("drop", "reset", "refuse"):
            self._close(conn, rst=self.mode == "reset")
            return
        try:
            plc_reader, conn.plc = await asyncio.wait_for(asyncio.open_connection(*self.target),
                                                          2.0)
        except (OSError, TimeoutError):
            self._close(conn, rst=False)
            return
        self._conns[conn.id] = conn
        up = asyncio.create_task(self._upstream(conn))
        down = asyncio.create_task(self._downstream(conn, plc_reader))
        try:
            await asyncio.wait({up, down}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for t in (up, down):
                t.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await t
            self._close(conn, rst=False)

    async def _upstream(self, conn: _Conn) -> None:
        while not conn.closed:
            frame = await _read_frame(conn.client_reader, conn.id)
            if frame is None:
                return
            self.requests.append(frame)
            if self.mode in ("drop", "reset"):
                self._close(conn, rst=self.mode == "reset")
                return
            if self.mode == "stall":
                self.counts["discarded"] += 1
                continue
            conn.pending[frame.tid] = frame
            conn.plc.write(frame.raw)
            await conn.plc.drain()

    async def _downstream(self, conn: _Conn, plc_reader: asyncio.StreamReader) -> None:
        while not conn.closed:
            frame = await _read_frame(plc_reader, conn.id)
            if frame is None:
                return
            request = conn.pending.pop(frame.tid, None)
            if self.mode == "stall" or request is None:
                self.counts["discarded"] += 1
                continue
            mode = self.mode
            if mode == "delay" and self.delay_s > 0:
                await asyncio.sleep(self.delay_s)
                mode = self.mode
            if conn.closed or conn.client_reader.at_eof():
                return
            if mode in ("drop", "reset"):
                self._close(conn, rst=mode == "reset")
                return
            if mode == "truncate":
                keep = self.keep_bytes if self.keep_bytes is not None else len(frame.raw) // 2
                conn.client.write(frame.raw[:max(0, min(keep, len(frame.raw) - 1))])
                with contextlib.suppress(ConnectionError):
                    await conn.client.drain()
                self.counts["truncated"] += 1
                self._close(conn, rst=False)
                return
            if mode == "garbage":
                conn.client.write(self._rng.randbytes(len(frame.raw)))
                self.counts["garbled"] += 1
            else:
                conn.client.write(frame.raw)
                self.counts["forwarded"] += 1
                self.answered.append((request, replace(frame, at=time.monotonic())))
            await conn.client.drain()


class ThreadedFaultProxy:
    """A FaultProxy on its own event loop in a daemon thread, for synchronous tests:
    `with ThreadedFaultProxy(plc_port) as proxy: proxy.set_mode("stall"); ... proxy.port`."""

    def __init__(self, target_port: int, **kwargs):
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="fault proxy",
                                         daemon=True)
        self.proxy = FaultProxy(target_port, **kwargs)

    def _call(self, coro, timeout: float = 10.0):
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout)

    def start(self) -> ThreadedFaultProxy:
        self._thread.start()
        self._call(self.proxy.start())
        return self

    def stop(self) -> None:
        if self._thread.is_alive():
            self._call(self.proxy.stop())
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(5.0)
        self._loop.close()

    def set_mode(self, mode: str, **kwargs) -> None:
        self._call(self.proxy.set_mode(mode, **kwargs))

    @property
    def port(self) -> int:
        return self.proxy.port

    def __getattr__(self, name: str):
        return getattr(self.proxy, name)

    def __enter__(self) -> ThreadedFaultProxy:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
