"""Reading the acquisition log: MCAP files merged in log-time order, whether or not their
writer finished them.

Reading. `read_messages` merges files in log-time order; a finished file is read through its
index, an unfinished one front to back up to the cut. A week of 1 Hz data is two million
messages, so the finished-file path parses the chunks itself (one struct unpack per message
instead of mcap's record objects and per-message priority queue), skips the topics not
asked for before decoding, reuses the decoded dict of a message whose bytes repeat those of
the one before on its topic (burner states change rarely), and chains files whose time spans
do not overlap instead of merging them message by message.

Here rather than beside the daemon's writer (`furnace_daq.mcaplog`) because both packages read
logs: the daemon's replay, refit and `logs` commands, and the model's `fit`, `validate` and
`diagnose`; `furnace_model` never imports `furnace_daq` (docs/logs.md).
"""

from __future__ import annotations

import heapq
import json
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import NamedTuple

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Chunk, Message

from .errors import DataError
from .logsalvage import has_footer, salvage

LOG_SUFFIX = ".mcap"
PART_SUFFIX = ".part"
"""A file being written is `<prefix>-<UTC start>.mcap.part`, renamed to `.mcap` once whole."""


def iso_time(ns: int) -> str:
    """A log time (ns since the epoch, UTC) as ISO 8601 to the millisecond, as messages and
    exported tables show it."""
    return datetime.fromtimestamp(ns / 1e9, UTC).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


class RawMessage(NamedTuple):
    topic: str
    message: Message


@dataclass
class LogFile:
    """One log file opened for reading; `complete` tells whether its writer finished it."""

    path: Path
    complete: bool
    cut: str | None = None  # for an unfinished file: where and why reading stops
    _salvaged: list[RawMessage] | None = None

    def raw(self) -> Iterator[RawMessage]:
        """Messages in log-time order, undecoded."""
        if self._salvaged is not None:
            yield from self._salvaged
            return
        try:
            with self.path.open("rb") as f:
                reader = make_reader(f)
                for _, channel, msg in reader.iter_messages(log_time_order=True):
                    yield RawMessage(channel.topic, msg)
        except (McapError, OSError, ValueError, EOFError) as exc:
            raise DataError(str(self.path), f"unreadable MCAP file: {exc}") from None

    def records(self, wanted: set[str] | None = None) -> Iterator[tuple[str, bytes, int, int]]:
        """(topic, data, log_time, publish_time) in log-time order, only the topics wanted."""
        if self._salvaged is not None:
            for raw in self._salvaged:
                if wanted is None or raw.topic in wanted:
                    m = raw.message
                    yield raw.topic, bytes(m.data), m.log_time, m.publish_time
            return
        try:
            records = _chunk_records(self.path, wanted)
        except (McapError, OSError, ValueError, EOFError, struct.error,
                zstandard.ZstdError, RuntimeError) as exc:
            raise DataError(str(self.path), f"unreadable MCAP file: {exc}") from None
        yield from records

    def span(self) -> tuple[int, int]:
        """(first, last) log time of the file's messages, from its index when it has one."""
        if self._salvaged is not None:
            times = [r.message.log_time for r in self._salvaged]
            return (min(times), max(times)) if times else (0, 0)
        try:
            with self.path.open("rb") as f:
                summary = make_reader(f).get_summary()
        except (McapError, OSError, ValueError, EOFError) as exc:
            raise DataError(str(self.path), f"unreadable MCAP file: {exc}") from None
        stats = None if summary is None else summary.statistics
        if stats is None or stats.message_count == 0:
            return (0, 0)
        return stats.message_start_time, stats.message_end_time


def open_log(path: str | Path) -> LogFile:
    """Open a log file, finished or not; raises DataError naming the file when it is not a
    readable MCAP log."""
    path = Path(path)
    if has_footer(path):
        return LogFile(path, True)
    got = salvage(path)  # raises DataError for missing, empty, non-MCAP, cut in the header
    raws = [RawMessage(got.channels[m.channel_id].topic, m) for m in got.messages]
    raws.sort(key=lambda r: r.message.log_time)
    return LogFile(path, got.complete, got.cut, raws)


def decode(path: Path, raw: RawMessage) -> dict:
    return _json(path, raw.topic, raw.message.data, raw.message.log_time)


def read_messages(paths: Iterable[str | Path] | str | Path,
                  topics: Iterable[str] | None = None
                  ) -> Iterator[tuple[str, dict, int, int]]:
    """(topic, message, log_time_ns, publish_time_ns) from every file, merged in log-time
    order; files whose writer died are read up to the cut. Treat the messages as read-only:
    consecutive identical messages on a topic may be one and the same dict."""
    if isinstance(paths, str | Path):
        paths = [paths]
    wanted = None if topics is None else set(topics)
    logs = [open_log(p) for p in paths]
    spans = [log.span() for log in logs]
    order = sorted(range(len(logs)), key=lambda i: spans[i])
    disjoint = all(spans[a][1] <= spans[b][0] for a, b in zip(order, order[1:], strict=False))
    streams = [_decoded(logs[i], wanted) for i in order]
    if disjoint:
        for stream in streams:
            yield from stream
    else:
        yield from heapq.merge(*streams, key=lambda item: item[2])


def _decoded(log: LogFile, wanted: set[str] | None) -> Iterator[tuple[str, dict, int, int]]:
    last: dict[str, tuple[bytes, dict]] = {}
    for name, data, log_ns, pub_ns in log.records(wanted):
        prev = last.get(name)
        if prev is not None and prev[0] == data:
            value = prev[1]
        else:
            value = _json(log.path, name, data, log_ns)
            last[name] = (data, value)
        yield name, value, log_ns, pub_ns


_DECODER = json.JSONDecoder()


def _json(path: Path, name: str, data: bytes, log_ns: int) -> dict:
    try:
        value = _DECODER.decode(data.decode())
    except (ValueError, UnicodeDecodeError) as exc:
        raise DataError(str(path), f"message on {name} at {iso_time(log_ns)} "
                        f"is not JSON: {exc}") from None
    if not isinstance(value, dict):
        raise DataError(str(path), f"message on {name} at {iso_time(log_ns)} "
                        "is not a JSON object")
    return value


_RECORD = struct.Struct("<BQ")  # opcode, content length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_OP_MESSAGE = 0x05


def _chunk_records(path: Path, wanted: set[str] | None
                   ) -> list[tuple[str, bytes, int, int]]:
    """Every message of a finished file as (topic, data, log_time, publish_time), in
    log-time order (stable: equal times keep the order they were written in)."""
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
        if summary is None or not summary.chunk_indexes:
            return [(raw.topic, bytes(raw.message.data), raw.message.log_time,
                     raw.message.publish_time) for raw in LogFile(path, True).raw()
                    if wanted is None or raw.topic in wanted]
        channels = {cid: ch.topic for cid, ch in summary.channels.items()
                    if wanted is None or ch.topic in wanted}
        out: list[tuple[str, bytes, int, int]] = []
        for index in sorted(summary.chunk_indexes,
                            key=lambda c: (c.message_start_time, c.chunk_start_offset)):
            f.seek(index.chunk_start_offset + 1 + 8)
            chunk = Chunk.read(ReadDataStream(f))
            buf = _decompress(chunk)
            pos, end = 0, len(buf)
            while pos < end:
                op, length = _RECORD.unpack_from(buf, pos)
                pos += 9
                if op == _OP_MESSAGE:
                    cid, _seq, log_ns, pub_ns = _MESSAGE.unpack_from(buf, pos)
                    name = channels.get(cid)
                    if name is not None:
                        out.append((name, buf[pos + 22:pos + length], log_ns, pub_ns))
                pos += length
    if any(a[2] > b[2] for a, b in zip(out, out[1:], strict=False)):
        out.sort(key=lambda r: r[2])
    return out


def _decompress(chunk: Chunk) -> bytes:
    if chunk.compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(chunk.data,
                                                       max_output_size=chunk.uncompressed_size)
    if chunk.compression == "lz4":
        return lz4.frame.decompress(chunk.data)
    if chunk.compression == "":
        return bytes(chunk.data)
    raise McapError(f"unsupported chunk compression '{chunk.compression}'")
