"""The daemon's YAML config: where the PLC is, its register map (thermocouples, burners,
the heat inputs of rate-fired zones, measured disturbances, extra signals), the CAN flame
signals, the log. Checked in full at load, so a typo stops the service at start with the key path
(exit code 2) rather than hours later as a silent gap. Defaults live here and only here
(a device's in furnace_daq.deviceconfig).
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pandas as pd

from furnace_model.config import Node, load_yaml
from furnace_model.errors import ConfigError
from furnace_model.experiment import OUTAGE_PERIODS
from furnace_model.simulation.furnace import PAPER, Furnace
from furnace_model.simulation.furnacefile import named_furnace
from furnace_model.simulation.network import parameter_names

from . import opcuamap, s7map
from .deviceconfig import PLC_KEYS, PlcConfig, parse_device, parse_devices
from .liveview import LiveViewConfig
from .opcuamap import UaBits, UaPoint
from .registers import (
    BIT,
    BIT_TABLES,
    MAX_BITS_PER_READ,
    ORDERS,
    POINT_TYPES,
    REGISTER_TABLES,
    STRING,
    TABLES,
    TELEGRAF_ORDERS,
    BitRange,
    Point,
    overlaps,
    register_count,
)
from .s7map import S7Bits, S7Point
from .scaling import parse_scaling
from .writeback import WriteBackConfig, parse_write_back


@dataclass(frozen=True)
class Addressing:
    """How the map names an item read by a protocol other than Modbus: how to tell its
    entries (`node:`, `s7:`), and how to read an analog point and a run of bits from one.
    Everything else of an entry (device, scaling, key paths) is the map's, whatever the
    protocol."""

    how: str
    """The entry's form, as errors name it."""
    is_entry: Callable[[Node], bool]
    is_bit_entry: Callable[[Node], bool]
    point: Callable[..., Any]
    """(node, name, extra, numeric) -> the item."""
    bits: Callable[..., Any]
    """(node, name, n, extra) -> the item."""


ADDRESSINGS: dict[str, Addressing] = {
    "opcua": Addressing(opcuamap.ADDRESSING, opcuamap.is_ua_entry, opcuamap.is_ua_bit_entry,
                        opcuamap.ua_point, opcuamap.ua_bits),
    "s7": Addressing(s7map.ADDRESSING, s7map.is_s7_entry, s7map.is_s7_bit_entry,
                     s7map.s7_point, s7map.s7_bits),
}
"""By protocol (furnace_daq.protocols); a Modbus entry is one that none of these claims."""
MODBUS_ADDRESSING = "a register (table, address)"


def _addressing(node: Node) -> Addressing | None:
    return next((a for a in ADDRESSINGS.values() if a.is_entry(node)), None)


BURNER_SOURCES = ("modbus", "can", "both")
REFIT_METHODS = ("ga_polish", "ga", "polish")
"""How each refit window is fitted (furnace_daq.refit): `ga_polish` (the default) runs the
genetic search seeded with the previous window's model, then the polish; `ga` the paper's
genetic algorithm alone, from scratch; `polish` the polish alone from the previous model.
The first window of `ga_polish` and `polish` is `fit`'s offline fast search."""
GA_METHODS = ("ga_polish", "ga")
"""The methods that take `population` and `generations`."""
PAPER_GA_SIZE = (20, 2000)
"""`ga`'s (population, generations): the paper's population, `fit --method ga`'s
generations."""
SEEDED_POPULATION = 16
"""`ga_polish`'s population: a small one, since it searches near the previous optimum, and
one whose batches stay on the simulator's path for a few sets, where 16 cost about twice
one (docs/performance.md, "Online refit")."""
SEEDED_GENERATIONS_MAX = 30
"""`ga_polish`'s generations when the budget allows more: as many as `fit`'s offline fast
search runs; more found nothing the polish did not on the shipped week
(docs/performance.md) and only cost time."""
SEEDED_BUDGET_SHARE = 0.25
"""The share of `budget_s` that `ga_polish`'s generations may take at `NOMINAL_SET_SAMPLE_S`;
the search stops at half the budget on the wall clock and the polish has the rest."""
NOMINAL_SET_SAMPLE_S = 200e-9
"""The cost assumed for one parameter set at one sample of a window in a GA generation: four
times what a 2-core machine measured (docs/performance.md, "Online refit"), so that a slower
or busier host still ends the generations well inside the budget."""



@dataclass(frozen=True)
class ClockConfig:
    point: Point
    epoch: pd.Timestamp | None = None
    """PLC second 0 in UTC; when absent it is anchored at the first reading."""


@dataclass(frozen=True)
class Signal:
    """An extra named point of the map (O2, furnace pressure, fuel flow, a door switch),
    logged on /furnace/signals with its unit and exported as a column of its name: an
    analog point, or one bit."""

    name: str
    unit: str
    item: Point | BitRange | UaPoint | UaBits | S7Point | S7Bits

    @property
    def bit(self) -> bool:
        return isinstance(self.item, BitRange | UaBits | S7Bits)

    @property
    def text(self) -> bool:
        """A string point (a recipe name, a product code): logged as text, never averaged."""
        return isinstance(self.item, Point) and self.item.dtype == STRING


HEAT_KEY = "heat"
DISTURBANCES_KEY = "disturbances"
SIGNALS_KEY = "signals"
RESERVED_FIELDS = ("quality", "unit", "plc_time", "plc_seconds", "error")
"""Fields the reading topics carry beside the values they name: no zone, disturbance or
signal may take one of these names, or its value and the field would be one key."""
TABLE_COLUMNS = ("timestamp", "t_min", "t_air")
TABLE_PREFIXES = ("tc_", "burners_", "heat_")


def item_name(section: str, key: str) -> str:
    """How a point of `heat:`, `disturbances:` or `signals:` is named among the map's items:
    its key path, which no thermocouple, zone or other point can be."""
    return f"{section}.{key}"


@dataclass(frozen=True)
class CanFrame:
    can_id: int
    start_bit: int
    extended: bool = False
    burners: int = 0
    """The zone's burners: bits start_bit .. start_bit + burners - 1."""


@dataclass(frozen=True)
class CanConfig:
    interface: str = "virtual"
    channel: str = "furnace"
    bitrate: int | None = None
    timeout_s: float = 3.0
    frames: dict[str, CanFrame] = field(default_factory=dict)
    """Per zone, in the furnace's zone order."""


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
class DiagnosisConfig:
    """Online diagnosis of what the refit's model misses (furnace_daq.diagnosisrunner,
    docs/operations.md "Online diagnosis")."""

    after_windows: int = 3
    """Fitted windows in a row above their misfit limit that start a diagnosis."""
    time_limit_s: float = 600.0
    effects: tuple[str, ...] | None = None
    """The candidate effects; None: every effect that applies to the furnace."""
    set_aside: bool = True
    """Leave a thermocouple a diagnosis finds drifting out of the later windows."""
    trusted: tuple[str, ...] = ()
    """Thermocouples never set aside (one replaced after it was: list it and restart)."""


@dataclass(frozen=True)
class RefitConfig:
    """Online identification on a sliding window of the data clock (docs/operations.md).

    Windows are cut on the PLC clock (publish time), never the host clock, so a replay of the
    log gives the same windows as the live daemon."""

    period_s: float = 900.0
    window_s: float = 86400.0
    step_s: float = 60.0
    budget_s: float = 30.0
    method: str = "ga_polish"
    population: int | None = None
    generations: int | None = None
    """The GA's knobs (methods ga and ga_polish); None: the method's own (`ga_size`)."""
    max_gap_fraction: float = 0.2
    max_outage_s: float | None = None
    """A window is fitted from its first reading after the last span this long without one
    (the burners' states in it are unknown, and a fit across it would hold the last ones);
    None: OUTAGE_PERIODS steps, 0: never cut."""
    min_burner_steps: int = 1
    drift_windows: int = 2
    drift_min_change: float = 0.03
    queue_max: int = 4
    state_dir: Path = Path("state")
    diagnosis: DiagnosisConfig | None = None
    """None: no online diagnosis (no `diagnosis:` block, or `enabled: false`)."""

    @property
    def outage_ns(self) -> int | None:
        """`max_outage_s` in ns; None when windows are never cut."""
        s = OUTAGE_PERIODS * self.step_s if self.max_outage_s is None else self.max_outage_s
        return int(round(s * 1e9)) if s > 0 else None

    def ga_size(self) -> tuple[int, int]:
        """(population, generations) of the method's genetic search: as configured, else
        the method's own. `ga_polish`'s generations follow from `budget_s` and the window's
        samples at a nominal cost, never from a measurement of the host: the same settings
        give the same search on any host, so a replay repeats the live windows
        (furnace_daq.refit)."""
        if self.method != "ga_polish":
            population, generations = PAPER_GA_SIZE
            return self.population or population, self.generations or generations
        population = self.population or SEEDED_POPULATION
        if self.generations is not None:
            return population, self.generations
        samples = self.window_s / self.step_s
        afford = SEEDED_BUDGET_SHARE * self.budget_s / (population * samples
                                                        * NOMINAL_SET_SAMPLE_S)
        return population, max(0, min(SEEDED_GENERATIONS_MAX, int(afford)))


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
    device_list: tuple[PlcConfig, ...] = ()
    """The `devices:` list; empty for a config with one `plc:` section."""
    live_view: LiveViewConfig | None = None
    """The Foxglove WebSocket server (furnace_daq.liveview); None unless `enabled: true`."""
    document: Any = field(default=None, repr=False, compare=False)
    """The YAML mapping this config was read from: recorded in each log, so that the log
    alone rebuilds it (`sim-plc --from-log` serves its register map)."""
    furnace: Furnace = field(kw_only=True)
    """The furnace the map reads (`furnace:`, default the paper's): its thermocouples and
    zones are the map's keys, the log's fields and the refit's model."""
    heat: tuple[Point, ...] = field(default=(), kw_only=True)
    """The heat input of each rate-fired zone (`heat:`), in the furnace's zone order."""
    disturbances: tuple[Point, ...] = field(default=(), kw_only=True)
    """Each measured disturbance the furnace declares (`disturbances:`), in its order."""
    signals: tuple[Signal, ...] = field(default=(), kw_only=True)
    """The map's extra named points (`signals:`), in the order of the file."""

    @property
    def devices(self) -> tuple[PlcConfig, ...]:
        """Every Modbus device: the `devices:` list, or the `plc:` section as the only one.
        `plc` is always the first, so `replace(config, plc=...)` (`--plc HOST:PORT`) moves
        the first device."""
        return (self.plc, *self.device_list[1:])

    @property
    def several_devices(self) -> bool:
        return bool(self.device_list)

    def device_items(self, device: PlcConfig) -> list:
        """The items read from `device` (of its protocol's kind)."""
        first = self.devices[0].name
        return [it for it in self.plc_items() if (it.device or first) == device.name]

    def modbus_items(self) -> list[Point | BitRange]:
        """Everything read over Modbus, in the order of the config file."""
        return [it for it in self.plc_items() if isinstance(it, Point | BitRange)]

    def plc_items(self) -> list:
        """Everything read from the PLC devices, by whichever protocol, in the order of the
        config file."""
        items: list = list(self.thermocouples)
        clock = None if self.clock is None else self.clock.point
        items += [p for p in (self.ambient, clock, self.heartbeat) if p is not None]
        if self.burner_source in ("modbus", "both"):
            items += self.burner_bits
        items += [*self.heat, *self.disturbances, *(s.item for s in self.signals)]
        return items

    def key_paths(self) -> dict[str, str]:
        """Where each Modbus item's entry is in the config file, by item name: errors and
        `furnace-daq check` name the key an engineer edits."""
        where = {p.name: f"thermocouples.{p.name}" for p in self.thermocouples}
        where.update(t_air="ambient", clock="clock", heartbeat="heartbeat")
        where.update({z: f"burners.modbus.{z}" for z in self.furnace.switched_zones})
        where.update({it.name: it.name for it in (*self.heat, *self.disturbances,
                                                  *(s.item for s in self.signals))})
        return where

    def heat_point(self, zone: str) -> Point:
        """The point a rate-fired zone's heat input is read from."""
        return next(p for p in self.heat if p.name == item_name(HEAT_KEY, zone))

    def disturbance_point(self, name: str) -> Point:
        return next(p for p in self.disturbances if p.name == item_name(DISTURBANCES_KEY, name))


def _orders(node: Node) -> tuple[str, str]:
    """(word_order, byte_order) from `word_order: big|little` and `byte_order: big|little`,
    or from one `byte_order` as Telegraf names it (ABCD, DCBA, BADC, CDAB, ...)."""
    byte = node.get_string("byte_order", "big", choices=(*ORDERS, *TELEGRAF_ORDERS))
    if byte in TELEGRAF_ORDERS:
        if node.has("word_order"):
            raise node.child("word_order").error(
                f"byte_order {byte} already gives the word order; remove word_order")
        return TELEGRAF_ORDERS[byte]
    return node.get_string("word_order", "big", choices=ORDERS), byte


def _point(node: Node, name: str, extra: tuple[str, ...] = (), numeric: bool = True,
           devices: tuple[str, ...] = (), bits: bool = False) -> Point:
    """An entry of the map. `numeric`: no string; `bits`: a coil or discrete input may be
    read as a number (0 or 1, before scale and offset), which a temperature never is."""
    addressing = _addressing(node)
    if addressing is not None:  # a node, an S7 address: its device's protocol is checked last
        return replace(addressing.point(node, name, extra, numeric),
                       device=_device_of(node, devices))
    node.mapping({"table", "address", "type", "word_order", "byte_order", "scale", "offset",
                  "sentinels", "range", "length", "device", *extra})
    table = node.get_string("table", "input",
                            choices=TABLES if bits else REGISTER_TABLES)
    length = 0
    if table in BIT_TABLES:
        for key in ("type", "length", "word_order", "byte_order"):
            if node.has(key):
                raise node.child(key).error(f"a {table} is one bit, read as 0 or 1: it has no "
                                            f"{key}")
        dtype = BIT
    else:
        dtype = node.get_string("type", "int16", choices=POINT_TYPES)
    if dtype == STRING:
        if numeric:
            raise node.child("type").error(f"{name} is a number; string is for the heartbeat "
                                           "and signals")
        length = node.get_integer("length", lo=1, hi=125)
    elif node.has("length"):
        raise node.child("length").error("applies to type: string only")
    count = register_count(dtype, length)
    address = node.get_integer("address", lo=0, hi=65536 - count)
    scaling = parse_scaling(node)
    word_order, byte_order = _orders(node)
    return Point(name=name, table=table, address=address, dtype=dtype,
                 word_order=word_order, byte_order=byte_order,
                 scale=scaling.scale, offset=scaling.offset, sentinels=scaling.sentinels,
                 lo=scaling.lo, hi=scaling.hi, length=length,
                 device=_device_of(node, devices))


def _device_of(node: Node, devices: tuple[str, ...]) -> str:
    """The `device:` a point names; required with several devices, the only one otherwise."""
    if not devices:
        if node.has("device"):
            raise node.child("device").error("there is no devices: list to name one of")
        return ""
    if len(devices) == 1 and not node.has("device"):
        return devices[0]
    return node.get_string("device", choices=devices)


def _bits(node: Node, zone: str, n: int, devices: tuple[str, ...] = (),
          extra: tuple[str, ...] = (), table: str = "discrete") -> BitRange:
    addressing = _addressing(node)
    if addressing is not None:
        return replace(addressing.bits(node, zone, n, extra), device=_device_of(node, devices))
    node.mapping({"table", "address", "invert", "bit", "device", *extra})
    table = node.get_string("table", table, choices=TABLES)
    bit = 0
    if table in REGISTER_TABLES:
        bit = node.get_integer("bit", 0, lo=0, hi=15)
    elif node.has("bit"):
        raise node.child("bit").error("applies to bits packed in a register (table: holding "
                                      "or input) only")
    width = (bit + n + 15) // 16 if table in REGISTER_TABLES else n
    return BitRange(zone, table, node.get_integer("address", lo=0, hi=65536 - width), n,
                    node.get_bool("invert", False), bit, _device_of(node, devices))


def _exact_keys(node: Node, names: tuple[str, ...], what: str, furnace: Furnace,
                required: bool = True, also: tuple[str, ...] = ()) -> Node:
    """A mapping whose keys are the furnace's `names` (thermocouples or zones), besides the
    settings `also`: a key the furnace does not have, or one of its own left out, names the
    key path and the furnace."""
    node.mapping()
    for key in node.value:
        if key not in names and key not in also:
            settings = f"; settings: {', '.join(also)}" if also else ""
            raise ConfigError(node.file, node._sub(key),
                              f"unknown key: furnace '{furnace.name}' has no {what} '{key}' "
                              f"(its {what}s: {', '.join(names)}{settings})")
    if required:
        for key in names:
            if key not in node.value:
                raise ConfigError(node.file, node._sub(key),
                                  f"required key is missing: {what} '{key}' of furnace "
                                  f"'{furnace.name}'")
    return node


def _no_rate_zones(node: Node, furnace: Furnace) -> None:
    """A rate-fired zone under a burner section: its heat input is an analog point."""
    for i in furnace.rated:
        zone = furnace.zones[i]
        if node.has(zone):
            raise node.child(zone).error(
                f"zone '{zone}' of furnace '{furnace.name}' is fired at a rate "
                f"({furnace.heat_inputs[i].unit}), not by burners switched on and off: its "
                f"heat input is read from heat.{zone}")


def _zone_points(root: Node, furnace: Furnace, devices: tuple[str, ...]) -> tuple[Point, ...]:
    """`heat:`: the analog point of each rate-fired zone, in the unit of its description.
    A zone fired by burners (whole or pulse-fired) is read from its burner bits instead."""
    rated = tuple(furnace.zones[i] for i in furnace.rated)
    if not rated and not root.has(HEAT_KEY):
        return ()
    node = root.child(HEAT_KEY, {})
    node.mapping()
    for key in node.value:
        if key in furnace.zones and key not in rated:
            kind = furnace.heat_inputs[furnace.zones.index(key)].kind
            how = "pulse-fired" if kind == "pulse" else "fired by burners switched on and off"
            raise ConfigError(node.file, node._sub(key),
                              f"zone '{key}' of furnace '{furnace.name}' is {how}: its heat "
                              f"input is the count of its burners' bits under burners.modbus "
                              f"(heat: holds the rate-fired zones: {', '.join(rated) or 'none'})")
    _exact_keys(node, rated, "rate-fired zone", furnace)
    return tuple(_point(node.child(z), item_name(HEAT_KEY, z), devices=devices, bits=True)
                 for z in rated)


def _disturbance_points(root: Node, furnace: Furnace, devices: tuple[str, ...]
                        ) -> tuple[Point, ...]:
    """`disturbances:`: the analog point of each measured disturbance the furnace declares,
    in the unit of its description."""
    names = tuple(d.name for d in furnace.disturbances)
    if not names and not root.has(DISTURBANCES_KEY):
        return ()
    node = _exact_keys(root.child(DISTURBANCES_KEY, {}), names, "disturbance", furnace)
    return tuple(_point(node.child(d), item_name(DISTURBANCES_KEY, d), devices=devices,
                        bits=True) for d in names)


_SIGNAL_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


def _signals(node: Node, furnace: Furnace, devices: tuple[str, ...]) -> tuple[Signal, ...]:
    """`signals:`: extra named points, each with its `unit`: an analog point as a
    thermocouple's (any table and type), or one bit (table discrete or coil, or `bit` of a
    holding or input register; `invert` for an active-low signal). A name is a field of
    /furnace/signals and a column of the export, so it may not be one the contract uses."""
    node.mapping()
    taken = {c: "a column of the tabular contract" for c in TABLE_COLUMNS}
    taken.update({f: "a field the reading topics carry" for f in RESERVED_FIELDS})
    taken.update({d.column: f"the column of disturbance '{d.name}'"
                  for d in furnace.disturbances})
    taken.update({d.name: f"disturbance '{d.name}' of furnace '{furnace.name}'"
                  for d in furnace.disturbances})
    out: list[Signal] = []
    for name, sn in node.items():
        if not _SIGNAL_NAME.match(name):
            raise sn.error(f"'{name}' is not a signal name: letters, digits and _, starting "
                           "with a letter")
        clash = taken.get(name) or next(
            (f"the {prefix}* columns of the tabular contract" for prefix in TABLE_PREFIXES
             if name.startswith(prefix)), None)
        if clash is None:
            clash = next((f"signal '{s.name}' (names differ only in case)" for s in out
                          if s.name.lower() == name.lower()), None)
        if clash is not None:
            raise sn.error(f"signal '{name}' collides with {clash}: name it otherwise")
        sn.mapping()
        table = sn.get_string("table", "input", choices=TABLES)
        key = item_name(SIGNALS_KEY, name)
        if table in BIT_TABLES or sn.has("bit") or any(a.is_bit_entry(sn)
                                                       for a in ADDRESSINGS.values()):
            item: Point | BitRange = _bits(sn, key, 1, devices, extra=("unit",), table=table)
        else:
            item = _point(sn, key, extra=("unit",), numeric=False, devices=devices)
        out.append(Signal(name, sn.get_string("unit"), item))
    return tuple(out)


def _can(node: Node, furnace: Furnace) -> CanConfig:
    zones = furnace.switched_zones
    _no_rate_zones(node, furnace)
    _exact_keys(node, zones, "zone", furnace, required=False,
                also=("interface", "channel", "bitrate", "timeout_s"))
    frames = {}
    for k, i in enumerate(furnace.switched):
        zone = zones[k]
        # default: one frame, the zones' burners in order (CONTRACTS.md: soak 0, heat 10, ...)
        default_start = sum(furnace.burners[j] for j in furnace.switched[:k])
        f = node.child(zone, {"id": 0x180, "start_bit": default_start}).mapping(
            {"id", "start_bit", "extended"})
        extended = f.get_bool("extended", False)
        can_id = f.get_integer("id", lo=0, hi=0x1FFFFFFF if extended else 0x7FF)
        if furnace.burners[i] > 64:
            raise f.error(f"the {zone} zone's {furnace.burners[i]} burners do not fit in one "
                          "CAN frame (64 bits)")
        start = f.get_integer("start_bit", lo=0, hi=64 - furnace.burners[i])
        frames[zone] = CanFrame(can_id, start, extended, furnace.burners[i])
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


def parse_refit(node: Node, furnace: Furnace | None = None) -> RefitConfig | None:
    """`refit`; `furnace`: the one its thermocouple names must be of (None: a fleet's)."""
    node.mapping({"enabled", "period_s", "window_s", "step_s", "budget_s", "method",
                  "population", "generations", "max_gap_fraction", "max_outage_s",
                  "min_burner_steps", "drift_windows", "drift_min_change", "queue_max",
                  "state_dir", "diagnosis"})
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
    method = node.get_string("method", RefitConfig.method, choices=REFIT_METHODS)
    for key in ("population", "generations"):
        if method not in GA_METHODS and node.has(key):
            raise node.child(key).error(f"applies to methods {' and '.join(GA_METHODS)} only "
                                        f"(method is {method})")
    outage = node.get_number("max_outage_s", lo=0.0) if node.has("max_outage_s") else None
    if outage is not None and 0 < outage < step:
        raise node.child("max_outage_s").error(f"must be 0 (never cut) or at least step_s "
                                               f"({step:g} s): a shorter span is one row's")
    default_dir = os.environ.get("STATE_DIRECTORY", "state").split(":")[0]
    return RefitConfig(
        period_s=period, window_s=window, step_s=step,
        budget_s=node.get_number("budget_s", 30.0, lo=0.01, hi=86400.0),
        method=method,
        population=(node.get_integer("population", lo=4, hi=10000)
                    if node.has("population") else None),
        generations=(node.get_integer("generations", lo=1, hi=10_000_000)
                     if node.has("generations") else None),
        max_gap_fraction=node.get_number("max_gap_fraction", 0.2, lo=0.0, hi=1.0),
        max_outage_s=outage,
        min_burner_steps=node.get_integer("min_burner_steps", 1, lo=0, hi=100000),
        drift_windows=node.get_integer("drift_windows", 2, lo=1, hi=1000),
        drift_min_change=node.get_number("drift_min_change", 0.03, lo=0.0, hi=10.0),
        queue_max=node.get_integer("queue_max", 4, lo=1, hi=10000),
        state_dir=Path(node.get_string("state_dir", default_dir)),
        diagnosis=parse_diagnosis(node.child("diagnosis"), furnace)
        if node.has("diagnosis") else None)


def parse_diagnosis(node: Node, furnace: Furnace | None = None) -> DiagnosisConfig | None:
    """`refit.diagnosis`; the effects must be names of the contract (CONTRACTS.md section
    4), each once, and the trusted thermocouples the furnace's."""
    from furnace_model.effects import EFFECTS

    node.mapping({"enabled", "after_windows", "time_limit_s", "effects", "set_aside",
                  "trusted"})
    enabled = node.get_bool("enabled", True)
    after = node.get_integer("after_windows", DiagnosisConfig.after_windows, lo=1, hi=100000)
    limit = node.get_number("time_limit_s", DiagnosisConfig.time_limit_s, lo=1.0, hi=86400.0)
    effects = None
    if node.has("effects"):
        effects = []
        for item in node.child("effects").elements(min_len=1):
            name = item.string(choices=tuple(EFFECTS))
            if name in effects:
                raise item.error(f"'{name}' is listed twice")
            effects.append(name)
        effects = tuple(effects)
    set_aside = node.get_bool("set_aside", True)
    trusted = tuple(item.string(choices=None if furnace is None else furnace.sensors)
                    for item in node.child("trusted", []).elements())
    if not enabled:
        return None
    return DiagnosisConfig(after_windows=after, time_limit_s=limit, effects=effects,
                           set_aside=set_aside, trusted=trusted)


def _live_view(node: Node) -> LiveViewConfig | None:
    node.mapping({"enabled", "host", "port"})
    host = node.get_string("host", LiveViewConfig.host)
    if not host or any(c.isspace() for c in host):
        raise node.child("host").error("expected an address to listen on, like 127.0.0.1")
    port = node.get_integer("port", LiveViewConfig.port, lo=1, hi=65535)
    if not node.get_bool("enabled", False):
        return None
    return LiveViewConfig(host=host, port=port)


def load_config(path: str | Path) -> DaqConfig:
    """Read and check a daemon config; every error names the file and key path."""
    return parse_config(load_yaml(path))


def config_furnace(root: Node) -> Furnace:
    """The furnace a config's `furnace:` key names (`named_furnace`); the paper's when the
    key is absent."""
    if not root.has("furnace"):
        return PAPER
    here = Path(root.file).parent if root.file and not root.file.startswith("<") else None
    return named_furnace(root.child("furnace"), here, "the config")


def parse_config(root: Node, furnace: Furnace | None = None) -> DaqConfig:
    """A daemon config from its YAML. `furnace`: the description to hold the map against
    instead of the one `furnace:` names (a log's recorded config: the log carries the
    description itself, and the path may not resolve where the log is read)."""
    root.mapping({"plc", "devices", "poll_period_s", "thermocouples", "ambient",
                  "ambient_default_c", "clock", "heartbeat", "stale_after_s", "burners",
                  "status_interval_s", "stderr_interval_s", "log", "refit", "write_back",
                  "live_view", "furnace", HEAT_KEY, DISTURBANCES_KEY, SIGNALS_KEY})
    if furnace is None:
        furnace = config_furnace(root)
    elif root.has("furnace"):
        root.get_string("furnace")
    device_list = parse_devices(root)
    plc = device_list[0] if device_list else parse_device(root.child("plc", {}).mapping(
        PLC_KEYS))
    names = tuple(d.name for d in device_list)

    sensors = furnace.sensors
    tc_node = _exact_keys(root.child("thermocouples"), sensors, "thermocouple", furnace)
    # the map names its points by these: two of one name would read as one
    clash = ({"t_air", "clock", "heartbeat"} & {*furnace.zones, *sensors}) \
        | (set(furnace.zones) & set(sensors))
    if clash:
        raise root.child("furnace", "").error(
            f"furnace '{furnace.name}' names a zone or thermocouple {', '.join(sorted(clash))}, "
            "which the map uses for its own points; rename it in the description")
    # /furnace/heat and /furnace/disturbances carry their values by name beside their fields
    named = {furnace.zones[i] for i in furnace.rated} | {d.name for d in furnace.disturbances}
    clash = named & set(RESERVED_FIELDS)
    if clash:
        raise root.child("furnace", "").error(
            f"furnace '{furnace.name}' names a rate-fired zone or disturbance "
            f"{', '.join(sorted(clash))}, which its log topic carries as a field of its own; "
            "rename it in the description")
    thermocouples = tuple(_point(tc_node.child(s), s, devices=names) for s in sensors)
    ambient = _point(root.child("ambient"), "t_air", devices=names) if root.has("ambient") \
        else None
    clock = None
    if root.has("clock"):
        cn = root.child("clock")
        point = _point(cn, "clock", extra=("epoch",), devices=names)
        epoch = cn.child("epoch").timestamp() if cn.has("epoch") else None
        clock = ClockConfig(point, epoch)
    heartbeat = _point(root.child("heartbeat"), "heartbeat", numeric=False, devices=names,
                       bits=True) if root.has("heartbeat") else None

    # A furnace every zone of which is fired at a rate has no burner bits to read.
    bn = root.child("burners", None if furnace.switched else {}).mapping(
        {"source", "modbus", "can", "disagreement_polls"})
    source = bn.get_string("source", "modbus", choices=BURNER_SOURCES)
    bits: tuple[BitRange, ...] = ()
    # A block the chosen source does not use is still checked: a typo there would bite later.
    if furnace.switched and (source in ("modbus", "both") or bn.has("modbus")):
        mb = bn.child("modbus")
        _no_rate_zones(mb, furnace)
        _exact_keys(mb, furnace.switched_zones, "zone", furnace)
        bits = tuple(_bits(mb.child(furnace.zones[i]), furnace.zones[i], furnace.burners[i],
                           names) for i in furnace.switched)
    can = _can(bn.child("can"), furnace) if furnace.switched and (
        source in ("can", "both") or bn.has("can")) else None
    heat = _zone_points(root, furnace, names)
    disturbances = _disturbance_points(root, furnace, names)
    signals = _signals(root.child(SIGNALS_KEY), furnace, names) if root.has(SIGNALS_KEY) \
        else ()

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
        refit=parse_refit(root.child("refit"), furnace) if root.has("refit") else None,
        write_back=parse_write_back(root.child("write_back", None)),
        device_list=device_list, live_view=_live_view(root.child("live_view", {})),
        document=root.value, furnace=furnace, heat=heat, disturbances=disturbances,
        signals=signals)
    if config.write_back is not None:
        names = parameter_names(furnace)
        for point in config.write_back.points:
            if point.name not in names:
                raise ConfigError(root.file, f"write_back.params.{point.name}",
                                  f"not a parameter of the model of furnace '{furnace.name}' "
                                  f"(its parameters: {', '.join(names)})")
    if config.write_back is not None and plc.protocol != "modbus":
        raise root.child("write_back").error(
            f"writes to the first device, {plc.name}, over Modbus TCP; it speaks {plc.protocol}")
    if config.write_back is not None and plc.transport != "tcp":
        raise root.child("write_back").error(
            f"writes to the first device, {plc.name}, over Modbus TCP; its transport is "
            f"{plc.transport}")
    _check_overlaps(root, config)
    _check_protocols(root, config)
    _check_coils_from_zero(root, config)
    return config


def _check_protocols(root: Node, config: DaqConfig) -> None:
    """Each item addressed as its device reads: registers on a Modbus device, nodes on an
    OPC UA one, S7 addresses on an S7 one."""
    where = config.key_paths()
    protocols = {d.name: d.protocol for d in config.devices}
    first = config.devices[0].name
    for item in config.plc_items():
        device = item.device or first
        spoken = protocols[device]
        given = getattr(item, "protocol", "modbus")
        if given != spoken:
            how = {"modbus": MODBUS_ADDRESSING,
                   **{name: a.how for name, a in ADDRESSINGS.items()}}
            raise ConfigError(root.file, where.get(item.name, item.name),
                              f"is given as {how[given]}, but device {device} speaks "
                              f"{spoken}: give {how[spoken]}")


def _check_coils_from_zero(root: Node, config: DaqConfig) -> None:
    """A device whose coil reads must start at address 0 can read coils only as far as one
    request reaches from there."""
    for k, device in enumerate(config.devices):
        if not device.workarounds.read_coils_starting_at_zero:
            continue
        coils = [it for it in config.device_items(device) if it.table == "coil"]
        end = min((it.address + (it.count if isinstance(it, BitRange) else 1) for it in coils),
                  default=0)
        if end > MAX_BITS_PER_READ:
            key = f"devices[{k}]" if config.several_devices else "plc"
            raise ConfigError(root.file, f"{key}.workarounds.read_coils_starting_at_zero",
                              f"the first coil read would span {end} coils from address 0, "
                              f"more than one request reads ({MAX_BITS_PER_READ})")


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
