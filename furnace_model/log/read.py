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

from ..errors import ConfigError, DataError
from ..simulation.furnace import PAPER, Furnace
from ..simulation.furnacefile import furnace_from_node
from .salvage import has_footer, salvage
from .schema import SignalField

LOG_SUFFIX = ".mcap"
PART_SUFFIX = ".part"
"""A file being written is `<prefix>-<UTC start>.mcap.part`, renamed to `.mcap` once whole."""
METADATA_NAME = "furnace-daq"
"""The metadata record every log file carries (furnace_daq.logmeta writes it)."""


def read_metadata(paths: Iterable[str | Path]) -> dict[str, str] | None:
    """The first `furnace-daq` metadata record found in `paths`, or None when none has one
    (logs written before the record existed). The writer puts the record right after the
    header, so only the front of each file is read, finished or cut alike."""
    from mcap.records import Header, Metadata
    from mcap.stream_reader import StreamReader

    for path in paths:
        try:
            with open(path, "rb") as fh:
                for record in StreamReader(fh, emit_chunks=True).records:
                    if isinstance(record, Metadata) and record.name == METADATA_NAME:
                        return dict(record.metadata)
                    if not isinstance(record, Header | Metadata):
                        break
        except Exception:  # noqa: BLE001 - a cut or damaged file: try the next one
            continue
    return None


PAPER_RECORD_NAME = "paper-3zone"
"""The name the metadata record has always given the paper's furnace."""


def furnace_record(furnace: Furnace) -> dict:
    """The `furnace` entry of a log's metadata record: the full description
    (`Furnace.describe()`), each zone's thermocouples listed by name as the log's fields
    name them (the record's shape since before it carried links; docs/logs.md), the paper's
    furnace under the name the record always gave it."""
    record = furnace.describe()
    if furnace == PAPER:
        record["name"] = PAPER_RECORD_NAME
    names = iter(furnace.sensors)
    for zone in record["zones"]:
        zone["thermocouples"] = [next(names) for _ in range(zone["thermocouples"])]
    return record


def recorded_furnace(metadata: dict[str, str] | None, where: str) -> Furnace:
    """The furnace a log's metadata record describes (`furnace_record`), checked as a
    description file is. A log without the record, or one written before the record held
    the full description (then it named the paper's furnace), is of the paper's furnace."""
    if not metadata or "furnace" not in metadata:
        return PAPER
    try:
        value = json.loads(metadata["furnace"])
    except ValueError:
        raise DataError(where, "the metadata record's furnace entry is not JSON") from None
    if not isinstance(value, dict) or "links" not in value:
        return PAPER
    from ..config import Node

    if value.get("name") == PAPER_RECORD_NAME:
        value = {**value, "name": PAPER.name}
    zones = value.get("zones")
    if isinstance(zones, list):  # thermocouples by name -> their count, as a description has
        value = {**value, "zones": [
            {**z, "thermocouples": len(z["thermocouples"])}
            if isinstance(z, dict) and isinstance(z.get("thermocouples"), list) else z
            for z in zones]}
    try:
        furnace = furnace_from_node(Node(value, f"{where} (recorded furnace)"), "furnace")
    except ConfigError as exc:
        raise DataError(where, f"the recorded furnace description is not valid: {exc}") from None
    if furnace_record(furnace)["zones"] != json.loads(metadata["furnace"])["zones"]:
        raise DataError(where, "the recorded furnace's thermocouple names are not "
                               "<zone>_<k> of its zones")
    return furnace


def recorded_signals(metadata: dict[str, str] | None) -> tuple[SignalField, ...]:
    """The extra named points of the register map a log was written with, as its metadata
    record lists them (none for a map without signals, and for a log without the record)."""
    if not metadata or "signals" not in metadata:
        return ()
    try:
        value = json.loads(metadata["signals"])
    except ValueError:
        return ()
    if not isinstance(value, list):
        return ()
    return tuple(SignalField(str(v["name"]), str(v.get("unit", "")), bool(v.get("bit", False)),
                             bool(v.get("text", False)))
                 for v in value if isinstance(v, dict) and "name" in v)


def log_furnace(paths: Iterable[str | Path], where: str | None = None) -> Furnace:
    """The furnace of a log (one file or a rotated series): from its metadata record."""
    paths = [Path(p) for p in paths]
    return recorded_furnace(read_metadata(paths),
                            where if where is not None else ", ".join(map(str, paths)))


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
