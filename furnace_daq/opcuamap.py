"""The map of an OPC UA PLC and how it is reached: each item of the daemon's map (a
thermocouple, a zone's burners, the ambient, the PLC clock, the heartbeat, a heat input,
a disturbance, a signal) named by its node, and the device's `opcua:` settings
(subscription or polling, security, user). Checked at load with key-path errors, as the
register map is; no OPC UA library is needed to read it.

A node is written as its NodeId (`ns=2;s=Soak.TC1`, `i=2258`, `nsu=urn:plant;s=TC1`) or
as a browse path from the Root folder in OPC UA's relative-path text
(`/0:Objects/2:Furnace/2:TC1`), resolved once per connection.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from furnace_model.config import Node

from .scaling import SCALING_KEYS, Scaling, parse_scaling

PROTOCOL = "opcua"
ADDRESSING = "a node (node: or nodes:)"
"""How an item of this protocol is given in the map, as errors name it."""
TYPES: dict[str, str] = {
    "boolean": "Boolean", "sbyte": "SByte", "byte": "Byte", "int16": "Int16",
    "uint16": "UInt16", "int32": "Int32", "uint32": "UInt32", "int64": "Int64",
    "uint64": "UInt64", "float": "Float", "double": "Double", "string": "String",
}
"""Map type -> OPC UA built-in type (the VariantType a simulated PLC serves)."""
NUMERIC_TYPES = tuple(t for t in TYPES if t not in ("boolean", "string"))
MODES = ("subscribe", "poll")
POLICIES = ("None", "Basic256Sha256", "Aes128_Sha256_RsaOaep", "Aes256_Sha256_RsaPss")
SECURITY_MODES = ("None", "Sign", "SignAndEncrypt")

_NODE_ID = re.compile(r"^(ns=\d+;|nsu=[^;]+;)?(i=\d+|s=.+|g=[0-9A-Fa-f]{8}(-[0-9A-Fa-f]{4}){3}"
                      r"-[0-9A-Fa-f]{12}|b=[A-Za-z0-9+/]+=*)$")
_PATH_ELEMENT = re.compile(r"^(\d+:)?[^/]+$")


def node_text(node: Node) -> str:
    """A NodeId or a browse path, checked for its form."""
    text = node.string()
    if text.startswith("/"):
        parts = text[1:].split("/")
        if not all(_PATH_ELEMENT.match(p) for p in parts):
            raise node.error(f"'{text}' is not a browse path: /0:Objects/2:Furnace/2:TC1 "
                             "(each step namespace:BrowseName)")
        return text
    if not _NODE_ID.match(text):
        raise node.error(f"'{text}' is not a NodeId: ns=2;s=Soak.TC1, ns=3;i=1001, "
                         "nsu=URI;s=NAME, or a browse path /0:Objects/2:Furnace/2:TC1")
    return text


@dataclass(frozen=True)
class UaPoint:
    """One value of the map read from an OPC UA node."""

    protocol: ClassVar[str] = PROTOCOL
    name: str
    node: str
    """NodeId text, or a browse path starting with '/'."""
    dtype: str = "double"
    scaling: Scaling = Scaling()
    device: str = ""

    @property
    def nodes(self) -> tuple[str, ...]:
        return (self.node,)

    @property
    def lo(self) -> float | None:
        return self.scaling.lo

    @property
    def hi(self) -> float | None:
        return self.scaling.hi


@dataclass(frozen=True)
class UaBits:
    """On/off states (one zone's burners, or a bit signal): one Boolean array node of
    `count` elements, or `count` Boolean nodes."""

    protocol: ClassVar[str] = PROTOCOL
    name: str
    nodes: tuple[str, ...]
    count: int
    invert: bool = False
    device: str = ""

    @property
    def array(self) -> bool:
        return len(self.nodes) == 1 and self.count > 1

    def states(self, values: list[bool]) -> list[bool]:
        return [bool(v) != self.invert for v in values]


def is_ua_entry(node: Node) -> bool:
    """Whether a map entry names OPC UA nodes (`node:` or `nodes:`) rather than registers."""
    return isinstance(node.value, dict) and ("node" in node.value or "nodes" in node.value)


def is_ua_bit_entry(node: Node) -> bool:
    """Whether a `signals:` entry is one Boolean node."""
    return is_ua_entry(node) and node.value.get("type") == "boolean"


def ua_point(node: Node, name: str, extra: tuple[str, ...] = (),
             numeric: bool = True) -> UaPoint:
    """A map entry `{node: NODE, type: TYPE, scale, offset, sentinels, range}`; the caller
    sets `device`."""
    node.mapping({"node", "type", "device", *SCALING_KEYS, *extra})
    dtype = node.get_string("type", "double", choices=tuple(TYPES))
    if dtype == "boolean":
        raise node.child("type").error(f"{name} is a number; boolean is for burner states "
                                       "and bit signals")
    if dtype == "string":
        if numeric:
            raise node.child("type").error(f"{name} is a number; string is for the heartbeat")
        for key in SCALING_KEYS:
            if node.has(key):
                raise node.child(key).error("a string has no scale, offset, sentinels or "
                                            "range")
    return UaPoint(name, node_text(node.child("node")), dtype, parse_scaling(node))


def ua_bits(node: Node, name: str, n: int, extra: tuple[str, ...] = ()) -> UaBits:
    """`{node: ARRAY}` (a Boolean array of n elements) or `{nodes: [N1, ..., Nn]}` (n
    Boolean nodes), with `invert` for active-low states; the caller sets `device`."""
    node.mapping({"node", "nodes", "type", "invert", "device", *extra})
    node.get_string("type", "boolean", choices=("boolean",))
    if node.has("node") == node.has("nodes"):
        raise node.error("give node: (one Boolean array node) or nodes: (one Boolean node "
                         "per state), not both" if node.has("node") else
                         "give node: or nodes:")
    if node.has("node"):
        nodes: tuple[str, ...] = (node_text(node.child("node")),)
    else:
        nodes = tuple(node_text(e) for e in node.child("nodes").elements())
        if len(nodes) != n:
            raise node.child("nodes").error(f"{name} has {n} burner(s): expected {n} nodes, "
                                            f"got {len(nodes)}")
    return UaBits(name, nodes, n, node.get_bool("invert", False))


@dataclass(frozen=True)
class UaSecurity:
    policy: str = "None"
    mode: str = "None"
    certificate: Path | None = None
    """The gateway's own certificate (DER or PEM) and its private key."""
    private_key: Path | None = None
    server_certificate: Path | None = None
    """The one server certificate trusted: a server presenting another is refused."""


@dataclass(frozen=True)
class OpcUaSettings:
    """A device's `opcua:` section."""

    path: str = ""
    """The endpoint's path: opc.tcp://HOST:PORT/PATH."""
    mode: str = "subscribe"
    """subscribe: the server sends changes (sampled every `sampling_interval_ms`); falls
    back to polling when the server offers no subscriptions. poll: one Read per poll."""
    sampling_interval_ms: float | None = None
    """None: the daemon's poll period."""
    security: UaSecurity = UaSecurity()
    user: str | None = None
    password: str | None = None


OPCUA_KEYS = ("path", "mode", "sampling_interval_ms", "security", "user", "password")


def parse_opcua(node: Node) -> OpcUaSettings:
    """A device's `opcua:` section; file paths are taken relative to the config's folder."""
    node.mapping(OPCUA_KEYS)
    path = node.get_string("path", "")
    if path and not path.startswith("/"):
        raise node.child("path").error(f"expected the endpoint's path from its '/', "
                                       f"e.g. /furnace, got '{path}'")
    sampling = node.child("sampling_interval_ms", None)
    sn = node.child("security", {}).mapping({"policy", "mode", "certificate", "private_key",
                                             "server_certificate"})
    policy = sn.get_string("policy", "None", choices=POLICIES)
    mode = sn.get_string("mode", "None" if policy == "None" else "SignAndEncrypt",
                         choices=SECURITY_MODES)
    if (policy == "None") != (mode == "None"):
        raise sn.child("mode").error(f"policy {policy} goes with mode "
                                     f"{'None' if policy == 'None' else 'Sign or SignAndEncrypt'}")
    here = Path(node.file).parent if node.file and not node.file.startswith("<") else Path()
    files: dict[str, Path | None] = {}
    for key in ("certificate", "private_key", "server_certificate"):
        if policy == "None":
            if sn.has(key):
                raise sn.child(key).error("applies to a security policy other than None")
            files[key] = None
            continue
        path_ = here / sn.get_string(key)
        if not path_.is_file():
            raise sn.child(key).error(f"no such file: {path_}")
        files[key] = path_
    user = node.child("user", None)
    if node.has("password") and user.value is None:
        raise node.child("password").error("goes with user:")
    return OpcUaSettings(
        path=path, mode=node.get_string("mode", "subscribe", choices=MODES),
        sampling_interval_ms=None if sampling.value is None else sampling.number(lo=0.0,
                                                                                 hi=3.6e6),
        security=UaSecurity(policy, mode, files["certificate"], files["private_key"],
                            files["server_certificate"]),
        user=None if user.value is None else user.string(),
        password=str(node.child("password").value) if node.has("password") else None)
