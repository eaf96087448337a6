"""Commissioning check: dial every configured device, read every configured point once, and
say for each what came back, as `telegraf --test` does for its inputs.

A wrong address, word order or scale in the map is otherwise found hours later in the MCAP
file; here it is one table on the terminal. The reads, the decoding and the qualities are
the daemon's own (sources.ModbusSource, registers.Point; for OPC UA and S7 their sources),
so a point that is ok here is ok for the daemon. Bounded in time: one connect and one read within `plc.timeout_s` each, and
at most `burners.can.timeout_s` listening to the CAN bus.
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass, field

from .daqconfig import SIGNALS_KEY, DaqConfig
from .deviceconfig import PlcConfig
from .registers import BIT_TABLES, COMM_ERROR, OK, BitRange, Image, Point, ReadRequest, span
from .sources import AllRefused, CanSource, ModbusSource, SourceError, exception_text

NOT_READ = "not read"


@dataclass
class PointCheck:
    """One configured point as read: the row of the table."""

    key: str
    """Key path in the config file (thermocouples.soak_1, burners.modbus.heat, heat.soak,
    signals.o2_pct)."""
    where: str
    """Table and address(es), or the CAN frame and bits."""
    raw: str = ""
    value: str = ""
    quality: str = COMM_ERROR
    error: str = ""

    @property
    def ok(self) -> bool:
        return self.quality == OK


@dataclass
class CheckReport:
    devices: list[tuple[str, str]] = field(default_factory=list)
    """(device, what happened when dialling it)."""
    points: list[PointCheck] = field(default_factory=list)
    elapsed_s: float = 0.0

    @property
    def failed(self) -> list[PointCheck]:
        return [p for p in self.points if not p.ok]

    @property
    def ok(self) -> bool:
        return bool(self.points) and not self.failed


def _where(item: Point | BitRange) -> str:
    _table, first, end = span(item)
    last = end - 1
    text = f"{item.table} {first}" + (f"-{last}" if last > first else "")
    if isinstance(item, BitRange) and item.packed:
        text += f" bits {item.bit}-{item.bit + item.count - 1}"
    return text


def _block_of(item: Point | BitRange, refused: dict[ReadRequest, int | None]) -> int | None:
    for req, code in refused.items():
        if req.table == item.table and req.address <= item.address < req.end:
            return code if code is not None else -1
    return None


def _states_text(key: str, states: list[bool]) -> str:
    """A signal's bit as on/off; a zone's burners as how many of them are on."""
    if key.startswith(f"{SIGNALS_KEY}."):
        return "on" if states[0] else "off"
    return f"{sum(states)} of {len(states)} on"


def _row(item: Point | BitRange, key: str, image: Image,
         refused: dict[ReadRequest, int | None], alone: Image | None = None,
         blame: dict[str, str] | None = None) -> PointCheck:
    """The row of one point. A point in a refused block is comm_error, as the daemon reads
    it; `alone` holds what it read on its own, `blame` why its block was refused (the key
    of the point that breaks it, or the point's own refusal)."""
    row = PointCheck(key, _where(item))
    code = _block_of(item, refused)
    if code is not None:
        row.error = f"block refused: {exception_text(None if code < 0 else code)}"
        why = (blame or {}).get(item.name)
        if why:
            row.error += f"; {why}"
        words = None if alone is None else alone.words(item)
        if words is not None:  # what it reads on its own, for the table's raw column
            shown = _row(item, key, alone, {})
            row.raw, row.value = shown.raw, shown.value
        return row
    words = image.words(item)
    if words is None:
        row.error = NOT_READ
        return row
    if item.table in BIT_TABLES and isinstance(item, BitRange):
        states = item.states([bool(b) for b in words])
        row.raw = "".join(str(int(b)) for b in words)
        row.value = _states_text(key, states)
        row.quality = OK
        return row
    if isinstance(item, BitRange):  # packed in registers
        states = item.states(words)
        row.raw = " ".join(f"0x{w:04x}" for w in words)
        row.value = _states_text(key, states)
        row.quality = OK
        return row
    assert isinstance(item, Point)
    row.raw = " ".join(str(w) for w in words)
    value, row.quality = item.value(words)
    if isinstance(value, str):
        row.value = repr(value)
        return row
    if value is not None:
        row.value = f"{value:g}"
        return row
    raw = item.raw(words)
    if raw != raw:
        row.error = "float NaN: open sensor"
    elif raw in item.sentinels:
        row.error = f"raw {raw:g} is a sentinel: open sensor"
    else:
        row.value = f"{raw * item.scale + item.offset:g}"
        lo = "-inf" if item.lo is None else f"{item.lo:g}"
        hi = "inf" if item.hi is None else f"{item.hi:g}"
        row.error = f"outside range [{lo}, {hi}]"
    return row


async def check_modbus(config: DaqConfig, report: CheckReport,
                       plc: PlcConfig | None = None) -> None:
    """Dial one Modbus device (the only one by default), read every request of the
    daemon's plan for it once, one row per point."""
    plc = plc if plc is not None else config.devices[0]
    source = ModbusSource(config, device=plc)
    keys = config.key_paths()
    device = f"{source.transport_text} (unit {plc.device_id})"
    if config.several_devices:
        device = f"{plc.name}: {device}"
    image, refused = Image(), {}
    alone, blame = Image(), {}
    error = ""
    # the requests one after the other, with the pauses and busy retries the device asked
    # for, after the other devices of its serial bus
    w = plc.workarounds
    n = max(1, len(source.requests))
    budget = plc.timeout_s * n + w.pause_between_requests_s * n + w.pause_after_connect_s \
        + plc.busy_retries * (plc.busy_retries_wait_s + plc.timeout_s) + source.line_wait_s
    try:
        await source.connect()
        try:
            image, refused = await asyncio.wait_for(source.read_image(), budget)
        except TimeoutError:
            error = f"no answer within {budget:g} s"
        except AllRefused as exc:  # the table says which points broke which block
            refused = exc.refused
        except SourceError as exc:
            error = str(exc)
        report.devices.append((device, error or
                               f"connected, {len(source.requests)} read request(s)"))
        if refused:
            alone, blame = await asyncio.wait_for(
                split_refused(source, refused, keys), budget * (1 + len(source.items)))
    except (SourceError, TimeoutError) as exc:
        error = error or str(exc) or "no answer"
        report.devices.append((device, error))
    finally:
        await source.close()
    for item in source.items:
        row = _row(item, keys.get(item.name, item.name), image, refused, alone, blame)
        if error:
            row.error, row.quality = error, COMM_ERROR
        report.points.append(row)


async def check_nodes(config: DaqConfig, report: CheckReport, plc: PlcConfig) -> None:
    """Dial a device read item by item (OPC UA nodes, S7 addresses) with the daemon's own
    source, read every item once, one row per item naming its node(s) or address(es); one
    that fails is named with the PLC's reason."""
    from .protocols import make_source

    source = make_source(config, plc)
    keys = config.key_paths()
    device = source.transport_text  # type: ignore[attr-defined]
    if config.several_devices:
        device = f"{plc.name}: {device}"
    sample, error = None, ""
    try:
        await source.connect()
        try:
            sample = await asyncio.wait_for(source.read(), 2 * plc.timeout_s)
        except TimeoutError:
            error = f"no answer within {2 * plc.timeout_s:g} s"
        except SourceError as exc:
            error = str(exc)
        notes = "; ".join(getattr(source, "notes", ()))
        plan = getattr(source, "plan_text", "read")
        report.devices.append((device, error or f"connected, {plan}"
                               + (f"; {notes}" if notes else "")))
    except SourceError as exc:
        error = str(exc)
        report.devices.append((device, error))
    finally:
        await source.close()
    for item in source.items:  # type: ignore[attr-defined]
        row = PointCheck(keys.get(item.name, item.name), ", ".join(item.nodes))
        if error or sample is None:
            row.error = error or NOT_READ
        else:
            _node_row(row, item, sample)
        report.points.append(row)


def _node_row(row: PointCheck, item, sample) -> None:
    """A row from the daemon's sample: the item's value and quality, and why it was not
    read: the errors that name its nodes (said without the node, which the row shows), or
    what the PLC answered for the part of its memory the item is in."""
    errors = [e.split(": ", 1)[1] if ": " in e else e for e in sample.errors
              if any(e.startswith(f"{n}:") for n in item.nodes)]
    errors = errors or [u.what for u in sample.unread if item.name in u.items]
    if item.name == "clock":
        value, quality = sample.plc_seconds, OK if sample.plc_seconds is not None else COMM_ERROR
    elif item.name == "heartbeat":
        value = sample.heartbeat
        quality = OK if value is not None else COMM_ERROR
    elif sample.burners is not None and item.name in sample.burners:
        value, quality = _states_text(row.key, sample.burners[item.name]), sample.burner_quality
    elif item.name in sample.quality:
        value, quality = sample.values.get(item.name), sample.quality[item.name]
        if isinstance(value, bool):
            value = "on" if value else "off"
    else:
        value, quality = None, COMM_ERROR
    row.quality = quality
    if isinstance(value, float):
        row.value = f"{value:g}"
    elif value is not None:
        row.value = repr(value) if isinstance(value, str) and item.name == "heartbeat" \
            else str(value)
    row.error = "; ".join(errors) or ("" if quality == OK else quality.replace("_", " "))


async def split_refused(source: ModbusSource, refused: dict[ReadRequest, int | None],
                        keys: dict[str, str]) -> tuple[Image, dict[str, str]]:
    """Which point breaks each refused block: its points read in halves, each half that is
    refused split again, down to single points (a few requests for a block of many).
    Returns what the points read on their own, and for each point of a refused block of
    several what broke it: the point itself, the points that did, or, when every point
    reads alone, the unmapped addresses the block spans between them."""
    alone = Image()
    blame: dict[str, str] = {}
    for req in refused:
        inside = sorted((it for it in source.items
                         if it.table == req.table and req.address <= it.address < req.end),
                        key=lambda it: span(it)[1])
        if len(inside) < 2:
            continue  # a point read on its own: its refusal is its own
        culprits: list[Point | BitRange] = []
        halves = [inside[len(inside) // 2:], inside[:len(inside) // 2]]
        while halves:
            part = halves.pop()
            first, end = span(part[0])[1], max(span(it)[2] for it in part)
            part_req = ReadRequest(req.table, first, end - first)
            values, code = await source.read_block(part_req)
            if values is not None:
                alone.put(part_req, values)
            elif len(part) == 1:
                culprits.append(part[0])
                blame[part[0].name] = "this point breaks it: refused alone too" \
                    if code == refused[req] else \
                    f"this point breaks it: refused alone with {exception_text(code)}"
            else:
                halves += [part[len(part) // 2:], part[:len(part) // 2]]
        names = ", ".join(keys.get(c.name, c.name) for c in culprits)
        for it in inside:
            if it.name not in blame:
                blame[it.name] = (
                    f"broken by {names}; alone this point reads" if culprits else
                    f"every point of {req.table} {req.address}-{req.end - 1} reads alone: "
                    "the device refuses the unmapped addresses between them (lower "
                    "max_gap_registers or max_gap_bits, or one_request_per_field)")
    return alone, blame


async def check_can(config: DaqConfig, report: CheckReport) -> None:
    """Listen to the flame scanners' bus until every zone's frame came, at most the CAN
    timeout; one row per zone."""
    can_cfg = config.can
    assert can_cfg is not None
    source = CanSource(can_cfg)
    device = f"CAN {can_cfg.interface}:{can_cfg.channel}"
    error = ""
    try:
        await source.connect()
        deadline = time.monotonic() + can_cfg.timeout_s
        while time.monotonic() < deadline and not all(source.latest(z) for z in can_cfg.frames):
            await asyncio.sleep(0.02)
        report.devices.append((device, f"open, {source.frames} frame(s) heard"))
    except SourceError as exc:
        error = str(exc)
        report.devices.append((device, error))
    try:
        for zone, frame in can_cfg.frames.items():
            n = frame.burners
            row = PointCheck(f"burners.can.{zone}", f"CAN id 0x{frame.can_id:x} bits "
                                                    f"{frame.start_bit}-{frame.start_bit + n - 1}")
            data = source.last_data.get((frame.can_id, frame.extended))
            latest = source.latest(zone)
            if error:
                row.error = error
            elif data is None:
                row.error = f"no frame within {can_cfg.timeout_s:g} s"
            elif latest is None:
                row.raw = data.hex(" ")
                row.error = f"frame of {len(data)} byte(s) too short for these bits"
            else:
                row.raw = data.hex(" ")
                row.value = f"{sum(latest)} of {n} on"
                row.quality = OK
            report.points.append(row)
    finally:
        await source.close()


async def check(config: DaqConfig) -> CheckReport:
    """Every configured device dialled and every configured point read once."""
    t0 = time.monotonic()
    report = CheckReport()
    if config.plc_items():
        # every device dialled at once: one that is down costs its timeout, not the others'
        subs = [CheckReport() for _ in config.devices]
        await asyncio.gather(*((check_modbus if plc.protocol == "modbus" else check_nodes)(
            config, sub, plc) for plc, sub in zip(config.devices, subs, strict=True)))
        for sub in subs:
            report.devices += sub.devices
            report.points += sub.points
    if config.burner_source in ("can", "both") and config.can is not None:
        await check_can(config, report)
    report.elapsed_s = time.monotonic() - t0
    return report


def format_report(report: CheckReport) -> str:
    """The devices, then one aligned row per point: key, where, raw, value, quality, error."""
    lines = [f"{device}: {what}" for device, what in report.devices]
    header = ("key", "table/address", "raw", "value", "quality", "error")
    rows = [header] + [(p.key, p.where, p.raw or "-", p.value or "-", p.quality, p.error)
                       for p in report.points]
    widths = [max(len(r[i]) for r in rows) for i in range(len(header) - 1)]
    lines.append("")
    for r in rows:
        lines.append("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=False))
                     + "  " + r[-1])
    return "\n".join(line.rstrip() for line in lines)
