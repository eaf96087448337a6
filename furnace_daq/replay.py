"""Replay: recorded MCAP logs through the same refit pipeline as the live daemon.

The furnace topics of the logs are fed, in log order, to a RefitRunner exactly as the daemon
feeds what it logs; windows are cut on the data clock, so the same log with the same `refit:`
settings gives the live daemon's /model/parameters timeline (same windows, same results to
the optimiser's tolerance). The /model topics go to one MCAP file; there log_time is the
window's end as well (a replay has no meaningful host time, and this keeps its output
reproducible).

Settings. The refit settings are those of `config` when one is given (`--config`), else
those recorded in the logs' metadata record (the daemon writes its `refit:` settings into
every file), else the defaults: a log alone replays as it was fitted live. The output file
carries a metadata record too, with the settings it was fitted with.

Diagnoses. With `refit.diagnosis` the same windows take the same trigger decisions
(diagnosistrigger), and each diagnosis is run again on the same records with the same seed.
Where the logs hold the live run's /model/diagnosis for that window, its record of what the
time limit cut replaces the clock (diagnosisrunner), so the verdict is the live one on any
host; without one, the configured time limit applies.

Reading and fitting overlap: the worker fits window k while this process reads and bins the
data of window k + 1, which is what makes a week of 1 Hz data replay in about half a minute on
two cores. Replay never drops a window: when the worker falls behind, reading waits.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable
from pathlib import Path

from mcap.writer import CompressionType, Writer

from furnace_model.errors import DataError
from furnace_model.log.messages import ModelDiagnosis, ModelEvent, ModelParameters, typed
from furnace_model.log.read import read_messages, recorded_furnace
from furnace_model.log.schema import (
    FURNACE_TOPICS,
    MESSAGE_ENCODING,
    MODEL_DIAGNOSIS,
    SCHEMA_ENCODING,
    topic,
)
from furnace_model.simulation.furnace import Furnace

from .daqconfig import DaqConfig, RefitConfig
from .logmeta import (
    METADATA_NAME,
    build_metadata,
    plain,
    read_metadata,
    recorded_ambient_default,
    recorded_refit,
    refit_config,
)
from .mcaplog import encode
from .refit import moves_data_clock
from .refitworker import RefitRunner

PUMP_EVERY = 256
"""Messages read between two looks at the worker."""


class ModelLog:
    """One MCAP file of /model/* messages (replay output); finished on close."""

    def __init__(self, path: Path, metadata: dict[str, str] | None, furnace: Furnace):
        self.path = path
        self.furnace = furnace
        path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = path.open("wb")
        self._writer = Writer(self._fh, compression=CompressionType.ZSTD, enable_crcs=True,
                              enable_data_crcs=True)
        self._writer.start(profile="", library="furnace-daq replay")
        if metadata is not None:
            self._writer.add_metadata(METADATA_NAME, metadata)
        self._channels: dict[str, int] = {}

    def write(self, name: str, message: dict, log_ns: int, pub_ns: int) -> None:
        channel = self._channels.get(name)
        if channel is None:
            t = topic(name, self.furnace)
            schema = self._writer.register_schema(t.schema_name, SCHEMA_ENCODING, t.schema_bytes())
            channel = self._writer.register_channel(name, MESSAGE_ENCODING, schema)
            self._channels[name] = channel
        self._writer.add_message(channel, log_ns, encode(message), pub_ns)

    def close(self) -> None:
        self._writer.finish()
        self._fh.close()


def default_out(paths: list[Path]) -> Path:
    """Next to the first log: <its name without .mcap[.part]>.model.mcap."""
    first = paths[0]
    stem = first.name.removesuffix(".part").removesuffix(".mcap")
    return first.with_name(f"{stem}.model.mcap")


def replay(paths: Iterable[str | Path], config: DaqConfig | None, out_path: str | Path | None,
           speed: float | None = None,
           echo: Callable[[str, ModelParameters | ModelEvent | ModelDiagnosis], None]
           | None = None
           ) -> list[ModelParameters]:
    """Run the logs through the refit pipeline; returns the /model/parameters messages in
    order. `speed` paces the data at that many data seconds per wall second (None: as fast
    as possible). `echo(topic, message)` sees every /model message as it is produced.
    The refit settings are `config.refit` when `config` is given, else those recorded in
    the logs (see `settings`). The furnace is the one the logs record; a config must be of
    the same furnace."""
    paths = [Path(p) for p in paths]
    if not paths:
        raise DataError("replay", "no log files given")
    if speed is not None and not speed > 0:
        raise DataError("--speed", f"must be positive, got {speed:g}")
    refit, t_air, _ = settings(paths, config)
    names = ", ".join(map(str, paths))
    furnace = recorded_furnace(read_metadata(sorted(paths)), names)
    if config is not None and config.furnace != furnace:
        raise DataError(names, f"the logs are of furnace '{furnace.name}', the config "
                               f"{config.file} of furnace '{config.furnace.name}'")
    out = Path(out_path) if out_path is not None else default_out(paths)
    if out.resolve() in {p.resolve() for p in paths}:
        raise DataError(str(out), "the output would overwrite one of the logs being replayed")
    params: list[ModelParameters] = []
    log: ModelLog | None = None

    def emit(name: str, message: ModelParameters | ModelEvent | ModelDiagnosis,
             pub_ns: int) -> None:
        assert log is not None
        log.write(name, message.to_json(), pub_ns, pub_ns)
        if isinstance(message, ModelParameters):
            params.append(message)
        if echo is not None:
            echo(name, message)

    runner = RefitRunner(refit, emit, t_air_default=t_air, max_queue=None, furnace=furnace,
                         recorded_diagnoses=recorded_diagnoses(paths))
    messages = typed(read_messages(paths, FURNACE_TOPICS), furnace)
    first = next(messages, None)  # reads and checks every file before anything is written
    if first is None:
        raise DataError(", ".join(map(str, paths)), "no furnace data in the logs")
    metadata = build_metadata(config, furnace=furnace)
    metadata["refit"] = json.dumps(plain(refit))
    metadata["replayed_from"] = json.dumps([p.name for p in paths])
    try:
        log = ModelLog(out, metadata, furnace)
    except OSError as exc:
        raise DataError(str(out), f"cannot write: {exc.strerror or exc}") from None
    runner.start()
    try:
        _feed(runner, first, messages, refit, speed)
        runner.drain(float("inf"))
    except DataError as exc:  # a message the windows cannot take: say in which logs
        names = ", ".join(map(str, paths))
        raise (exc if names in str(exc) else DataError(names, str(exc))) from None
    finally:
        runner.close()
        log.close()
    return params


def recorded_diagnoses(paths: list[Path]) -> dict[int, ModelDiagnosis]:
    """The diagnoses the live run logged, by publish time (the end of the window that
    raised each): what its time limit cut, which replay cuts in place of the clock."""
    return {pub_ns: ModelDiagnosis.from_json(raw)
            for _topic, raw, _log_ns, pub_ns in read_messages(paths, [MODEL_DIAGNOSIS])}


def settings(paths: list[Path], config: DaqConfig | None
             ) -> tuple[RefitConfig, float, str]:
    """(refit settings, default t_air, where they came from): `config`'s, else the ones
    recorded in the logs, else the defaults."""
    if config is not None:
        return config.refit or RefitConfig(), config.ambient_default_c, "config"
    metadata = read_metadata(sorted(paths))
    recorded = recorded_refit(metadata)
    t_air = recorded_ambient_default(metadata)
    t_air = 30.0 if t_air is None else t_air
    if recorded is not None:
        return refit_config(recorded), t_air, "log"
    return RefitConfig(), t_air, "defaults"


def _feed(runner: RefitRunner, first, messages, refit: RefitConfig,
          speed: float | None) -> None:
    pub0: int | None = None
    t_wall0 = 0.0  # set with pub0, at the first reading that moves the data clock
    limit = 2  # windows waiting beyond the one in flight before reading pauses
    for n, (name, msg, _log_ns, pub_ns) in enumerate(_chain(first, messages), 1):
        if speed is not None and moves_data_clock(msg):  # paced as the windows are cut
            if pub0 is None:
                pub0, t_wall0 = pub_ns, time.monotonic()
            ahead = (pub_ns - pub0) / 1e9 / speed - (time.monotonic() - t_wall0)
            if ahead > 0:
                runner.pump(ahead)
                time.sleep(max(0.0, (pub_ns - pub0) / 1e9 / speed - (time.monotonic() - t_wall0)))
        runner.feed(name, msg, pub_ns)
        if n % PUMP_EVERY == 0:
            runner.pump()
            while len(runner.queue) > limit:
                runner.pump(0.05)


def _chain(first, rest):
    yield first
    yield from rest
