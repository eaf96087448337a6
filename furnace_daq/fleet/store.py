"""Finished task results under the output directory, so that a rerun (cron every night on
a growing history) computes only what is new or changed.

A result is keyed by its job, its furnace and a hash of what it was computed from: the
identity of every input file (path, size, modification time) and the settings of the task.
A log that grew, a changed refit setting or another furnace description give another key;
a task that failed stores nothing and runs again. One small JSON file per result, written
to a temporary name and renamed, so a run killed while writing leaves no half result.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, is_dataclass
from pathlib import Path

from furnace_model.cli.arguments import version

STORE_DIR = "store"
FORMAT = 1


def task_key(job: str, furnace: str, inputs: list, settings: object) -> str:
    """Hash of the job, furnace, input file identities, settings and the software version
    (another version may fit differently; its results are not this one's)."""
    doc = {"format": FORMAT, "version": version(), "job": job, "furnace": furnace,
           "inputs": inputs, "settings": _plain(settings)}
    text = json.dumps(doc, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def _plain(x: object) -> object:
    if is_dataclass(x) and not isinstance(x, type):
        return {k: _plain(v) for k, v in asdict(x).items()}
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_plain(v) for v in x]
    return x if isinstance(x, int | float | str | bool | None) else str(x)


class Store:
    def __init__(self, out_dir: Path):
        self.root = Path(out_dir) / STORE_DIR

    def _path(self, job: str, furnace: str, key: str) -> Path:
        return self.root / job / furnace / f"{key}.json"

    def get(self, job: str, furnace: str, key: str) -> dict | None:
        path = self._path(job, furnace, key)
        try:
            doc = json.loads(path.read_text())
        except (OSError, ValueError):
            return None
        return doc.get("result") if isinstance(doc, dict) and doc.get("key") == key else None

    def put(self, job: str, furnace: str, key: str, result: dict) -> None:
        path = self._path(job, furnace, key)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps({"key": key, "result": result}, allow_nan=True))
        os.replace(tmp, path)
