"""Reading an MCAP file whose writer died before writing its footer.

`make_reader` needs the footer and summary at the end of the file; a killed or powered-off
writer leaves none. `StreamReader` reads records front to back and stops at the cut: every
chunk that was closed (the log writer closes one at least every flush interval) comes back
whole, the chunk being filled when the writer died is lost, and a half-written record at the
end is detected (its length runs past the end of the file) and dropped, never half-decoded.

Here rather than beside the daemon's writer because reading needs it as much as recovery:
`fit` on a log directory reads a dead writer's `.mcap.part` through it, and `furnace_model`
never imports `furnace_daq` (docs/logs.md).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Footer, Header, Message, Schema
from mcap.stream_reader import StreamReader

from ..errors import DataError

MAGIC = b"\x89MCAP0\r\n"
_FOOTER_RECORD_SIZE = 1 + 8 + 20


@dataclass
class Salvage:
    """What could be read from the front of a file."""

    path: Path
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: list[Message] = field(default_factory=list)
    complete: bool = False  # the footer was reached
    cut: str | None = None  # why reading stopped before the footer
    good_bytes: int = 0  # end of the last complete record


def has_footer(path: str | Path) -> bool:
    """Whether the file ends with a footer record and the closing magic: a cheap test of
    'the writer finished this file', without reading it."""
    path = Path(path)
    size = _size(path)
    if size < 2 * len(MAGIC) + _FOOTER_RECORD_SIZE:
        return False
    with path.open("rb") as f:
        f.seek(size - len(MAGIC) - _FOOTER_RECORD_SIZE)
        tail = f.read()
    opcode, length = struct.unpack_from("<BQ", tail)
    return tail.endswith(MAGIC) and opcode == Opcode.FOOTER and length == 20


def salvage(path: str | Path) -> Salvage:
    """Read every complete record up to the footer or the cut. Raises DataError when the file
    is missing, empty, not MCAP, or cut inside its header (nothing to salvage)."""
    path = Path(path)
    size = _size(path)
    if size == 0:
        raise DataError(str(path), "empty file: not an MCAP log")
    out = Salvage(path)
    with path.open("rb") as f:
        head = f.read(len(MAGIC))
        if head != MAGIC:
            if len(head) < len(MAGIC) and MAGIC.startswith(head):
                raise DataError(str(path), "truncated in the header: not a usable MCAP file")
            raise DataError(str(path), "not an MCAP file (bad magic bytes)")
        f.seek(0)
        # Chunk CRCs are checked: a chunk of zeros left by a power cut must not pass as data.
        records = StreamReader(f, validate_crcs=True, record_size_limit=1 << 31).records
        try:
            first = next(records)
        except (McapError, struct.error, ValueError, zlib.error, UnicodeDecodeError) as exc:
            raise DataError(str(path), "truncated in the header: not a usable MCAP file"
                            if _is_cut(exc) else f"unreadable header: {exc}") from None
        except StopIteration:
            first = None
        if not isinstance(first, Header):
            raise DataError(str(path), "truncated in the header: not a usable MCAP file")
        out.good_bytes = f.tell()
        try:
            for record in records:
                if isinstance(record, Schema):
                    out.schemas[record.id] = record
                elif isinstance(record, Channel):
                    out.channels[record.id] = record
                elif isinstance(record, Message):
                    out.messages.append(record)
                elif isinstance(record, Footer):
                    out.complete = True
                out.good_bytes = f.tell()
        except (McapError, struct.error, ValueError, zlib.error, UnicodeDecodeError) as exc:
            out.cut = (f"file ends inside a record at byte {out.good_bytes} of {size}"
                       if _is_cut(exc) else
                       f"unreadable record after byte {out.good_bytes} of {size}: {exc}")
    if not out.complete and out.cut is None:
        out.cut = f"no footer: the file ends after byte {out.good_bytes}"
    # A message whose channel record was lost cannot be decoded: keep what can be.
    out.messages = [m for m in out.messages if m.channel_id in out.channels]
    return out


def _is_cut(exc: BaseException) -> bool:
    return type(exc).__name__ == "EndOfFile" or isinstance(exc, struct.error)


def _size(path: Path) -> int:
    try:
        if path.is_dir():
            raise DataError(str(path), "is a directory, not an MCAP file")
        return path.stat().st_size
    except FileNotFoundError:
        raise DataError(str(path), "file not found") from None
    except OSError as exc:
        raise DataError(str(path), f"cannot read: {exc.strerror or exc}") from None
