"""The live view: a Foxglove WebSocket server inside the daemon (config `live_view:`), so an
engineer watches the furnace in Foxglove while it is logged, without waiting for a file.

It shows exactly what the log holds: the `LogWriter` hands it every message it queues (see
`LogWriter.listeners`), already encoded, with the log time as the message time and the
same topic and JSON schema as the MCAP channel. The server is read-only: it advertises no
capability (no client publishing, services, parameters), so a client cannot write anything
to the daemon or, through it, to the PLC.

Protocol. foxglove-sdk's server speaks the WebSocket subprotocol `foxglove.sdk.v1` only: a
client that offers only `foxglove.websocket.v1` (older Foxglove and Lichtblick releases,
tools on @foxglove/ws-protocol before it offered the new name) is refused during the
handshake with "400 Bad Request" (docs/operations.md, "Live view").

The library logs through Python's `logging` (its Rust core bridged by pyo3-log into the
logger `foxglove`): with a journal, those lines go to it with a priority prefix like the
daemon's own, never above warning, since a client's failure is not the daemon's; a
refused handshake says which subprotocol to offer.

Failures. A port that cannot be bound stops the daemon at start with an error naming
`live_view.port`. Once running, nothing the live view does may stop logging: `send` never
raises; its first failure is kept in `error` and the view goes quiet.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from furnace_model.errors import FurnaceError
from furnace_model.log.schema import (
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    SignalField,
    topic,
    topics,
)
from furnace_model.simulation.furnace import Furnace

from .journal import WARNING, Journal, JournalHandler

SUBPROTOCOL = "foxglove.sdk.v1"
"""The one WebSocket subprotocol the server accepts (foxglove-sdk 0.30)."""

LIBRARY_LOGGER = "foxglove"
"""Where foxglove-sdk's log records arrive in Python's logging."""


@dataclass(frozen=True)
class LiveViewConfig:
    """Where the server listens. Loopback unless configured: a plant network reaches it
    through an SSH tunnel or a reverse proxy, never by accident."""

    host: str = "127.0.0.1"
    port: int = 8765


class LiveView:
    """A running server and its channels, one per log topic."""

    def __init__(self, config: LiveViewConfig, name: str = "furnace-daq", where: str = "",
                 *, furnace: Furnace, signals: tuple[SignalField, ...] = (),
                 journal: Journal | None = None):
        self.furnace = furnace
        self.signals = signals
        # before the library starts: its bridge reads the logger's level when it first logs
        self._handler = None if journal is None else _route_library_logs(journal)
        import foxglove

        self._foxglove = foxglove
        # A context of its own: the server sees only these channels, and nothing else in the
        # process (another sink, the global context) sees them.
        self._context = foxglove.Context()
        self._channels: dict[str, foxglove.Channel] = {}
        self.error: str | None = None
        """The failure that silenced the view (None while it works)."""
        try:
            self._server = foxglove.start_server(
                name=name, host=config.host, port=config.port, capabilities=[],
                services=None, context=self._context)
        except (RuntimeError, OSError, ValueError, TypeError, OverflowError) as exc:
            self._unroute_library_logs()
            key = f"{where}: live_view.port" if where else "live_view.port"
            raise FurnaceError(f"{key}: cannot serve the live view on "
                               f"{config.host}:{config.port}: {_reason(exc)}") from None
        self.host = config.host
        self.port = int(self._server.port)
        # every topic of the contract, even one not yet written
        for name_ in topics(furnace, signals):
            self._channel(name_)

    @property
    def url(self) -> str:
        """What to type into Foxglove's Open connection → Foxglove WebSocket."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def send(self, name: str, data: bytes, log_time_ns: int) -> None:
        """Forward one encoded log message. Never raises (see the module docstring)."""
        if self.error is not None:
            return
        try:
            self._channel(name).log(data, log_time=int(log_time_ns))
        except Exception as exc:  # the log must go on whatever the server does
            self.error = f"live view stopped: {_reason(exc)}"

    def close(self) -> None:
        """Stop the server (clients see the connection close)."""
        try:
            self._server.stop()
        except Exception as exc:  # stopping must not hide the daemon's own exit status
            self.error = self.error or f"live view stop: {_reason(exc)}"
        self._unroute_library_logs()

    def _unroute_library_logs(self) -> None:
        if self._handler is not None:
            logger = logging.getLogger(LIBRARY_LOGGER)
            logger.removeHandler(self._handler)
            logger.propagate, self._handler = True, None
            logger.setLevel(logging.NOTSET)

    def _channel(self, name: str):
        channel = self._channels.get(name)
        if channel is None:
            t = topic(name, self.furnace, self.signals)
            schema = self._foxglove.Schema(name=t.schema_name, encoding=SCHEMA_ENCODING,
                                           data=t.schema_bytes())
            channel = self._foxglove.Channel(name, schema=schema,
                                             message_encoding=MESSAGE_ENCODING,
                                             context=self._context)
            self._channels[name] = channel
        return channel


class _HandshakeHint(logging.Filter):
    """A refused handshake's line says what the server wants: the library says only
    "Dropping client ADDRESS: handshake failed"."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.getMessage().endswith("handshake failed"):
            record.msg = (f"{record.getMessage()} (the live view accepts WebSocket clients "
                          f"that offer the subprotocol {SUBPROTOCOL}; see docs/operations.md, "
                          "\"Live view\")")
            record.args = None
        return True


def _route_library_logs(journal: Journal) -> JournalHandler:
    """The library's records, from INFO up (clients coming and going, refused handshakes),
    to the journal only: not to the root logger's stderr, unprefixed."""
    logger = logging.getLogger(LIBRARY_LOGGER)
    handler = JournalHandler(journal, "live view", most=WARNING)
    handler.addFilter(_HandshakeHint())
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False
    return handler


def _reason(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.removeprefix("FoxgloveError: ")
