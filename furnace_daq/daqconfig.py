"""The daemon's YAML config: where the PLC is, its register map, the CAN flame signals, the
log. Checked in full at load, so a typo stops the service at start with the key path
(exit code 2) rather than hours later as a silent gap. Defaults live here and only here.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from furnace_model import BURNERS_PER_ZONE, SENSORS, ZONES
from furnace_model.config import Node, load_yaml
from furnace_model.errors import ConfigError

from .registers import BIT_TABLES, DATA_TYPES, ORDERS, TABLES, BitRange, Point, overlaps
from .writeback import WriteBackConfig, parse_write_back

BURNER_SOURCES = ("modbus", "can", "both")
REFIT_METHODS = ("polish", "ga")
"""How each refit window is fitted: `polish` starts from the previous window's model (the
first window: `fit`'s fast search), `ga` runs the paper's genetic algorithm from scratch."""


@dataclass(frozen=True)
class Backoff:
    """When to redial the PLC (docs/reliability.md, "Reconnect").

    A dial the PLC never accepted (refused, unreachable, no answer) costs it no session, so
    for the first `fast_for_s` of an outage those are retried every `retry_s`: a restarted
    PLC is found within that interval. Everything else (a PLC that accepts and hangs up, an
    outage longer than `fast_for_s`) backs off exponentially from `initial_s` to `max_s`."""

    initial_s: float = 0.5
    max_s: float = 5.0
    factor: float = 2.0
    retry_s: float = 0.5
    fast_for_s: float = 120.0

    def delay(self, attempt: int) -> float:
        """Wait before reconnect attempt number `attempt` (0 = first retry)."""
        return min(self.max_s, self.initial_s * self.factor ** min(attempt, 64))

    @property
    def fast_s(self) -> float:
        """The fixed interval in use: `retry_s`, never longer than the backoff cap."""
        return min(self.retry_s, self.max_s)


@dataclass(frozen=True)
class PlcConfig:
    host: str = "127.0.0.1"
    port: int = 502
    device_id: int = 1
    timeout_s: float = 1.0
    max_gap_registers: int = 8
    max_gap_bits: int = 64
    max_consecutive_errors: int = 3
    reconnect: Backoff = field(default_factory=Backoff)


@dataclass(frozen=True)
class ClockConfig:
    point: Point
    epoch: pd.Timestamp | None = None
    """PLC second 0 in UTC; when absent it is anchored at the first reading."""


@dataclass(frozen=True)
class CanFrame:
    can_id: int
    start_bit: int
    extended: bool = False


@dataclass(frozen=True)
class CanConfig:
    interface: str = "virtual"
    channel: str = "furnace"
    bitrate: int | None = None
    timeout_s: float = 3.0
    frames: dict[str, CanFrame] = field(default_factory=dict)


@dataclass(frozen=True)
class LogConfig:
    dir: Path = Path("logs")
    prefix: str = "furnace"
    flush_interval_s: float = 5.0
    rotate_s: float = 3600.0
    rotate_bytes: int = 256 * 2**20
    retention_files: int = 0
    file_mode: int = 0o640


@dataclass(frozen=True)
class RefitConfig:
    """Online identification on a sliding window of the data clock (docs/operations.md).

    Windows are cut on the PLC clock (publish time), never the host clock, so a replay of the
    log gives the same windows as the live daemon."""

    period_s: float = 900.0
    window_s: float = 86400.0
    step_s: float = 60.0
    budget_s: float = 30.0
    method: str = "polish"
    population: int = 20
    generations: int = 2000
    """The GA's knobs (method ga only): the paper's population, and `fit --method ga`'s
    generations."""
    max_gap_fraction: float = 0.2
    min_burner_steps: int = 1
    drift_windows: int = 2
    drift_min_change: float = 0.03
    queue_max: int = 4
    state_dir: Path = Path("state")


@dataclass(frozen=True)
class DaqConfig:
    plc: PlcConfig
    poll_period_s: float
    thermocouples: tuple[Point, ...]
    ambient: Point | None
    ambient_default_c: float
    clock: ClockConfig | None
    heartbeat: Point | None
    stale_after_s: float
    burner_source: str
    burner_bits: tuple[BitRange, ...]
    can: CanConfig | None
    disagreement_polls: int
    status_interval_s: float
    log: LogConfig
    file: str = ""
    stderr_interval_s: float = 60.0
    """The same kind of message goes to stderr (the journal) at most this often."""
    refit: RefitConfig | None = None
    write_back: WriteBackConfig | None = None
    """None when online identification is off (no `refit:` section or `enabled: false`)."""

    def modbus_items(self) -> list[Point | BitRange]:
        """Everything read over Modbus, in the order of the config file."""
        items: list[Point | BitRange] = list(self.thermocouples)
        clock = None if self.clock is None else self.clock.point
        items += [p for p in (self.ambient, clock, self.heartbeat) if p is not None]
        if self.burner_source in ("modbus", "both"):
            items += self.burner_bits
        return items

    def key_paths(self) -> dict[str, str]:
        """Where each Modbus item's entry is in the config file, by item name: errors and
        `furnace-daq check` name the key an engineer edits."""
        where = {p.name: f"thermocouples.{p.name}" for p in self.thermocouples}
        where.update(t_air="ambient", clock="clock", heartbeat="heartbeat")
        where.update({z: f"burners.modbus.{z}" for z in ZONES})
        return where


def _point(node: Node, name: str, extra: tuple[str, ...] = ()) -> Point:
    node.mapping({"table", "address", "type", "word_order", "byte_order", "scale", "offset",
                  "sentinels", "range", *extra})
    table = node.get_string("table", "input", choices=[t for t in TABLES if t not in BIT_TABLES])
    dtype = node.get_string("type", "int16", choices=tuple(DATA_TYPES))
    count = DATA_TYPES[dtype][0]
    address = node.get_integer("address", lo=0, hi=65536 - count)
    sentinels = tuple(n.number() for n in node.child("sentinels", []).elements())
    lo = hi = None
    if node.has("range"):
        rng = node.child("range")
        lo, hi = (n.number() for n in rng.elements(2, 2))
        if lo >= hi:
            raise rng.error(f"expected [low, high] with low < high, got [{lo:g}, {hi:g}]")
    scale = node.get_number("scale", 1.0)
    if scale == 0:
        raise node.child("scale").error("must not be 0")
    return Point(name=name, table=table, address=address, dtype=dtype,
                 word_order=node.get_string("word_order", "big", choices=ORDERS),
                 byte_order=node.get_string("byte_order", "big", choices=ORDERS),
                 scale=scale, offset=node.get_number("offset", 0.0),
                 sentinels=sentinels, lo=lo, hi=hi)


def _bits(node: Node, zone: str, n: int) -> BitRange:
    node.mapping({"table", "address", "invert"})
    return BitRange(zone, node.get_string("table", "discrete", choices=BIT_TABLES),
                    node.get_integer("address", lo=0, hi=65536 - n), n,
                    node.get_bool("invert", False))


def _can(node: Node) -> CanConfig:
    node.mapping({"interface", "channel", "bitrate", "timeout_s", *ZONES})
    frames = {}
    defaults = {"soak": 0, "heat": 10, "preheat": 18}
    for i, zone in enumerate(ZONES):
        f = node.child(zone, {"id": 0x180, "start_bit": defaults[zone]}).mapping(
            {"id", "start_bit", "extended"})
        extended = f.get_bool("extended", False)
        can_id = f.get_integer("id", lo=0, hi=0x1FFFFFFF if extended else 0x7FF)
        start = f.get_integer("start_bit", lo=0, hi=64 - BURNERS_PER_ZONE[i])
        frames[zone] = CanFrame(can_id, start, extended)
    bitrate = node.child("bitrate", None)
    return CanConfig(interface=node.get_string("interface", "virtual"),
                     channel=str(node.get_string("channel", "furnace")),
                     bitrate=None if bitrate.value is None else bitrate.integer(lo=1),
                     timeout_s=node.get_number("timeout_s", 3.0, lo=0.01, hi=3600.0),
                     frames=frames)


def _log(node: Node) -> LogConfig:
    node.mapping({"dir", "prefix", "flush_interval_s", "rotate_s", "rotate_mb",
                  "retention_files", "file_mode"})
    default_dir = os.environ.get("LOGS_DIRECTORY", "logs").split(":")[0]
    mode = node.get_string("file_mode", "0640")
    try:
        file_mode = int(mode, 8)
    except ValueError:
        raise node.child("file_mode").error(f"expected an octal mode like '0640', got '{mode}'") from None
    if file_mode & ~0o644 or file_mode & 0o600 != 0o600:
        # A log another user can rewrite is no record of the plant; one the daemon cannot
        # write, or an executable one, is a typo.
        raise node.child("file_mode").error(
            f"{mode} is not allowed: the owner must read and write the logs and nobody else "
            "may write or execute them (at most 0644; the default is 0640)")
    return LogConfig(
        dir=Path(node.get_string("dir", default_dir)),
        prefix=node.get_string("prefix", "furnace"),
        flush_interval_s=node.get_number("flush_interval_s", 5.0, lo=0.1, hi=3600.0),
        rotate_s=node.get_number("rotate_s", 3600.0, lo=1.0),
        rotate_bytes=int(node.get_number("rotate_mb", 256.0, lo=0.01) * 2**20),
        retention_files=node.get_integer("retention_files", 0, lo=0),
        file_mode=file_mode)


def _refit(node: Node) -> RefitConfig | None:
    node.mapping({"enabled", "period_s", "window_s", "step_s", "budget_s", "method",
                  "population", "generations", "max_gap_fraction", "min_burner_steps",
                  "drift_windows", "drift_min_change", "queue_max", "state_dir"})
    if not node.get_bool("enabled", True):
        return None
    step = node.get_number("step_s", 60.0, lo=0.001, hi=86400.0)
    period = node.get_number("period_s", 900.0, lo=step, hi=86400.0 * 365)
    window = node.get_number("window_s", 86400.0, lo=step, hi=86400.0 * 365)
    for key, value in (("period_s", period), ("window_s", window)):
        if abs(value / step - round(value / step)) > 1e-9:
            raise node.child(key).error(f"must be a whole multiple of step_s ({step:g} s): "
                                        "windows are cut on the resampling grid")
    if window / step < 10:
        raise node.child("window_s").error(f"holds only {window / step:g} samples of "
                                           f"step_s; at least 10 are needed to fit")
    method = node.get_string("method", "polish", choices=REFIT_METHODS)
    for key in ("population", "generations"):
        if method != "ga" and node.has(key):
            raise node.child(key).error(f"applies to method: ga only (method is {method})")
    default_dir = os.environ.get("STATE_DIRECTORY", "state").split(":")[0]
    return RefitConfig(
        period_s=period, window_s=window, step_s=step,
        budget_s=node.get_number("budget_s", 30.0, lo=0.01, hi=86400.0),
        method=method,
        population=node.get_integer("population", 20, lo=4, hi=10000),
        generations=node.get_integer("generations", 2000, lo=1, hi=10_000_000),
        max_gap_fraction=node.get_number("max_gap_fraction", 0.2, lo=0.0, hi=1.0),
        min_burner_steps=node.get_integer("min_burner_steps", 1, lo=0, hi=100000),
        drift_windows=node.get_integer("drift_windows", 2, lo=1, hi=1000),
        drift_min_change=node.get_number("drift_min_change", 0.03, lo=0.0, hi=10.0),
        queue_max=node.get_integer("queue_max", 4, lo=1, hi=10000),
        state_dir=Path(node.get_string("state_dir", default_dir)))


def load_config(path: str | Path) -> DaqConfig:
    """Read and check a daemon config; every error names the file and key path."""
    return parse_config(load_yaml(path))


def parse_config(root: Node) -> DaqConfig:
    root.mapping({"plc", "poll_period_s", "thermocouples", "ambient", "ambient_default_c",
                  "clock", "heartbeat", "stale_after_s", "burners", "status_interval_s",
                  "stderr_interval_s", "log", "refit", "write_back"})

    plc_node = root.child("plc", {}).mapping(
        {"host", "port", "device_id", "timeout_s", "max_gap_registers", "max_gap_bits",
         "max_consecutive_errors", "reconnect"})
    rc = plc_node.child("reconnect", {}).mapping({"initial_s", "max_s", "factor", "retry_s",
                                                  "fast_for_s"})
    backoff = Backoff(rc.get_number("initial_s", 0.5, lo=0.01, hi=3600.0),
                      rc.get_number("max_s", 5.0, lo=0.01, hi=86400.0),
                      rc.get_number("factor", 2.0, lo=1.0, hi=10.0),
                      rc.get_number("retry_s", 0.5, lo=0.01, hi=3600.0),
                      rc.get_number("fast_for_s", 120.0, lo=0.0, hi=86400.0))
    if backoff.max_s < backoff.initial_s:
        raise rc.child("max_s").error(f"must be at least initial_s ({backoff.initial_s:g})")
    plc = PlcConfig(
        host=plc_node.get_string("host", "127.0.0.1"),
        port=plc_node.get_integer("port", 502, lo=1, hi=65535),
        device_id=plc_node.get_integer("device_id", 1, lo=0, hi=255),
        timeout_s=plc_node.get_number("timeout_s", 1.0, lo=0.01, hi=60.0),
        max_gap_registers=plc_node.get_integer("max_gap_registers", 8, lo=0, hi=124),
        max_gap_bits=plc_node.get_integer("max_gap_bits", 64, lo=0, hi=1999),
        max_consecutive_errors=plc_node.get_integer("max_consecutive_errors", 3, lo=1, hi=1000),
        reconnect=backoff)

    tc_node = root.child("thermocouples").mapping(SENSORS)
    thermocouples = tuple(_point(tc_node.child(s), s) for s in SENSORS)
    ambient = _point(root.child("ambient"), "t_air") if root.has("ambient") else None
    clock = None
    if root.has("clock"):
        cn = root.child("clock")
        point = _point(cn, "clock", extra=("epoch",))
        epoch = cn.child("epoch").timestamp() if cn.has("epoch") else None
        clock = ClockConfig(point, epoch)
    heartbeat = _point(root.child("heartbeat"), "heartbeat") if root.has("heartbeat") else None

    bn = root.child("burners").mapping({"source", "modbus", "can", "disagreement_polls"})
    source = bn.get_string("source", "modbus", choices=BURNER_SOURCES)
    bits: tuple[BitRange, ...] = ()
    # A block the chosen source does not use is still checked: a typo there would bite later.
    if source in ("modbus", "both") or bn.has("modbus"):
        mb = bn.child("modbus").mapping(ZONES)
        bits = tuple(_bits(mb.child(z), z, BURNERS_PER_ZONE[i]) for i, z in enumerate(ZONES))
    can = _can(bn.child("can")) if source in ("can", "both") or bn.has("can") else None

    poll = root.get_number("poll_period_s", 1.0, lo=0.01, hi=3600.0)
    config = DaqConfig(
        plc=plc, poll_period_s=poll, thermocouples=thermocouples, ambient=ambient,
        ambient_default_c=root.get_number("ambient_default_c", 30.0, lo=-60.0, hi=200.0),
        clock=clock, heartbeat=heartbeat,
        stale_after_s=root.get_number("stale_after_s", 5.0, lo=0.01, hi=86400.0),
        burner_source=source, burner_bits=bits, can=can,
        disagreement_polls=bn.get_integer("disagreement_polls", 2, lo=1, hi=10000),
        status_interval_s=root.get_number("status_interval_s", 10.0, lo=0.1, hi=86400.0),
        stderr_interval_s=root.get_number("stderr_interval_s", 60.0, lo=0.0, hi=86400.0),
        log=_log(root.child("log", {})), file=root.file,
        refit=_refit(root.child("refit")) if root.has("refit") else None,
        write_back=parse_write_back(root.child("write_back", None)))
    _check_overlaps(root, config)
    return config


def _check_overlaps(root: Node, config: DaqConfig) -> None:
    """Two entries that share an address are almost always a copy-paste slip in the map."""
    where = config.key_paths()
    items = config.modbus_items()
    hit = overlaps(items)
    if hit is not None:
        a, b = items[hit[0]], items[hit[1]]
        first, second = where[a.name], where[b.name]
        raise ConfigError(root.file, second, f"overlaps {first} ({a.table} address "
                                             f"{max(a.address, b.address)})")
