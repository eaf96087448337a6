"""One device of the daemon's config: where it is (TCP host or serial line), how it is
redialled, and the Telegraf workarounds it needs; read from a `plc:` section or one
entry of `devices:`, every key checked, its defaults here."""

from __future__ import annotations

from dataclasses import dataclass, field

from furnace_model.config import Node

from .opcuamap import OpcUaSettings, parse_opcua
from .protocols import NAMES as PROTOCOL_NAMES
from .protocols import PROTOCOLS
from .s7map import S7Settings, parse_s7


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


TRANSPORTS = ("tcp", "rtu-over-tcp", "ascii-over-tcp", "rtu", "ascii")
"""Modbus TCP; RTU or ASCII frames over a TCP socket (a serial-to-Ethernet converter in
transparent mode); RTU or ASCII on a serial line (Telegraf's transmission modes TCP,
RTUoverTCP, ASCIIoverTCP, RTU, ASCII)."""
SERIAL_TRANSPORTS = ("rtu", "ascii")
LINE_TRANSPORTS = ("rtu-over-tcp", "ascii-over-tcp", "rtu", "ascii")
"""Transports whose frames travel on one serial bus (directly, or behind a converter): the
devices on it share it, one request at a time."""
PARITIES = ("N", "E", "O")


@dataclass(frozen=True)
class SerialConfig:
    """A serial line, as pyserial opens it."""

    port: str = "/dev/ttyUSB0"
    baudrate: int = 19200
    parity: str = "N"
    stopbits: int = 1
    bytesize: int = 8


@dataclass(frozen=True)
class Workarounds:
    """Telegraf's Modbus `workarounds`, for devices that need them: a gateway that drops
    the first request after a connect, a slow RTU slave behind a converter, a device that
    allows only one connection and keeps it busy, one that refuses reads of more than a
    few registers or over unmapped holes."""

    pause_after_connect_s: float = 0.0
    pause_between_requests_s: float = 0.0
    close_connection_after_gather: bool = False
    one_request_per_field: bool = False
    max_registers_per_request: int = 125
    read_coils_starting_at_zero: bool = False
    """A device that refuses a coil read not starting at address 0: the first coil request
    starts there."""


@dataclass(frozen=True)
class PlcConfig:
    """One Modbus device (the only one when the config has no `devices:` list)."""

    host: str = "127.0.0.1"
    port: int = 502
    device_id: int = 1
    timeout_s: float = 1.0
    max_gap_registers: int = 8
    max_gap_bits: int = 64
    max_consecutive_errors: int = 3
    reconnect: Backoff = field(default_factory=Backoff)
    name: str = "plc"
    transport: str = "tcp"
    serial: SerialConfig | None = None
    workarounds: Workarounds = field(default_factory=Workarounds)
    protocol: str = "modbus"
    """How the device is read (furnace_daq.protocols): modbus, opcua or s7."""
    opcua: OpcUaSettings | None = None
    """The `opcua:` section of an OPC UA device."""
    s7: S7Settings | None = None
    """The `s7:` section of an S7 device."""
    busy_retries: int = 0
    busy_retries_wait_s: float = 0.1
    """A request the device answers with exception 6 (server device busy) is sent again, up
    to `busy_retries` times, `busy_retries_wait_s` apart (Telegraf's `busy_retries`,
    `busy_retries_wait`)."""

    @property
    def where(self) -> str:
        """host:port, or the serial port: what an engineer finds the device by."""
        if self.transport in SERIAL_TRANSPORTS and self.serial is not None:
            return self.serial.port
        return f"{self.host}:{self.port}"

    def read_budget_s(self, requests: int) -> float:
        """The longest one read of `requests` requests may take on the device's own: its
        timeout, plus the pauses its workarounds ask for and the waits of its busy retries."""
        w = self.workarounds
        n = max(1, requests)
        budget = self.timeout_s + w.pause_between_requests_s * (n - 1)
        if w.close_connection_after_gather:
            budget += self.timeout_s + w.pause_after_connect_s
        if w.one_request_per_field:
            budget += self.timeout_s * (n - 1)
        return budget + self.busy_retries * (self.busy_retries_wait_s + self.timeout_s)

    @property
    def line(self) -> tuple[str, str] | None:
        """The serial bus the device is on, as (framing, where): devices with the same line
        share one opening of it; None for Modbus TCP, where each device has its own
        connection."""
        if self.transport not in LINE_TRANSPORTS:
            return None
        return self.transport.split("-")[0], self.where


PLC_KEYS = {"host", "port", "device_id", "timeout_s", "max_gap_registers", "max_gap_bits",
            "max_consecutive_errors", "reconnect", "protocol", "opcua", "s7", "busy_retries",
            "busy_retries_wait_s"}
DEVICE_KEYS = PLC_KEYS | {"name", "transport", "serial", "workarounds"}
MODBUS_KEYS = ("device_id", "max_gap_registers", "max_gap_bits", "transport", "serial",
               "workarounds", "busy_retries", "busy_retries_wait_s")
"""Settings of a Modbus device only."""
PROTOCOL_SECTIONS = ("opcua", "s7")
"""Sections of settings each for one protocol, named as the protocol."""


def parse_device(node: Node, name: str = "plc") -> PlcConfig:
    """A `plc:` section, or one entry of `devices:` (which adds name, transport, serial
    line and workarounds)."""
    rc = node.child("reconnect", {}).mapping({"initial_s", "max_s", "factor", "retry_s",
                                              "fast_for_s"})
    backoff = Backoff(rc.get_number("initial_s", 0.5, lo=0.01, hi=3600.0),
                      rc.get_number("max_s", 5.0, lo=0.01, hi=86400.0),
                      rc.get_number("factor", 2.0, lo=1.0, hi=10.0),
                      rc.get_number("retry_s", 0.5, lo=0.01, hi=3600.0),
                      rc.get_number("fast_for_s", 120.0, lo=0.0, hi=86400.0))
    if backoff.max_s < backoff.initial_s:
        raise rc.child("max_s").error(f"must be at least initial_s ({backoff.initial_s:g})")
    protocol = node.get_string("protocol", "modbus", choices=PROTOCOL_NAMES)
    for key in (*(MODBUS_KEYS if protocol != "modbus" else ()), *PROTOCOL_SECTIONS):
        if node.has(key) and key != protocol:
            owner = key if key in PROTOCOL_SECTIONS else "modbus"
            raise node.child(key).error(f"applies to protocol: {owner} only (protocol is "
                                        f"{protocol})")
    transport = node.get_string("transport", "tcp", choices=TRANSPORTS)
    serial = None
    if transport in SERIAL_TRANSPORTS:
        for key in ("host", "port"):
            if node.has(key):
                raise node.child(key).error("a serial device has no host or port: its line "
                                            "is under serial: (port, baudrate, parity, stopbits)")
        sn = node.child("serial").mapping({"port", "baudrate", "parity", "stopbits", "bytesize"})
        serial = SerialConfig(port=sn.get_string("port"),
                              baudrate=sn.get_integer("baudrate", 19200, lo=50, hi=4_000_000),
                              parity=sn.get_string("parity", "N", choices=PARITIES),
                              stopbits=sn.get_integer("stopbits", 1, lo=1, hi=2),
                              bytesize=sn.get_integer("bytesize", 8, lo=7, hi=8))
    elif node.has("serial"):
        raise node.child("serial").error(f"applies to transport: rtu or ascii only "
                                         f"(transport is {transport})")
    wn = node.child("workarounds", {}).mapping(
        {"pause_after_connect_s", "pause_between_requests_s", "close_connection_after_gather",
         "one_request_per_field", "max_registers_per_request", "read_coils_starting_at_zero"})
    workarounds = Workarounds(
        pause_after_connect_s=wn.get_number("pause_after_connect_s", 0.0, lo=0.0, hi=60.0),
        pause_between_requests_s=wn.get_number("pause_between_requests_s", 0.0, lo=0.0, hi=60.0),
        close_connection_after_gather=wn.get_bool("close_connection_after_gather", False),
        one_request_per_field=wn.get_bool("one_request_per_field", False),
        max_registers_per_request=wn.get_integer("max_registers_per_request", 125, lo=1,
                                                 hi=125),
        read_coils_starting_at_zero=wn.get_bool("read_coils_starting_at_zero", False))
    return PlcConfig(
        host=node.get_string("host", "127.0.0.1"),
        port=node.get_integer("port", PROTOCOLS[protocol].port, lo=1, hi=65535),
        device_id=node.get_integer("device_id", 1, lo=0, hi=255),
        timeout_s=node.get_number("timeout_s", 1.0, lo=0.01, hi=60.0),
        max_gap_registers=node.get_integer("max_gap_registers", 8, lo=0, hi=124),
        max_gap_bits=node.get_integer("max_gap_bits", 64, lo=0, hi=1999),
        max_consecutive_errors=node.get_integer("max_consecutive_errors", 3, lo=1, hi=1000),
        reconnect=backoff, name=name, transport=transport, serial=serial,
        workarounds=workarounds, protocol=protocol,
        opcua=parse_opcua(node.child("opcua", {})) if protocol == "opcua" else None,
        s7=parse_s7(node.child("s7", {})) if protocol == "s7" else None,
        busy_retries=node.get_integer("busy_retries", 0, lo=0, hi=100),
        busy_retries_wait_s=node.get_number("busy_retries_wait_s", 0.1, lo=0.0, hi=60.0))


def parse_devices(root: Node) -> tuple[PlcConfig, ...]:
    if not root.has("devices"):
        return ()
    if root.has("plc"):
        raise root.child("plc").error("give either plc: (one device) or devices: (a list), "
                                      "not both")
    out: list[PlcConfig] = []
    for dn in root.child("devices").elements(1, 64):
        dn.mapping(DEVICE_KEYS)
        name = dn.get_string("name")
        if not name or any(c.isspace() for c in name):
            raise dn.child("name").error("expected a name without spaces")
        if any(d.name == name for d in out):
            raise dn.child("name").error(f"device {name} is listed twice")
        device = parse_device(dn, name)
        _same_line(dn, device, out)
        out.append(device)
    return tuple(out)


def _same_line(node: Node, device: PlcConfig, before: list[PlcConfig]) -> None:
    """Devices on one serial bus: opened once with one framing and one set of line
    settings, each answering to its own device id."""
    for other in before:
        if other.where != device.where or device.line is None and other.line is None:
            continue
        if device.line != other.line:
            how = "serial line" if device.transport in SERIAL_TRANSPORTS else "converter"
            raise node.child("transport").error(
                f"{device.transport} on the {how} {device.where}, which device {other.name} "
                f"reads with transport {other.transport}: one bus has one framing")
        if device.serial != other.serial:
            raise node.child("serial").error(
                f"the line {device.where} is device {other.name}'s too, with other settings "
                f"({_line_text(other.serial)}): one port is opened once, with one setting")
        if device.device_id == other.device_id:
            raise node.child("device_id").error(
                f"device id {device.device_id} on {device.where} is device {other.name}'s "
                "already: each device on a bus answers to its own id")


def _line_text(serial: SerialConfig | None) -> str:
    if serial is None:
        return "none"
    return f"{serial.baudrate} baud {serial.bytesize}{serial.parity}{serial.stopbits}"
