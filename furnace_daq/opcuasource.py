"""An OPC UA PLC as a source: the map's nodes read by subscription (the server sends each
change, sampled at the configured interval) or by one Read request per poll, decoded into
the same `Sample` as a Modbus PLC's.

The connection is the daemon's, as for Modbus: asyncua's own reconnect is off, so every
loss and redial shows on /daq/status and follows the device's backoff. A subscription that
the server refuses (no subscription service, too many subscriptions) falls back to polling,
and says so. Each node's status code becomes its item's quality (`quality_of`); a node the
server does not know, or a browse path that leads nowhere, makes its items comm_error and
is named in the sample's errors, while the other items stay ok.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import socket
from collections.abc import Sequence

from asyncua import Client, ua
from asyncua.crypto import security_policies
from asyncua.ua.uaerrors import UaError, UaStatusCodeError
from asyncua.ua.uaprotocol_auto import MessageSecurityMode

try:  # where asyncua keeps the connection state
    from asyncua.client.ua_client import UaClientState
except ImportError:  # pragma: no cover
    UaClientState = None  # type: ignore[assignment,misc]

from .daqconfig import DaqConfig
from .deviceconfig import PlcConfig
from .itemsample import Reading, build_sample
from .opcuamap import OpcUaSettings
from .registers import COMM_ERROR, OK, OUT_OF_RANGE, SENSOR_OPEN, STALE
from .sources import Sample, Source, SourceError, failure_kind

for _name in ("asyncua", "asyncua.client", "asyncua.common"):
    # Connection trouble is the daemon's to report; asyncua would log a traceback at each
    # second of an outage.
    logging.getLogger(_name).setLevel(logging.CRITICAL)

COMM_STATUSES = frozenset({
    "BadCommunicationError", "BadNotConnected", "BadServerNotConnected", "BadNoCommunication",
    "BadConnectionClosed", "BadTimeout", "BadShutdown", "BadServerHalted",
    "BadSecureChannelClosed", "BadSessionClosed", "BadSessionIdInvalid", "BadDeviceFailure",
    "BadOutOfService", "BadWaitingForInitialData", "BadNodeIdUnknown", "BadNodeIdInvalid",
    "BadNotReadable", "BadUserAccessDenied", "BadAttributeIdInvalid", "BadNoMatch"})
"""Statuses that mean no value came through (comm_error), named in the sample's errors."""

POLICIES = {"Basic256Sha256": "SecurityPolicyBasic256Sha256",
            "Aes128_Sha256_RsaOaep": "SecurityPolicyAes128Sha256RsaOaep",
            "Aes256_Sha256_RsaPss": "SecurityPolicyAes256Sha256RsaPss"}


def quality_of(status: ua.StatusCode) -> str:
    """The daemon's quality for an OPC UA status code: good -> ok; uncertain (last usable
    value, substitute, not accurate) -> stale; a sensor failure -> sensor_open; a value
    beyond its range -> out_of_range; every other bad status (no communication, unknown
    node, not readable, ...) -> comm_error."""
    if status.is_good():
        return OK
    name = status.name
    if status.is_uncertain():
        return OUT_OF_RANGE if name == "UncertainEngineeringUnitsExceeded" else STALE
    if name == "BadSensorFailure":
        return SENSOR_OPEN
    if name == "BadOutOfRange":
        return OUT_OF_RANGE
    return COMM_ERROR


def _status_text(status: ua.StatusCode) -> str:
    return status.name or f"0x{status.value:08X}"


class _Refused(Exception):
    """A server the gateway will not talk to, with the kind of failure and why."""

    def __init__(self, kind: str, why: str):
        super().__init__(why)
        self.kind, self.why = kind, why


def connect_failure(exc: BaseException) -> tuple[str, str]:
    """(kind, why) of a failed dial: the socket's failures as Modbus names them, a
    server that refused the session by its status code."""
    if isinstance(exc, _Refused):
        return exc.kind, exc.why
    if isinstance(exc, TimeoutError):
        return "connect timeout", "no answer"
    if isinstance(exc, UaStatusCodeError):
        name = ua.StatusCode(exc.code).name
        if name in ("BadUserAccessDenied", "BadIdentityTokenInvalid",
                    "BadIdentityTokenRejected"):
            return "access denied", f"{name}: user or password refused"
        if "Certificate" in name or "Security" in name:
            return "security refused", f"{name}: the server does not accept this security"
        return "session refused", name
    if isinstance(exc, OSError | socket.gaierror):
        return failure_kind(exc), str(exc) or type(exc).__name__
    return "session refused", f"{type(exc).__name__}: {exc}"


class _Changes:
    """asyncua's subscription handler: the latest DataValue of each node."""

    def __init__(self, source: OpcUaSource):
        self.source = source

    def datachange_notification(self, node, val, data) -> None:
        self.source._changed(node.nodeid, data.monitored_item.Value)

    def status_change_notification(self, status) -> None:
        code = getattr(status, "Status", status)
        if isinstance(code, ua.StatusCode) and not code.is_good():
            self.source._ended = _status_text(code)


class OpcUaSource(Source):
    """One OPC UA server (a PLC's, or a gateway's in front of it)."""

    name = "opcua"

    def __init__(self, config: DaqConfig, host: str | None = None, port: int | None = None,
                 device: PlcConfig | None = None, items: list | None = None):
        self.config = config
        self.device = device if device is not None else config.devices[0]
        self.host = host or self.device.host
        self.port = port or self.device.port
        self.settings = self.device.opcua or OpcUaSettings()
        self.items = items if items is not None else config.device_items(self.device)
        self.addresses: tuple[str, ...] = tuple(dict.fromkeys(
            a for it in self.items for a in it.nodes))
        """Every node of the map on this device, once, in the order of the config."""
        self.mode = self.settings.mode
        """How values come in on the current connection: subscribe, or poll (configured,
        or the fallback when the server refused the subscription)."""
        self.notes: list[str] = []
        """What the last connection found worth telling (a refused subscription)."""
        self.unresolved: dict[str, str] = {}
        """Nodes of the map the server has not got (by address): why."""
        self._client: Client | None = None
        self._ids: dict[str, ua.NodeId] = {}
        self._by_id: dict[ua.NodeId, str] = {}
        self._latest: dict[str, ua.DataValue] = {}
        self._arrived = asyncio.Event()
        self._ended: str | None = None

    # -- where -----------------------------------------------------------------------------
    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"opc.tcp://{host}:{self.port}{self.settings.path}"

    @property
    def where(self) -> str:
        return self.url

    @property
    def transport_text(self) -> str:
        s = self.settings.security
        security = "no security" if s.policy == "None" else f"{s.policy} {s.mode}"
        user = f", user {self.settings.user}" if self.settings.user else ""
        return f"OPC UA {self.url} ({self.mode}, {security}{user})"

    @property
    def plan_text(self) -> str:
        """What one read covers, as `furnace-daq check` says it."""
        return f"{len(self.addresses)} node(s)"

    @property
    def connected(self) -> bool:
        client = self._client
        if client is None or self._ended is not None:
            return False
        return UaClientState is None or client.state is UaClientState.CONNECTED

    # -- connection ------------------------------------------------------------------------
    async def connect(self) -> None:
        await self.close()
        timeout = self.device.timeout_s
        client = Client(self.url, timeout=timeout, watchdog_intervall=max(timeout, 0.2))
        self._ended = None
        try:
            await self._secure(client)
            await asyncio.wait_for(client.connect(), 4 * timeout)
        except (TimeoutError, OSError, UaError, ValueError, _Refused) as exc:
            await _quietly_disconnect(client, timeout)
            kind, why = connect_failure(exc)
            raise SourceError(f"cannot connect to {self.url}: {why}", kind) from None
        self._client = client
        try:
            await asyncio.wait_for(self._resolve(client), 2 * timeout)
            self.mode, self.notes = self.settings.mode, []
            if self.mode == "subscribe":
                await self._subscribe(client, timeout)
        except (TimeoutError, OSError, UaError) as exc:
            await self.close()
            kind, why = connect_failure(exc)
            raise SourceError(f"{self.url}: connected, but setting up the reads failed: "
                              f"{why}", "connection lost" if kind == "session refused"
                              else kind) from None

    async def _secure(self, client: Client) -> None:
        s = self.settings
        if s.user is not None:
            client.set_user(s.user)
            if s.password is not None:
                client.set_password(s.password)
        sec = s.security
        if sec.policy == "None":
            return
        from cryptography import x509

        trusted = sec.server_certificate
        assert trusted is not None and sec.certificate is not None
        own = _load_certificate(sec.certificate.read_bytes())
        with contextlib.suppress(x509.ExtensionNotFound, IndexError):
            # the session's application URI must be the one in the gateway's certificate
            client.application_uri = own.extensions.get_extension_for_class(
                x509.SubjectAlternativeName).value.get_values_for_type(
                x509.UniformResourceIdentifier)[0]
        pinned = _load_certificate(trusted.read_bytes())
        policy = getattr(security_policies, POLICIES[sec.policy])
        mode = getattr(MessageSecurityMode, sec.mode)
        # The server's endpoints (an unsecured GetEndpoints) say which certificate it
        # holds: one other than the trusted is refused before any secret is sent to it.
        endpoints = await asyncio.wait_for(client.connect_and_get_server_endpoints(),
                                           2 * self.device.timeout_s)
        offered = [e for e in endpoints if e.SecurityMode == mode
                   and e.SecurityPolicyUri == policy.URI]
        if not offered:
            raise _Refused("security refused", f"the server offers no endpoint with "
                                               f"{sec.policy} {sec.mode}")
        presented = _load_certificate(_first_certificate(offered[0].ServerCertificate))
        if presented != pinned:
            raise _Refused("security refused", f"the server's certificate "
                                               f"({presented.subject.rfc4514_string()}) is not "
                                               f"the trusted one, {trusted}")

        async def only_the_trusted_server(cert, _app) -> None:
            if cert != pinned:
                raise ua.UaStatusCodeError(ua.StatusCodes.BadCertificateUntrusted)

        client.certificate_validator = only_the_trusted_server
        await client.set_security(policy,
                                  str(sec.certificate), str(sec.private_key),
                                  server_certificate=str(trusted), mode=mode)

    async def _resolve(self, client: Client) -> None:
        """NodeIds of the map's nodes: browse paths translated in one request, namespace
        URIs looked up; what the server has not got goes to `unresolved`."""
        self._ids, self.unresolved = {}, {}
        paths = [a for a in self.addresses if a.startswith("/")]
        if paths:
            results = await client.translate_browsepaths(ua.NodeId(ua.ObjectIds.RootFolder),
                                                         paths)
            for path, result in zip(paths, results, strict=True):
                if result.StatusCode.is_good() and result.Targets:
                    self._ids[path] = result.Targets[0].TargetId.NodeId \
                        if hasattr(result.Targets[0].TargetId, "NodeId") \
                        else result.Targets[0].TargetId
                else:
                    self.unresolved[path] = f"browse path not found ({_status_text(result.StatusCode)})"
        namespaces: list[str] | None = None
        for address in self.addresses:
            if address.startswith("/"):
                continue
            text = address
            m = re.match(r"^nsu=([^;]+);(.*)$", address)
            if m:
                if namespaces is None:
                    namespaces = await client.get_namespace_array()
                if m.group(1) not in namespaces:
                    self.unresolved[address] = f"namespace {m.group(1)} unknown to the server"
                    continue
                text = f"ns={namespaces.index(m.group(1))};{m.group(2)}"
            self._ids[address] = ua.NodeId.from_string(text)
        self._by_id = {nid: a for a, nid in self._ids.items()}

    async def _subscribe(self, client: Client, timeout: float) -> None:
        """A subscription on every resolved node; refused as a whole, the source polls."""
        period = self.settings.sampling_interval_ms
        if period is None:
            period = 1000.0 * self.config.poll_period_s
        self._latest = {}
        self._arrived = asyncio.Event()
        addresses = list(self._ids)
        try:
            sub = await client.create_subscription(period, _Changes(self))
            handles = await sub.subscribe_data_change([client.get_node(self._ids[a])
                                                       for a in addresses],
                                                      sampling_interval=period) \
                if addresses else []
        except UaStatusCodeError as exc:
            self.mode = "poll"
            self.notes.append(f"subscription refused ({ua.StatusCode(exc.code).name}): "
                              "polling instead")
            return
        for address, handle in zip(addresses, _as_list(handles), strict=True):
            if isinstance(handle, ua.StatusCode):  # this node refused
                self.unresolved[address] = _status_text(handle)
                del self._ids[address]
        # the first values: a read right after connecting must not find them missing
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(2 * timeout):
                while not all(a in self._latest for a in self._ids):
                    self._arrived.clear()
                    await self._arrived.wait()

    def _changed(self, node_id: ua.NodeId, value: ua.DataValue) -> None:
        address = self._by_id.get(node_id)
        if address is not None:
            self._latest[address] = value
            self._arrived.set()

    async def close(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            await _quietly_disconnect(client, self.device.timeout_s)

    # -- reading ---------------------------------------------------------------------------
    async def read_values(self) -> dict[str, ua.DataValue | str]:
        """Each node of the map: its DataValue, or why there is none. Raises SourceError
        when the connection fails. A poll's Read is bounded by nine tenths of the timeout,
        so that a slow server is named here rather than cut off by the daemon's budget."""
        client = self._client
        if client is None:
            raise SourceError("not connected", "connection lost")
        if not self.connected:
            why = f"server ended the subscription ({self._ended})" if self._ended \
                else "connection lost"
            raise SourceError(f"{self.url}: {why}", "connection lost")
        out: dict[str, ua.DataValue | str] = dict(self.unresolved)
        addresses = list(self._ids)
        if self.mode == "poll" and addresses:
            budget = 0.9 * self.device.timeout_s
            try:
                values = await asyncio.wait_for(
                    client.read_attributes([client.get_node(self._ids[a]) for a in addresses]),
                    budget)
            except TimeoutError:
                raise SourceError(f"read of {len(addresses)} node(s) at {self.url}: no answer "
                                  f"within {budget:.3g} s", "poll timeout") from None
            except (ConnectionError, OSError) as exc:
                raise SourceError(f"{self.url}: {exc or 'connection lost'}",
                                  "connection lost") from None
            except UaStatusCodeError as exc:
                raise SourceError(f"{self.url}: read refused "
                                  f"({ua.StatusCode(exc.code).name})", "read refused") from None
            out.update(zip(addresses, values, strict=True))
        else:
            for a in addresses:
                out[a] = self._latest.get(a, "no value notified yet")
        return out

    async def read(self) -> Sample:
        return self.sample(await self.read_values())

    def sample(self, values: dict[str, ua.DataValue | str]) -> Sample:
        """The sample of one read: each item's reading from its node(s)."""
        got = {it.name: _reading(it.nodes, values) for it in self.items}
        return build_sample(self.config, self.items, got)


def _reading(nodes: Sequence[str], values: dict[str, ua.DataValue | str]) -> Reading:
    """An item's reading: one node's value, or one Boolean per node of a bit range."""
    raws, quality = [], OK
    for address in nodes:
        dv = values.get(address, "not read")
        if isinstance(dv, str):
            return Reading(None, COMM_ERROR, f"{address}: {dv}")
        q = quality_of(dv.StatusCode)
        if q == COMM_ERROR or dv.Value is None or dv.Value.Value is None:
            why = _status_text(dv.StatusCode) if q == COMM_ERROR else "no value"
            return Reading(None, COMM_ERROR, f"{address}: {why}")
        if q in (SENSOR_OPEN, OUT_OF_RANGE):  # the quality says it, as for a register
            return Reading(float("nan") if q == SENSOR_OPEN else None, q)
        if q == STALE:
            quality = STALE
        raws.append(dv.Value.Value)
    return Reading(raws[0] if len(nodes) == 1 else raws, quality)


def _as_list(handles) -> list:
    return list(handles) if isinstance(handles, list | tuple) else [handles]


def _first_certificate(chain: bytes) -> bytes:
    """The server's own certificate from the DER chain an endpoint carries."""
    from asyncua.client.client import _first_cert_from_chain

    return _first_cert_from_chain(chain)


def _load_certificate(data: bytes):
    from cryptography import x509

    return x509.load_pem_x509_certificate(data) if data.lstrip().startswith(b"-----") \
        else x509.load_der_x509_certificate(data)


async def _quietly_disconnect(client: Client, timeout: float) -> None:
    """Close a session that may be dead already; whatever goes wrong, the client's tasks
    end and its socket is closed."""
    with contextlib.suppress(Exception):
        await asyncio.wait_for(client.disconnect(), timeout)
    with contextlib.suppress(Exception):
        client.disconnect_socket()
