"""The simulated PLC served over OPC UA: the same plant, PLC clock and heartbeat as the
Modbus simulated PLC (simplc.SimPLC, whose scan this reuses), each value on a variable
node of an asyncua server, so the daemon, `furnace-daq check` and the tests can run
against a real OPC UA server.

The nodes are a daemon config's OPC UA map (`sim-plc --protocol opcua --config`), or by
default the map of config/gateway-opcua.yaml, derived for any furnace by one rule
(`default_items`): under Objects/Furnace, `ns=2;s=Furnace.<item>` for each thermocouple
(Double, degC), `t_air`, `plc_seconds` (UInt32), `heartbeat` (UInt16), `burners.<zone>`
(a Boolean array per zone fired by burners), `heat.<zone>` and `disturbances.<name>`
(Double, in the description's units); their browse names are the same without
`Furnace.` and with `_` for `.` (`/0:Objects/2:Furnace/2:burners_soak`). An open
thermocouple is served with the status BadSensorFailure.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

from asyncua import Server, ua
from asyncua.server.user_managers import UserManager

from furnace_model.simulation.furnace import Furnace
from furnace_model.simulation.scenario import Scenario

from .daqconfig import DISTURBANCES_KEY, HEAT_KEY, Signal, item_name
from .itemplc import ItemPLC
from .opcuamap import TYPES, UaBits, UaPoint
from .scaling import wrapped
from .simplc import ValueSource

NAMESPACE = "urn:furnace-daq:sim-plc"
for _name in ("asyncua",):
    logging.getLogger(_name).setLevel(logging.ERROR)


def default_items(furnace: Furnace) -> tuple[UaPoint | UaBits, ...]:
    """The default OPC UA map of a furnace (the module's docstring)."""
    def node(key: str) -> str:
        return f"ns=2;s=Furnace.{key}"

    items: list[UaPoint | UaBits] = [UaPoint(s, node(s)) for s in furnace.sensors]
    items += [UaPoint("t_air", node("t_air")), UaPoint("clock", node("plc_seconds"), "uint32"),
              UaPoint("heartbeat", node("heartbeat"), "uint16")]
    items += [UaBits(furnace.zones[i], (node(f"burners.{furnace.zones[i]}"),),
                     furnace.burners[i]) for i in furnace.switched]
    items += [UaPoint(item_name(HEAT_KEY, furnace.zones[i]),
                      node(item_name(HEAT_KEY, furnace.zones[i]))) for i in furnace.rated]
    items += [UaPoint(item_name(DISTURBANCES_KEY, d.name), node(item_name(DISTURBANCES_KEY,
                                                                          d.name)))
              for d in furnace.disturbances]
    return tuple(items)


class _Users(UserManager):
    """The one user the server accepts (with a user configured), or anonymous."""

    def __init__(self, users: dict[str, str]):
        self.users = users

    def get_user(self, iserver, username=None, password=None, certificate=None):
        from asyncua.crypto.permission_rules import User, UserRole

        if not self.users:
            return User(role=UserRole.User)
        if username is not None and self.users.get(username) == password:
            return User(role=UserRole.User, name=username)
        return None


class OpcUaPLC(ItemPLC):
    """A running simulated PLC on OPC UA: `await start()`, then `url`; `await stop()`.

    `items`: the nodes to serve (default: `default_items`); `signals`: the map's extra
    signals (simulated when the source has no value). Security: with `certificate` and
    `private_key` the server offers Basic256Sha256 Sign and SignAndEncrypt only; `users`
    ({name: password}) makes it refuse anonymous sessions."""

    item_types = (UaPoint, UaBits)
    default_items = staticmethod(default_items)

    def __init__(self, source: ValueSource | Scenario, *, items=None,
                 signals: tuple[Signal, ...] = (), path: str = "/furnace",
                 certificate: Path | None = None, private_key: Path | None = None,
                 users: dict[str, str] | None = None, port: int = 4840, **kw):
        super().__init__(source, items=items, signals=signals, port=port, **kw)
        self.path = path
        self.certificate, self.private_key = certificate, private_key
        self.users = dict(users or {})
        self._ua: Server | None = None
        self._nodes: dict[str, list] = {}
        """asyncua nodes by item name."""

    @property
    def url(self) -> str:
        return f"opc.tcp://{self.host}:{self.port}{self.path}"

    # -- life cycle ----------------------------------------------------------------------
    async def start(self) -> None:
        server = Server(user_manager=_Users(self.users))
        await server.init()
        server.set_endpoint(self.url)
        server.set_server_name("furnace-daq simulated PLC")
        if self.certificate is not None:
            await server.load_certificate(str(self.certificate))
            await server.load_private_key(str(self.private_key))
            server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
                                        ua.SecurityPolicyType.Basic256Sha256_Sign])
        if self.users:
            server.set_security_IDs(["Username"])
        idx = await server.register_namespace(NAMESPACE)
        furnace_obj = await server.nodes.objects.add_object(f"ns={idx};s=Furnace",
                                                            f"{idx}:Furnace")
        for item in self.items:
            self._nodes[item.name] = [await self._add(server, furnace_obj, idx, address, item)
                                      for address in item.nodes]
        await server.start()
        if self.port == 0:  # the port the system chose
            self.port = server.bserver._server.sockets[0].getsockname()[1]
        self._ua = server
        await self._start_scanning()

    async def _add(self, server: Server, parent, idx: int, address: str, item):
        """The variable of one node of the map: at its NodeId under Objects/Furnace, or at
        its browse path (objects made along the way)."""
        if isinstance(item, UaBits):
            vtype = ua.VariantType.Boolean
            initial = [False] * item.count if item.array else False
        else:
            vtype = getattr(ua.VariantType, TYPES[item.dtype])
            initial = "" if item.dtype == "string" else vtype_zero(item.dtype)
        if address.startswith("/"):
            steps = address[1:].split("/")
            node = server.nodes.root
            for step in steps[:-1]:
                try:
                    node = await node.get_child(step)
                except ua.UaStatusCodeError:
                    ns, _, name = step.rpartition(":")
                    node = await node.add_object(int(ns or idx), name)
            ns, _, name = steps[-1].rpartition(":")
            return await node.add_variable(int(ns or idx), name, initial, varianttype=vtype)
        nodeid = ua.NodeId.from_string(address)
        # a browse name without '.', which a browse path reads as a reference
        name = str(nodeid.Identifier).removeprefix("Furnace.").replace(".", "_")
        return await parent.add_variable(nodeid, f"{nodeid.NamespaceIndex}:{name}", initial,
                                         varianttype=vtype)

    async def stop(self) -> None:
        await self._stop_scanning()
        if self._ua is not None:
            server, self._ua = self._ua, None
            await server.stop()

    async def vanish(self, name: str) -> None:
        """Delete an item's node(s) from the server, as a PLC program download that drops
        a variable would (a fault drill)."""
        assert self._ua is not None
        nodes = self._nodes.pop(name)
        await self._ua.delete_nodes(nodes)

    # -- one scan ------------------------------------------------------------------------
    async def scan(self) -> None:
        await self._publish(self.advance())

    async def _publish(self, values) -> None:
        server = self._ua
        if server is None:
            return
        shown = self.item_values(values)
        for item in self.items:
            nodes = self._nodes.get(item.name)
            if not nodes:
                continue
            value = shown[item.name]
            if isinstance(item, UaBits):
                assert isinstance(value, list)
                if item.array:
                    dvs = [_dv(value, ua.VariantType.Boolean)]
                else:
                    dvs = [_dv(s, ua.VariantType.Boolean) for s in value]
                for node, dv in zip(nodes, dvs, strict=True):
                    await server.write_attribute_value(node.nodeid, dv)
                continue
            assert isinstance(value, float)
            await server.write_attribute_value(nodes[0].nodeid, _encoded(item, value))
        self.scans += 1


def vtype_zero(dtype: str) -> float | int:
    return 0.0 if dtype in ("float", "double") else 0


def _dv(value, vtype: ua.VariantType, status: ua.StatusCode | None = None) -> ua.DataValue:
    return ua.DataValue(ua.Variant(value, vtype),
                        StatusCode=status or ua.StatusCode(ua.StatusCodes.Good))


def _encoded(item: UaPoint, value: float | str) -> ua.DataValue:
    """The DataValue that reads as `value` through the item's scaling: an integer rounded
    and wrapped into its type (counters), NaN as BadSensorFailure."""
    vtype = getattr(ua.VariantType, TYPES[item.dtype])
    if item.dtype == "string":
        return _dv(f"{value:g}" if isinstance(value, float) else str(value), vtype)
    if isinstance(value, str) or not math.isfinite(value):
        return ua.DataValue(StatusCode=ua.StatusCode(ua.StatusCodes.BadSensorFailure))
    raw = item.scaling.raw(value)
    if item.dtype not in ("float", "double"):
        bits = {"sbyte": 8, "byte": 8, "int16": 16, "uint16": 16, "int32": 32, "uint32": 32,
                "int64": 64, "uint64": 64}[item.dtype]
        raw = wrapped(raw, bits, signed=not item.dtype.startswith(("u", "byte")))
    return _dv(raw, vtype)
