"""`furnace-daq run`: the acquisition daemon. Polls the furnace PLC (and the flame scanners
on CAN) as the config describes and logs every sample to MCAP until SIGTERM or --duration."""

from __future__ import annotations

import argparse
import os
import signal
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from furnace_model.errors import ConfigError, FurnaceError
from furnace_model.log.messages import DaqEvent, DaqEventKind
from furnace_model.log.schema import DAQ_EVENTS

if TYPE_CHECKING:
    from ..journal import Journal
    from ..mcaplog import LogWriter


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run the acquisition daemon", description=__doc__)
    p.add_argument("--config", required=True, type=Path, help="daemon YAML (config/gateway.yaml)")
    p.add_argument("--plc", metavar="HOST:PORT", help="PLC address, overrides plc.host/port")
    p.add_argument("--log-dir", type=Path, help="MCAP directory, overrides log.dir")
    p.add_argument("--state-dir", type=Path,
                   help="where the latest model (model.json) and the refit chain are kept, "
                   "overrides refit.state_dir")
    p.add_argument("--no-refit", action="store_true",
                   help="poll and log only, whatever the config's refit section says")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (exit 0)")
    p.set_defaults(run=run)


def _plc_address(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ConfigError("--plc", "", f"expected HOST:PORT, got '{text}'")
    return host.strip("[]"), int(port)


def run(args: argparse.Namespace) -> int:
    import asyncio
    import logging

    from ..daqconfig import load_config
    from ..journal import ERR, INFO, WARNING, Journal
    from ..mcaplog import LogWriter

    config = load_config(args.config)
    if args.plc:
        host, port = _plc_address(args.plc)
        config = replace(config, plc=replace(config.plc, host=host, port=port))
    if args.log_dir:
        config = replace(config, log=replace(config.log, dir=args.log_dir))
    if args.no_refit:
        config = replace(config, refit=None)
    if args.state_dir and config.refit is not None:
        config = replace(config, refit=replace(config.refit, state_dir=args.state_dir))
    if args.duration is not None and args.duration <= 0:
        raise ConfigError("--duration", "", f"must be positive, got {args.duration:g}")
    # Connection trouble is reported on /daq/status; the client library's own log lines
    # would only repeat it on stderr at every retry.
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    journal = Journal(config.stderr_interval_s)
    lc = config.log
    try:
        lc.dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # not fatal: the writer retries and /daq/status says why
        journal.say(ERR, f"log: {lc.dir}: {exc.strerror or exc}")
    from ..daemon import EVENT_PRIORITY
    from ..logmeta import build_metadata, signal_fields

    try:
        log = LogWriter(lc.dir, prefix=lc.prefix, flush_interval_s=lc.flush_interval_s,
                        rotate_s=lc.rotate_s, rotate_bytes=lc.rotate_bytes,
                        retention_files=lc.retention_files, file_mode=lc.file_mode,
                        metadata=build_metadata(config), event_priority=EVENT_PRIORITY,
                        furnace=config.furnace, signals=signal_fields(config))
        lock, recovered = _recover_at_start(lc.dir, lc.prefix)
    except (OSError, ValueError) as exc:
        raise FurnaceError(f"log directory {lc.dir}: {exc}") from None
    for note in recovered:  # files of a daemon that died: in the journal and in the log
        journal.say(WARNING, f"log recovery: {note}")
        now = time.time_ns()
        log.write(DAQ_EVENTS, DaqEvent(DaqEventKind.LOG_RECOVERED, note).to_json(), now, now)
    live = None
    if config.live_view is not None:  # after the log lock and recovery:
        # a second daemon stops at the lock, and a port taken leaves the recovery on record
        from ..liveview import LiveView

        try:
            live = LiveView(config.live_view, where=config.file, furnace=config.furnace,
                            signals=signal_fields(config), journal=journal)
        except FurnaceError:
            log.close()
            if lock is not None:
                os.close(lock)
            raise
        log.listeners.append(live.send)
        journal.say(INFO, f"live view: Foxglove WebSocket on {live.url}")
    try:
        return asyncio.run(_main(config, log, args.duration, journal))
    finally:
        if live is not None:
            live.close()
            if live.error:
                journal.say(WARNING, live.error)
        if lock is not None:
            os.close(lock)


def _recover_at_start(log_dir: Path, prefix: str) -> tuple[int | None, list[str]]:
    """Lock the log directory (held until the daemon stops) and recover what a dead daemon
    left. An unwritable directory (full, read-only) must not stop the service: it then starts
    without recovery and reports the log error as usual."""
    from ..logrecover import lock_log_dir, recover_leftovers

    try:
        lock = lock_log_dir(log_dir, prefix)
    except OSError as exc:
        return None, [f"skipped, the log directory is not writable: {exc.strerror or exc}"]
    try:
        return lock, recover_leftovers(log_dir, prefix)
    except BaseException:
        os.close(lock)
        raise


async def _main(config, log: LogWriter, duration: float | None, journal: Journal) -> int:
    import asyncio

    from ..daemon import Daemon, summary
    from ..journal import ERR, INFO
    from ..sdnotify import Notifier
    from ..writeback import WriteBack

    write_back = None
    if config.write_back is not None:  # off unless the config enables it
        def event(message: DaqEvent) -> None:
            now = time.time_ns()
            log.write(DAQ_EVENTS, message.to_json(), now, now)
        write_back = WriteBack(config.write_back, config.plc.host, config.plc.port,
                               device_id=config.plc.device_id, timeout_s=config.plc.timeout_s,
                               events=event)
    daemon = Daemon(config, log, notifier=Notifier(), journal=journal,
                    on_model=None if write_back is None else write_back.on_model)
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, daemon.stop)
    journal.say(INFO, f"polling {', '.join(link.label for link in daemon.links)} every "
                      f"{config.poll_period_s:g} s, logging to {config.log.dir}")
    counters = await daemon.run(duration)
    if write_back is not None:
        write_back.events = None  # the log is closed
        await write_back.close()
    journal.say(*summary(counters))
    if log.error:
        journal.say(ERR, f"log: {log.error}")
    return 0
