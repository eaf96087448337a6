"""The metadata record every log file carries (CONTRACTS.md section 2): which software wrote
it, for which furnace, with which settings, on which host; so that a log alone says how it
was made, and a replay can fit it as the daemon did without the daemon's config file.

One MCAP metadata record named `furnace-daq` per file (each rotated file repeats it), its
values strings as MCAP requires: plain text, or JSON for the structured ones (docs/logs.md).
"""

from __future__ import annotations

import dataclasses
import json
import socket
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from furnace_model.log.read import (
    METADATA_NAME,
    furnace_record,
    read_metadata,
    recorded_furnace,
    recorded_signals,
)
from furnace_model.log.schema import SignalField
from furnace_model.simulation.furnace import Furnace

__all__ = ["METADATA_NAME", "build_metadata", "read_metadata", "recorded_furnace",
           "recorded_signals"]
SECRET_WORDS = ("password", "secret", "token")
"""A config key containing one of these is left out of the recorded config."""


def plain(value: Any) -> Any:
    """A dataclass config as JSON-ready mappings and lists, keys that name a secret dropped:
    a log is handed around more freely than the config file."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()
                if not any(w in str(k).lower() for w in SECRET_WORDS)}
    if isinstance(value, list | tuple | set | frozenset):
        return [plain(v) for v in value]
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, Path):
        return str(value)
    if hasattr(value, "isoformat"):  # pandas/datetime timestamps
        return value.isoformat()
    return str(value)


def build_metadata(config: Any = None, *, furnace: Furnace | None = None,
                   software_version: str | None = None,
                   host: str | None = None) -> dict[str, str]:
    """The record's key-value pairs for a daemon run with `config` (a DaqConfig, or None for
    a writer without one). `furnace`: the full description the readings belong to (the
    config's when not given; a writer without a config names it), from which every reader
    rebuilds the furnace."""
    if software_version is None:
        from furnace_model.cli.arguments import version

        software_version = version()
    refit = getattr(config, "refit", None)
    settings = plain(config)
    if isinstance(settings, dict):
        settings.pop("document", None)  # recorded on its own, as written
        settings.pop("furnace", None)  # recorded on its own, in full
    if furnace is None:
        furnace = getattr(config, "furnace", None)
    if furnace is None:
        raise ValueError("the metadata record needs the furnace: give `furnace` or a config "
                         "with one")
    record = {
        "software_version": software_version,
        "furnace": json.dumps(furnace_record(furnace)),
        "config": json.dumps(settings),
        "config_source": json.dumps(plain(getattr(config, "document", None))),
        "config_file": str(getattr(config, "file", "") or ""),
        "host": host if host is not None else socket.gethostname(),
        "refit": json.dumps(plain(refit)),
    }
    signals = signal_fields(config)
    if signals:  # /furnace/signals's schema and the export's columns are read from here
        record["signals"] = json.dumps([dataclasses.asdict(s) for s in signals])
    return record


def signal_fields(config: Any) -> tuple[SignalField, ...]:
    """The `signals:` of a daemon config as /furnace/signals carries them (none without a
    config)."""
    return tuple(SignalField(s.name, s.unit, s.bit, s.text)
                 for s in getattr(config, "signals", ()))


def recorded_refit(metadata: Mapping[str, str] | None) -> dict | None:
    """The refit settings a log was written with, as recorded (None when not recorded or
    when the daemon ran without refits)."""
    if not metadata or "refit" not in metadata:
        return None
    value = json.loads(metadata["refit"])
    return value if isinstance(value, dict) else None


def refit_config(recorded: Mapping[str, Any]) -> Any:
    """A RefitConfig from recorded settings: the fields it knows, the rest left at their
    defaults (a log from a newer version may record more). A log that records no method was
    written before there was a choice, by the polish alone."""
    from .daqconfig import DiagnosisConfig, RefitConfig

    known = {f.name: f for f in dataclasses.fields(RefitConfig)}
    values = {"method": "polish", **{k: v for k, v in recorded.items() if k in known}}
    # A log written before windows were cut at outages was refitted across them.
    values.setdefault("max_outage_s", 0.0)
    if "state_dir" in values:
        values["state_dir"] = Path(values["state_dir"])
    diagnosis = values.get("diagnosis")
    if isinstance(diagnosis, Mapping):
        names = {f.name for f in dataclasses.fields(DiagnosisConfig)}
        given = {k: v for k, v in diagnosis.items() if k in names}
        if given.get("effects") is not None:
            given["effects"] = tuple(given["effects"])
        given["trusted"] = tuple(given.get("trusted") or ())
        # A log written before verdicts set thermocouples aside was refitted with them all.
        given.setdefault("set_aside", False)
        values["diagnosis"] = DiagnosisConfig(**given)
    else:
        values["diagnosis"] = None
    return RefitConfig(**values)


def recorded_ambient_default(metadata: Mapping[str, str] | None) -> float | None:
    """The recorded config's ambient_default_c (the t_air the refits used without an ambient
    point), or None."""
    if not metadata or "config" not in metadata:
        return None
    value = json.loads(metadata["config"])
    t_air = value.get("ambient_default_c") if isinstance(value, dict) else None
    return float(t_air) if isinstance(t_air, int | float) else None


def recorded_config(metadata: Mapping[str, str] | None, where: str) -> Any:
    """The daemon config a log was written with, rebuilt from the YAML recorded in it (None
    when the log records none); `where` names the log in errors."""
    if not metadata or "config_source" not in metadata:
        return None
    document = json.loads(metadata["config_source"])
    if not isinstance(document, dict):
        return None
    from furnace_model.config import Node

    from .daqconfig import parse_config

    return parse_config(Node(document, f"{where} (recorded config)"),
                        furnace=recorded_furnace(metadata, where))
