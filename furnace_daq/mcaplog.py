"""The acquisition log's writer: MCAP files written so that a crash, a power cut or a full
disk costs at most a few seconds of data. They are read back, finished or not, by
`furnace_model.log.read`, which the model's commands share (docs/logs.md).

Writing. mcap's `Writer.flush()` closes the chunk being filled and writes it out; the log
calls it, then `os.fsync`, at least every `flush_interval_s`, so a killed writer loses only
the messages since the last flush (`logs recover` restores the rest). A file being written is
named `<prefix>-<UTC start>.mcap.part` and renamed to `.mcap` once its footer is on disk: a
`.mcap` file is always complete, a `.part` left behind is the file of a writer that died.
Files rotate on UTC boundaries of `rotate_s` (hourly files start on the hour) and when they
pass `rotate_bytes`; the oldest finished files beyond `retention_files` are deleted.

Failures. The poll loop must not die because the disk is full or the directory vanished: an
`OSError` abandons the current file (its `.part` stays, recoverable), keeps the messages not
yet known to be on disk plus those still arriving in a bounded buffer (oldest dropped first),
and retries with a new file every `retry_s`. `error` holds the failure while it lasts. When
writing works again, a `/daq/events` message of kind `log_gap` records the outage. A message
may then appear twice, once in the abandoned file and once in the new one; none is lost while
the buffer holds it.

What every file carries. Right after its header, the metadata record of `logmeta` (software
version, furnace, settings, host), repeated in each rotated file so that any one file says
how it was made. CRCs on chunks and on the data section, explicitly (mcap's writer leaves the
data section's off by default): a reader can tell a damaged file from a good one. Every
/daq/status change of state or detail and every /daq/events and /model/events message is
mirrored as a `foxglove.Log` line on /log, its level from the journal priority of its kind.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

from mcap.writer import CompressionType, Writer

from furnace_model.log.messages import DaqEvent, DaqEventKind, DaqStatus, LogLine, ModelEvent
from furnace_model.log.read import PART_SUFFIX, iso_time, recorded_furnace, recorded_signals
from furnace_model.log.schema import (
    DAQ_EVENTS,
    DAQ_STATUS,
    LOG,
    LOG_LEVELS,
    MESSAGE_ENCODING,
    MODEL_EVENTS,
    SCHEMA_ENCODING,
    SignalField,
    topic,
)
from furnace_model.simulation.furnace import Furnace

from .logmeta import METADATA_NAME
from .logrecover import fsync_dir

LIBRARY = "furnace-daq"
_STAMP = "%Y%m%dT%H%M%SZ"


class _Rec(NamedTuple):
    topic: str
    data: bytes
    log_time: int
    publish_time: int


@dataclass
class _OpenFile:
    part: Path
    final: Path
    fh: BinaryIO
    writer: Writer
    start_ns: int
    rotate_at_ns: int | None
    last_sync: float | None  # caller's clock; None before its first maybe_flush
    channels: dict[str, int] = field(default_factory=dict)
    unsynced: list[_Rec] = field(default_factory=list)


class LogWriter:
    """Rotating, crash-tolerant MCAP writer for the poll loop. Never raises on I/O errors;
    see the module docstring for what happens instead."""

    def __init__(self, log_dir: str | Path, prefix: str = "furnace", flush_interval_s: float = 5.0,
                 rotate_s: float = 3600.0, rotate_bytes: int = 256 * 2**20,
                 retention_files: int = 0, file_mode: int = 0o640,
                 max_buffered: int = 20000, retry_s: float = 5.0,
                 metadata: Mapping[str, str] | None = None,
                 event_priority: Mapping[str, int] | None = None,
                 furnace: Furnace | None = None, signals: tuple[SignalField, ...] | None = None):
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", prefix):
            raise ValueError(f"log file prefix {prefix!r}: use letters, digits, '_', '.', '-'")
        self.log_dir = Path(log_dir)
        self.prefix = prefix
        self.flush_interval_s = float(flush_interval_s)
        self.rotate_ns = int(rotate_s * 1e9) if rotate_s and rotate_s > 0 else None
        self.rotate_bytes = int(rotate_bytes) if rotate_bytes and rotate_bytes > 0 else None
        self.retention_files = int(retention_files)
        self.file_mode = file_mode
        self.max_buffered = int(max_buffered)
        self.retry_s = float(retry_s)
        self.metadata: dict[str, str] | None = None if metadata is None else dict(metadata)
        """The `furnace-daq` metadata record of every file opened from now on."""
        self.furnace = furnace if furnace is not None \
            else recorded_furnace(self.metadata, str(log_dir))
        """The furnace the readings are of: the furnace topics' schemas list its fields. By
        default the one the metadata record describes (the paper's without one)."""
        self.signals = signals if signals is not None else recorded_signals(self.metadata)
        """The register map's extra points, the fields of /furnace/signals: by default
        those the metadata record lists."""
        self.event_priority = dict(event_priority or {})
        """Journal (sd-daemon) priority of each event kind: the level of its /log line."""
        self.listeners: list[Callable[[str, bytes, int], None]] = []
        """Called with (topic, encoded message, log time in ns) for every message queued,
        /log lines included (the live view, furnace_daq.liveview). A listener's failure is
        its own: it never stops the log."""
        self._last_status: tuple[object, object] | None = None
        # Chunks small against the size limit, so a file overshoots it by little.
        self._chunk_size = min(2**20, max(4096, (self.rotate_bytes or 2**22) // 8))
        self.error: str | None = None
        """The failure that stops the log right now (None while writing works)."""
        self.dropped = 0
        """Messages dropped because the buffer overflowed during a failure, since start."""
        self._file: _OpenFile | None = None
        self._pending: deque[_Rec] = deque()
        self._retry_at = 0.0
        self._outage: tuple[int, str] | None = None  # (log time of first unwritten, error)
        self._dropped_in_outage = 0
        self._now: float | None = None  # the caller's monotonic clock at its last maybe_flush

    @property
    def current_path(self) -> Path | None:
        """The file being written (its `.part` name), or None between files."""
        return self._file.part if self._file else None

    def write(self, topic: str, message: dict, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """Queue one message and write it if the log is healthy. `message` must be
        JSON-serialisable (numpy scalars and arrays are accepted; NaN becomes null)."""
        log_time_ns = int(log_time_ns)
        pub = log_time_ns if publish_time_ns is None else int(publish_time_ns)
        self._queue(_Rec(topic, encode(message), log_time_ns, pub))
        line = self._log_line(topic, message, log_time_ns)
        if line is not None:
            self._queue(_Rec(LOG, encode(line), log_time_ns, log_time_ns))
        self._drain(self._now if self._now is not None else time.monotonic())

    def _log_line(self, name: str, message: dict, log_time_ns: int) -> dict | None:
        """The /log line of a status change or an event, or None for other messages (and
        for a periodic status that repeats the last one)."""
        if name == DAQ_STATUS:
            status = DaqStatus.from_json(message)
            key = (status.state, status.detail)
            if key == self._last_status:
                return None
            self._last_status = key
            level = LOG_LEVELS["info" if status.state == "connected" else "warning"]
            text = f"{status.state}: {status.detail}"
        elif name in (DAQ_EVENTS, MODEL_EVENTS):
            event = DaqEvent.from_json(message) if name == DAQ_EVENTS else \
                ModelEvent.from_json(message)
            level = _level(self.event_priority.get(event.kind, 5))
            text = f"{event.kind}: {event.detail}"
        else:
            return None
        return LogLine(log_time_ns, level, text, LIBRARY, name).to_json()

    def maybe_flush(self, now_monotonic: float) -> None:
        """Close the chunk and fsync when the flush interval has passed; retry a failed log.
        The writer keeps time on this clock only, whichever monotonic clock the caller uses."""
        if self._now is None:  # times so far came from time.monotonic(): retry on this clock
            self._retry_at = -math.inf
        self._now = now_monotonic
        self._drain(now_monotonic)
        f = self._file
        if f is not None and (f.last_sync is None
                              or now_monotonic - f.last_sync >= self.flush_interval_s):
            self._sync(now_monotonic)

    def close(self) -> None:
        """Write what is buffered (one last try) and finish the file with its footer."""
        self._retry_at = -math.inf
        self._drain(self._now if self._now is not None else time.monotonic())
        if self._file is not None:
            self._finish()
        if self._pending:
            self.error = (f"{self.error or 'log not writable'}; {len(self._pending)} buffered "
                          f"messages lost at close")
            self._pending.clear()

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals -------------------------------------------------------------------------

    def _queue(self, rec: _Rec) -> None:
        for listener in self.listeners:
            with contextlib.suppress(Exception):
                listener(rec.topic, rec.data, rec.log_time)
        self._pending.append(rec)
        while len(self._pending) > self.max_buffered:
            self._pending.popleft()
            self.dropped += 1
            self._dropped_in_outage += 1

    def _drain(self, now: float) -> None:
        while self._pending:
            rec = self._pending[0]
            f = self._file
            if f is not None and self._must_rotate(f, rec):
                self._finish()
                f = None
            if f is None:
                if now < self._retry_at:
                    return
                f = self._open(rec.log_time, now)
                if f is None:
                    return
            try:
                channel = f.channels.get(rec.topic)
                if channel is None:
                    t = topic(rec.topic, self.furnace, self.signals)
                    schema_id = f.writer.register_schema(t.schema_name, SCHEMA_ENCODING,
                                                         t.schema_bytes())
                    channel = f.writer.register_channel(rec.topic, MESSAGE_ENCODING, schema_id)
                    f.channels[rec.topic] = channel
                f.writer.add_message(channel, rec.log_time, rec.data, rec.publish_time)
            except OSError as exc:
                self._fail(exc, now)
                return
            f.unsynced.append(self._pending.popleft())
            if len(f.unsynced) >= self.max_buffered:
                self._sync(now)
        if self._outage is not None and self._file is not None:
            self._note_outage()

    def _must_rotate(self, f: _OpenFile, rec: _Rec) -> bool:
        if f.rotate_at_ns is not None and rec.log_time >= f.rotate_at_ns:
            return True
        return self.rotate_bytes is not None and f.fh.tell() >= self.rotate_bytes

    def _open(self, start_ns: int, now: float) -> _OpenFile | None:
        stamp = datetime.fromtimestamp(start_ns / 1e9, UTC).strftime(_STAMP)
        part: Path | None = None
        fh: BinaryIO | None = None
        try:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            part, final, fd = self._create(stamp)
            fh = os.fdopen(fd, "wb")
            os.fchmod(fh.fileno(), self.file_mode)  # the umask must not change the mode
            writer = Writer(fh, chunk_size=self._chunk_size, compression=CompressionType.ZSTD,
                            enable_crcs=True, enable_data_crcs=True)
            writer.start(profile="", library=LIBRARY)
            if self.metadata is not None:
                writer.add_metadata(METADATA_NAME, self.metadata)
            fh.flush()
            fsync_dir(self.log_dir)
        except OSError as exc:
            if fh is not None:
                with contextlib.suppress(OSError):
                    fh.close()
            if part is not None:
                with contextlib.suppress(OSError):
                    part.unlink()
            self._fail(exc, now)
            return None
        rotate_at = None
        if self.rotate_ns is not None:
            rotate_at = (start_ns // self.rotate_ns + 1) * self.rotate_ns
        self._file = _OpenFile(part, final, fh, writer, start_ns, rotate_at, self._now)
        return self._file

    def _create(self, stamp: str) -> tuple[Path, Path, int]:
        for n in range(1000):
            base = f"{self.prefix}-{stamp}" + (f"-{n}" if n else "")
            final = self.log_dir / f"{base}.mcap"
            part = self.log_dir / f"{base}.mcap{PART_SUFFIX}"
            if final.exists():
                continue
            try:
                fd = os.open(part, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC,
                             self.file_mode)
            except FileExistsError:
                continue
            return part, final, fd
        raise FileExistsError(f"no free file name for {self.prefix}-{stamp} in {self.log_dir}")

    def _sync(self, now: float) -> None:
        f = self._file
        if f is None:
            return
        try:
            f.writer.flush()
            os.fsync(f.fh.fileno())
        except OSError as exc:
            self._fail(exc, now)
            return
        f.unsynced.clear()
        f.last_sync = self._now

    def _finish(self) -> None:
        f = self._file
        if f is None:
            return
        try:
            f.writer.finish()
            f.fh.flush()
            os.fsync(f.fh.fileno())
            f.fh.close()
            os.rename(f.part, f.final)
            fsync_dir(self.log_dir)
        except OSError as exc:
            self._fail(exc, self._now if self._now is not None else time.monotonic())
            return
        self._file = None
        self._apply_retention()

    def _fail(self, exc: OSError, now: float) -> None:
        where = exc.filename or self.log_dir
        self.error = f"{where}: {exc.strerror or exc}"
        f = self._file
        self._file = None
        if f is not None:
            with contextlib.suppress(OSError, ValueError):
                f.fh.close()
            # Not known to be on disk: write them again into the next file.
            self._pending.extendleft(reversed(f.unsynced))
            while len(self._pending) > self.max_buffered:
                self._pending.popleft()
                self.dropped += 1
                self._dropped_in_outage += 1
        if self._outage is None:
            first = self._pending[0].log_time if self._pending else time.time_ns()
            self._outage = (first, self.error)
        self._retry_at = now + self.retry_s

    def _note_outage(self) -> None:
        first_ns, error = self._outage
        self._outage = None
        self.error = None
        dropped, self._dropped_in_outage = self._dropped_in_outage, 0
        now_ns = time.time_ns()
        self.write(DAQ_EVENTS, DaqEvent(
            DaqEventKind.LOG_GAP,
            (f"the log could not be written from {iso_time(first_ns)} to {iso_time(now_ns)}: "
             f"{error}; {dropped} messages dropped"),
            error=error, dropped=dropped).to_json(), now_ns)

    def _apply_retention(self) -> None:
        if self.retention_files <= 0:
            return
        finished = finished_files(self.log_dir, self.prefix)
        for old in finished[: max(0, len(finished) - self.retention_files)]:
            try:
                old.unlink()
            except FileNotFoundError:
                pass
            except OSError as exc:
                self.error = f"{old}: cannot delete for retention: {exc.strerror or exc}"


def _level(priority: int) -> int:
    """foxglove.LogLevel of an sd-daemon priority: err and worse error, warning warning,
    notice and info info, debug debug."""
    if priority <= 3:
        return LOG_LEVELS["error"]
    if priority == 4:
        return LOG_LEVELS["warning"]
    return LOG_LEVELS["info"] if priority <= 6 else LOG_LEVELS["debug"]


def finished_files(log_dir: str | Path, prefix: str) -> list[Path]:
    """The finished log files of one writer, oldest first (by the start time in the name)."""
    pattern = re.compile(rf"{re.escape(prefix)}-(\d{{8}}T\d{{6}}Z)(?:-(\d+))?(?:\.recovered)?\.mcap")
    found = []
    for p in Path(log_dir).iterdir():
        m = pattern.fullmatch(p.name)
        if m and p.is_file():
            found.append(((m.group(1), int(m.group(2) or 0), p.name), p))
    return [p for _, p in sorted(found)]


def encode(message: dict) -> bytes:
    """JSON bytes of one message. A non-finite float is 'missing': a field holding one is
    left out, an array item becomes null (bare NaN is not JSON, and Foxglove and most
    parsers refuse it)."""
    try:
        text = json.dumps(message, separators=(",", ":"), allow_nan=False, default=_plain)
    except ValueError:
        text = json.dumps(_finite(json.loads(json.dumps(message, default=_plain))),
                          separators=(",", ":"), allow_nan=False)
    return text.encode()


def _plain(obj: Any) -> Any:
    if hasattr(obj, "tolist"):  # numpy scalars and arrays
        return obj.tolist()
    raise TypeError(f"cannot log a {type(obj).__name__} as JSON")


def _finite(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):  # a field that is not a number is left out (schemas hold no null)
        return {k: _finite(v) for k, v in obj.items()
                if not (isinstance(v, float) and not math.isfinite(v))}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    return obj
