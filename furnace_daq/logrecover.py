"""Recovery of MCAP files whose writer died before writing its footer: `logs recover`
rewrites one into a complete file, and the daemon does so at start for every `.part` its
previous run left behind.

What can be read from the front of such a file is `furnace_model.log.salvage`'s job (the
model's readers need it too); this module writes the copies and runs the start-up sweep.
"""

from __future__ import annotations

import fcntl
import os
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from furnace_model.errors import DataError
from furnace_model.log.salvage import has_footer, salvage


def default_output(path: str | Path) -> Path:
    """`furnace-20260302T060000Z.mcap[.part]` -> `furnace-20260302T060000Z.recovered.mcap`."""
    path = Path(path)
    name = path.name
    for suffix in (".part", ".mcap"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
    return path.with_name(name + ".recovered.mcap")


@dataclass
class Recovered:
    source: Path
    out: Path
    messages: int
    start_ns: int
    end_ns: int
    was_complete: bool
    cut: str | None


def recover(path: str | Path, out: str | Path | None = None) -> Recovered:
    """Write every salvageable message of `path` into a new, complete file; the input is never
    touched. The new file is written under a temporary name and renamed when whole."""
    path = Path(path)
    target = Path(out) if out is not None else default_output(path)
    if target.resolve() == path.resolve():
        raise DataError(str(path), "--out must differ from the input: the input is never overwritten")
    if target.exists():
        raise DataError(str(target), "output exists already: remove it or pass another --out")
    got = salvage(path)
    if not got.messages:
        raise DataError(str(path), f"no complete message to recover ({got.cut or 'empty log'})")
    tmp = target.with_name(target.name + ".tmp")
    try:
        with tmp.open("wb") as f:
            writer = Writer(f, compression=CompressionType.ZSTD)
            writer.start(profile="", library="furnace-daq recover")
            schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data)
                          for sid, s in sorted(got.schemas.items())}
            channel_ids = {cid: writer.register_channel(c.topic, c.message_encoding,
                                                        schema_ids.get(c.schema_id, 0),
                                                        dict(c.metadata))
                           for cid, c in sorted(got.channels.items())}
            for m in got.messages:
                writer.add_message(channel_ids[m.channel_id], m.log_time, m.data,
                                   m.publish_time, m.sequence)
            writer.finish()
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise DataError(str(target), f"cannot write: {exc.strerror or exc}") from None
    times = [m.log_time for m in got.messages]
    return Recovered(path, target, len(got.messages), min(times), max(times), got.complete,
                     got.cut)


# -- at daemon start ----------------------------------------------------------------------


def lock_log_dir(log_dir: str | Path, prefix: str) -> int:
    """Take the log directory for this writer (an exclusive `flock` held until the process
    ends) and return the lock's descriptor. Recovery at start deletes `.part` files, which is
    safe only when no other daemon is writing one: a second `furnace-daq run` on the same
    directory and prefix is refused instead."""
    lock = Path(log_dir) / f".{prefix}.lock"
    fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o640)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise DataError(str(lock), "another furnace-daq run is logging to this directory "
                        "with this prefix") from None
    return fd


def recover_leftovers(log_dir: str | Path, prefix: str) -> list[str]:
    """Turn every `<prefix>-*.mcap.part` a dead writer left in `log_dir` into a complete
    `.recovered.mcap` (which retention then counts like any finished file) and delete the
    `.part` once the copy is on disk and reads back whole. A `.part` with nothing in it (cut
    before its first message) is deleted; one that is not MCAP at all is left where it is.
    Returns one line per file for the journal. Interrupted at any point, it is redone at the
    next start without loss: the `.part` goes only after its copy is complete."""
    log_dir = Path(log_dir)
    notes = []
    for tmp in sorted(log_dir.glob(f"{prefix}-*.recovered.mcap.tmp")):
        tmp.unlink(missing_ok=True)  # a copy cut short; its .part is still there
    for part in sorted(log_dir.glob(f"{prefix}-*.mcap.part")):
        notes.append(_recover_leftover(part))
    if notes:
        fsync_dir(log_dir)
    return notes


def _recover_leftover(part: Path) -> str:
    target = default_output(part)
    try:
        if target.exists() and has_footer(target):
            saved = _count_messages(target)  # copied by an earlier start that died after it
            note = f"{part.name}: recovered earlier to {target.name} ({saved} messages)"
        else:
            target.unlink(missing_ok=True)
            try:
                r = recover(part, target)
            except DataError as exc:
                if not _holds_nothing(part):
                    return f"{part.name}: NOT recovered, left in place: {exc}"
                part.unlink()
                return f"{part.name}: deleted, the writer died before its first message"
            saved = _count_messages(target)
            if saved != r.messages:
                return (f"{part.name}: NOT deleted: its copy {target.name} reads back "
                        f"{saved} of {r.messages} messages")
            note = (f"{part.name}: recovered {saved} messages from {_iso(r.start_ns)} to "
                    f"{_iso(r.end_ns)} into {target.name} ({r.cut})")
        part.unlink()
        return note
    except (OSError, McapError) as exc:
        return f"{part.name}: NOT recovered, left in place: {exc}"


def _holds_nothing(part: Path) -> bool:
    try:
        return not salvage(part).messages
    except DataError as exc:  # empty, or cut inside the header: bytes of nothing
        return str(exc).endswith(("empty file: not an MCAP log",
                                  "truncated in the header: not a usable MCAP file"))


def _count_messages(path: Path) -> int:
    with path.open("rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages())


def fsync_dir(path: Path) -> None:
    """A rename or a new file is durable only once its directory entry is."""
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _iso(ns: int) -> str:
    return datetime.fromtimestamp(ns / 1e9, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
