"""A TCP proxy on loopback whose replies can be held back: a PLC (or server) that stops
answering while its connection stays up, for the tests of a slow device of any protocol
that speaks TCP (the Modbus tests have the fuller faultproxy, which parses MBAP frames)."""

from __future__ import annotations

import asyncio
import contextlib


class StallingProxy:
    """Forwards 127.0.0.1:`port` to 127.0.0.1:`target_port`; while `stalled`, what the
    target sends is dropped (requests still go through, replies never come)."""

    def __init__(self, target_port: int):
        self.target_port = target_port
        self.stalled = False
        self.port = 0
        self._server: asyncio.Server | None = None
        self._writers: list[asyncio.StreamWriter] = []

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._client, "127.0.0.1", 0)
        self.port = self._server.sockets[0].getsockname()[1]

    async def _client(self, reader, writer) -> None:
        up_r, up_w = await asyncio.open_connection("127.0.0.1", self.target_port)
        self._writers += [writer, up_w]

        async def pipe(src, dst, held):
            with contextlib.suppress(OSError, asyncio.CancelledError):
                while data := await src.read(65536):
                    if not (held and self.stalled):
                        dst.write(data)
                        await dst.drain()
            dst.close()

        await asyncio.gather(pipe(reader, up_w, False), pipe(up_r, writer, True))

    async def stop(self) -> None:
        for w in self._writers:
            w.close()
        if self._server is not None:
            self._server.close()
