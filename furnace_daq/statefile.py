"""Small JSON files other programs read while the daemon writes them (the latest model):
written whole or not at all, so a reader never sees half a file, even after a power cut."""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path


def write_json_atomic(path: str | Path, value: object) -> None:
    """Write to a temporary file in the same directory, fsync it, rename it over `path`,
    fsync the directory. Raises OSError; the previous file stays intact on any failure."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    data = (json.dumps(value, indent=2, allow_nan=False, default=_plain) + "\n").encode()
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o644)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    dfd = os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)


def _plain(obj: object) -> object:
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"cannot write a {type(obj).__name__} as JSON")
