"""Processes a test started, read from Linux /proc: to check that nothing outlives what
killed or stopped it."""

from __future__ import annotations

import contextlib
from pathlib import Path


def children(pid: int) -> set[int]:
    """The live child processes of pid."""
    out: set[int] = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError):
            out |= {int(x) for x in (task / "children").read_text().split()}
    return out


def alive(pids: set[int]) -> set[int]:
    """Those of pids still running (a zombie has ended)."""
    out = set()
    for p in pids:
        with contextlib.suppress(OSError):
            if Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z":
                out.add(p)
    return out
