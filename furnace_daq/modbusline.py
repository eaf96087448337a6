"""One serial bus shared by the Modbus devices on it: the port (or the TCP connection to the
converter in front of it) opened once, one device's read on it at a time.

Why. A serial port opens once (a second open fails with "Resource temporarily unavailable",
the lock pyserial takes), and a half-duplex bus carries one request and its answer at a
time: two devices polled at once on one line would collide. So the devices of one line keep
one client between them, and each device's read holds the line until it is done; a device
that does not answer costs the others its timeout, never their values.

The lines are kept per event loop (each `asyncio.run` is a new set of clients); a line's
client is closed when the last device on it lets go, and opened again by the next that
dials.
"""

from __future__ import annotations

import asyncio
import weakref
from collections.abc import Awaitable, Callable, Hashable
from typing import Any

_LINES: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, dict[Hashable, SharedLine]] = \
    weakref.WeakKeyDictionary()


class SharedLine:
    """The client of one bus, the devices holding it, and the lock that takes turns."""

    def __init__(self, key: Hashable):
        self.key = key
        self.client: Any = None
        self.users: set[object] = set()
        self.turn = asyncio.Lock()
        """Held for one device's whole read."""
        self._opening = asyncio.Lock()

    async def attach(self, user: object, open_client: Callable[[], Awaitable[Any]]
                     ) -> tuple[Any, bool]:
        """The line's client for `user`, opened with `open_client()` when it is not open
        (which may raise); and whether it was opened now."""
        async with self._opening:
            fresh = False
            if self.client is None or not self.client.connected:
                if self.client is not None:
                    self.client.close()
                self.client = None
                self.client = await open_client()
                fresh = True
            self.users.add(user)
            return self.client, fresh

    def detach(self, user: object) -> None:
        """`user` lets go; the last one closes the line."""
        self.users.discard(user)
        if not self.users and self.client is not None:
            self.client.close()
            self.client = None


def shared_line(key: Hashable) -> SharedLine:
    """The line `key` of the running event loop, made on first use."""
    lines = _LINES.setdefault(asyncio.get_running_loop(), {})
    line = lines.get(key)
    if line is None:
        line = lines[key] = SharedLine(key)
    return line

