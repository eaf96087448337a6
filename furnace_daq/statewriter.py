"""The daemon's state files: the latest model (model.json, for other programs) and the refit
chain's state (refit_chain.json, for the next run), written from a thread.

A slow or full disk must not delay a poll, so the files are written by one writer thread
and the poll loop never waits for it. A failure cannot be raised into the loop from there:
it is remembered, and reported as one /daq/events message when it first appears and again
whenever it changes, not at every model.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from furnace_model.log.messages import DaqEvent, DaqEventKind

from .statefile import write_json_atomic

MODEL_FILE = "model.json"
CHAIN_FILE = "refit_chain.json"


class StateWriter:
    def __init__(self, state_dir: Path, report: Callable[[DaqEvent], None]):
        self.state_dir = state_dir
        self.chain_path = state_dir / CHAIN_FILE
        self._report = report
        self._pool: ThreadPoolExecutor | None = None
        self._error: str | None = None  # set by the writer thread
        self._reported: str | None = None

    def start(self) -> None:
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="state-writer")

    def save(self, model: dict, chain: dict | None) -> None:
        """Queue the model (and the chain's state, which has taken this model's window in
        already) for writing; nothing before start()."""
        if self._pool is None:
            return
        files = [(self.state_dir / MODEL_FILE, model)]
        if chain is not None:
            files.append((self.chain_path, chain))
        self._pool.submit(self._write, files)

    def report(self) -> None:
        """Report the latest write's failure if it is news (in the poll loop's thread)."""
        error = self._error
        if error != self._reported:
            self._reported = error
            if error is not None:
                self._report(DaqEvent(DaqEventKind.STATE_WRITE_FAILED,
                                      f"latest model not saved: {error}"))

    def close(self) -> None:
        """Write what is queued, then report how it went."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
        self.report()

    def _write(self, files: list[tuple[Path, dict]]) -> None:
        """In the writer thread; a failure is remembered for report()."""
        for path, value in files:
            try:
                write_json_atomic(path, value)
            except (OSError, ValueError, TypeError) as exc:
                self._error = f"{path}: {getattr(exc, 'strerror', None) or exc}"
                return
        self._error = None
