"""`furnace-daq sim-plc`: a Modbus (or OPC UA, or S7) PLC serving either a scenario's simulated plant
(`--scenario`) or recorded logs (`--from-log`), optionally broadcasting flame states on a CAN
bus. The register map is the default of CONTRACTS.md section 3 (for another furnace the map
derived from its description by the same rule, docs/operations.md), a daemon config's
(`--config`), or with `--from-log` the one the log was recorded with. The furnace is the
scenario's (its `furnace` key) or the log's (its metadata record); `--furnace` names the
description it must be."""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from furnace_model.errors import FurnaceError

from ..protocols import NAMES as PROTOCOL_NAMES

if TYPE_CHECKING:
    from ..simplc import ValueSource


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim-plc", help="run the simulated furnace PLC (Modbus, OPC UA or S7 server)",
                       description=__doc__)
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--scenario", metavar="SCENARIO.yaml",
                      help="scenario YAML, or the name of a shipped one (paper_exp1; "
                           "config/scenarios/): serve the simulated plant")
    what.add_argument("--from-log", type=Path, nargs="+", metavar="LOG",
                      help="MCAP log file(s) of the daemon: serve the recorded values")
    p.add_argument("--furnace", metavar="FURNACE.yaml",
                   help="furnace description (a file or a shipped name) the scenario or log "
                        "must be of (default: the scenario's or log's own, the paper's when "
                        "it names none)")
    p.add_argument("--speed", type=float, default=3600.0,
                   help="simulated seconds per wall second (default 3600)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    p.add_argument("--port", type=int, help="TCP port (default 5020, with --protocol opcua "
                                             "4840, with --protocol s7 1102; 0 = any free)")
    p.add_argument("--protocol", choices=PROTOCOL_NAMES, default="modbus",
                   help="serve the PLC over Modbus (default), OPC UA (an asyncua server, the "
                        "nodes of config/gateway-opcua.yaml or of --config) or S7 "
                        "(python-snap7's server, the addresses of config/gateway-s7.yaml or "
                        "of --config)")
    p.add_argument("--manual", action="store_true",
                   help="burners follow coil writes from a client instead of the schedule "
                        "(--scenario only)")
    p.add_argument("--seed", type=int, default=0,
                   help="sensor noise seed (default 0; --scenario only)")
    p.add_argument("--loop", action="store_true",
                   help="start the log again at its end instead of stopping (--from-log only)")
    p.add_argument("--config", type=Path,
                   help="serve the register map of this daemon config (default: with "
                        "--from-log the map the log was recorded with, else CONTRACTS.md's)")
    p.add_argument("--device", help="which device of the config's map to serve (default: "
                                    "its first)")
    p.add_argument("--scan-s", type=float, default=0.1, help="PLC scan period, s (default 0.1)")
    p.add_argument("--can-channel", help="also send flame states as CAN frames on this channel")
    p.add_argument("--can-interface", default="virtual",
                   help="python-can interface for --can-channel (default virtual)")
    p.add_argument("--transport", choices=("tcp", "rtu-over-tcp", "rtu"), default="tcp",
                   help="Modbus TCP (default), RTU frames over TCP, or RTU on --serial-port")
    p.add_argument("--serial-port", help="serial device for --transport rtu (e.g. one end of "
                                         "a socat pty pair)")
    p.add_argument("--baudrate", type=int, default=19200,
                   help="serial line speed for --transport rtu (default 19200)")
    p.add_argument("--duration", type=float, help="stop after this many wall seconds")
    p.set_defaults(run=run)


DEFAULT_PORTS = {"modbus": 5020, "opcua": 4840, "s7": 1102}
"""The simulated PLC's: S7's own port, 102, is below 1024, which only root may bind."""


def run(args: argparse.Namespace) -> int:
    if args.port is None:
        args.port = DEFAULT_PORTS[args.protocol]
    if args.protocol != "modbus":
        for flag, given in (("--transport", args.transport != "tcp"),
                            ("--serial-port", args.serial_port), ("--manual", args.manual),
                            ("--can-channel", args.can_channel)):
            if given:
                raise FurnaceError(f"{flag} works with --protocol modbus only")
    if (args.transport == "rtu") != (args.serial_port is not None):
        raise FurnaceError("--serial-port goes with --transport rtu, and only with it")
    import asyncio

    from furnace_model.cli.arguments import furnace_path, scenario_path
    from furnace_model.simulation.furnace import PAPER
    from furnace_model.simulation.furnacefile import load_furnace
    from furnace_model.simulation.scenario import load_scenario

    from ..logplayer import LogPlayer

    if args.speed <= 0 or args.scan_s <= 0:
        raise FurnaceError("--speed and --scan-s must be positive")
    if not 0 <= args.port <= 65535:
        raise FurnaceError(f"--port must be 0-65535, got {args.port}")
    source: ValueSource
    furnace = None if args.furnace is None else load_furnace(furnace_path(args.furnace))
    if args.from_log:
        if args.manual:
            raise FurnaceError("--manual works with --scenario only: a log's burners are recorded")
        source = LogPlayer(args.from_log, loop=args.loop)
        if furnace is not None and source.furnace != furnace:
            raise FurnaceError(f"--furnace {args.furnace}: the log is of furnace "
                               f"'{source.furnace.name}', not '{furnace.name}'")
        what = f"{', '.join(map(str, args.from_log))}: {source.describe()}"
    else:
        if args.loop:
            raise FurnaceError("--loop works with --from-log only")
        scenario = load_scenario(scenario_path(args.scenario), furnace)
        source = scenario
        if scenario.control is not None and args.manual:
            raise FurnaceError(f"--manual: scenario '{scenario.name}' runs in closed loop "
                               "(its control section): its loops set the burners")
        mode = ("closed loop" if scenario.control is not None
                else "manual" if args.manual else "schedule")
        what = f"{scenario.name}: {mode} burners"
    if args.protocol != "modbus":
        return asyncio.run(_serve_nodes(source, what, args))
    served, map_from = _served_map(args)
    own = source.furnace if isinstance(source, LogPlayer) else scenario.furnace
    if served is not None and served.furnace != own:
        raise FurnaceError(f"--config {args.config}: its map is of furnace "
                           f"'{served.furnace.name}', the values of furnace '{own.name}'")
    if served is None and own != PAPER:
        map_from = f"the default derived from furnace '{own.name}'"
    return asyncio.run(_serve(source, f"{what}; register map: {map_from}", args, served))


def _served_map(args: argparse.Namespace):
    """The map to serve and where it comes from, in words."""
    from ..daqconfig import load_config
    from ..logmeta import read_metadata, recorded_config
    from ..servedmap import ServedMap

    config, where = None, "the default of CONTRACTS.md section 3"
    if args.config is not None:
        config, where = load_config(args.config), str(args.config)
    elif args.from_log:
        files = sorted(f for p in args.from_log
                       for f in ([p] if not p.is_dir() else p.glob("*.mcap*")))
        config = recorded_config(read_metadata(files), str(files[0]) if files else "log")
        if config is not None:
            where = f"recorded in {files[0]}"
        elif args.device is not None:
            raise FurnaceError("--device: the log records no register map to choose from")
    elif args.device is not None:
        raise FurnaceError("--device goes with --config or --from-log")
    if config is None:
        return None, where
    names = [d.name for d in config.devices]
    if args.device is not None and args.device not in names:
        raise FurnaceError(f"--device {args.device}: the map has {', '.join(names)}")
    device = args.device or names[0]
    return ServedMap.of_config(config, device), f"{where}, device {device}"


async def _serve_nodes(source, what: str, args: argparse.Namespace) -> int:
    """The PLC over a protocol that names items one by one (OPC UA, S7): the items of
    `--config` (its first device speaking the protocol, or `--device`), else the protocol's
    default map."""
    from ..daqconfig import load_config
    from ..protocols import server_class

    cls = server_class(args.protocol)
    kw = dict(speed=args.speed, host=args.host, port=args.port, seed=args.seed,
              scan_s=args.scan_s)
    if args.config is None:
        if args.device is not None:
            raise FurnaceError("--device goes with --config")
        plc, map_from = cls(source, **kw), "the default map"
    else:
        config = load_config(args.config)
        names = [d.name for d in config.devices if d.protocol == args.protocol]
        if not names:
            raise FurnaceError(f"--config {args.config}: no device speaks {args.protocol}")
        if args.device is not None and args.device not in names:
            raise FurnaceError(f"--device {args.device}: the {args.protocol} devices of the "
                               f"map are {', '.join(names)}")
        device = args.device or names[0]
        if config.furnace != source.furnace:
            raise FurnaceError(f"--config {args.config}: its map is of furnace "
                               f"'{config.furnace.name}', the values of furnace "
                               f"'{source.furnace.name}'")
        plc = cls.of_config(source, config, device, **kw)
        map_from = f"{args.config}, device {device}"
    return await _run_server(plc, f"{what}; {args.protocol} map: {map_from}", args,
                             f"{args.host}:{{port}}")


async def _serve(source, what: str, args: argparse.Namespace, served) -> int:
    from ..simplc import SimPLC

    plc = SimPLC(source, speed=args.speed, host=args.host, port=args.port, manual=args.manual,
                 seed=args.seed, scan_s=args.scan_s, can_channel=args.can_channel,
                 can_interface=args.can_interface, transport=args.transport,
                 serial_port=args.serial_port, baudrate=args.baudrate, served=served)
    where = args.serial_port if args.transport == "rtu" else f"{args.host}:{{port}}"
    return await _run_server(plc, what, args, where)


async def _run_server(plc, what: str, args: argparse.Namespace, where: str) -> int:
    """Start the PLC, say where it listens, serve until SIGTERM or --duration."""
    import asyncio

    try:
        await plc.start()
    except (OSError, RuntimeError) as exc:
        raise FurnaceError(f"cannot listen on {where.format(port=args.port)}: {exc}") from None
    except Exception as exc:  # python-can raises various types for a bad interface/channel
        await plc.stop()
        raise FurnaceError(f"cannot start: {exc}") from None
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    print(f"listening on {where.format(port=plc.port)}", flush=True)
    print(f"{what}; {args.speed:g}x", file=sys.stderr, flush=True)

    async def tell_end() -> None:
        await plc.ended.wait()
        print(f"end of log at PLC second {plc.plc_seconds}: no new values; the last ones stay "
              "on the registers, heartbeat stopped", flush=True)

    teller = asyncio.create_task(tell_end())
    try:
        await asyncio.wait_for(stop.wait(), args.duration)
    except TimeoutError:
        pass
    finally:
        teller.cancel()
        await plc.stop()
    return 0
