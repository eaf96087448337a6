"""The protocols a PLC is reached by, as python-can's `BACKENDS` names its interfaces: a
name in the config (`protocol:` of a device) -> the source that reads it and the
simulated PLC that serves it, imported only when used, so that `--help` stays fast and a
gateway polling Modbus never loads an OPC UA or S7 library.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from furnace_model.errors import FurnaceError

if TYPE_CHECKING:
    from .daqconfig import DaqConfig
    from .deviceconfig import PlcConfig
    from .sources import Source


@dataclass(frozen=True)
class Protocol:
    source: str
    """module:Class of its Source."""
    server: str
    """module:Class of its simulated PLC (SimPLC's interface)."""
    port: int
    """The protocol's usual TCP port: a device's default."""
    install: str
    """What to install when its module is missing: the package itself, or the extra that
    brings it."""
    text: str


PROTOCOLS: dict[str, Protocol] = {
    "modbus": Protocol("furnace_daq.sources:ModbusSource", "furnace_daq.simplc:SimPLC", 502,
                       "pymodbus", "Modbus TCP or RTU"),
    "opcua": Protocol("furnace_daq.opcuasource:OpcUaSource",
                      "furnace_daq.opcuaserver:OpcUaPLC", 4840, "furnace-daq[opcua]", "OPC UA"),
    "s7": Protocol("furnace_daq.s7source:S7Source", "furnace_daq.s7server:S7PLC", 102,
                   "furnace-daq[s7]", "Siemens S7 (ISO on TCP)"),
}
NAMES = tuple(PROTOCOLS)


def _load(name: str, target: str) -> Any:
    module, _, cls = target.partition(":")
    try:
        return getattr(importlib.import_module(module), cls)
    except ImportError as exc:
        need = PROTOCOLS[name].install
        raise FurnaceError(f"protocol {name} needs a package this installation lacks "
                           f"({exc}): install {need} (pip install '{need}')") from None


def source_class(name: str) -> type[Source]:
    return _load(name, PROTOCOLS[name].source)


def server_class(name: str) -> type:
    return _load(name, PROTOCOLS[name].server)


def make_source(config: DaqConfig, device: PlcConfig) -> Source:
    """The source that polls `device` by its protocol."""
    return source_class(device.protocol)(config, device=device)
