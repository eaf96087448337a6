"""A ready daemon config for a furnace description: the default register map of
`ServedMap.default` written out as the YAML an engineer edits (`furnace-daq config
--furnace F`).

Why generate it. Another furnace's map has as many thermocouple entries as its description
has thermocouples and a burner entry per zone, at addresses that follow one rule; writing them
by hand invites a missing sensor or an overlap. The engineer starts from this file, which
the simulated PLC serves as it is (`sim-plc --furnace F`), and changes addresses, types and
orders to the plant PLC's I/O list; `furnace-daq check` then reads every point once.
"""

from __future__ import annotations

from furnace_model.simulation.furnace import Furnace

from .servedmap import ServedMap


def gateway_yaml(furnace: Furnace, furnace_ref: str, *, port: int = 5020) -> str:
    """The config text: `furnace: furnace_ref` (a path as the config will find it, relative
    to the config's directory), the furnace's default map, the usual daemon settings."""
    served = ServedMap.default(furnace)
    n = len(furnace.sensors)
    width = max(len(s) for s in furnace.sensors) + 1
    first, *rest = served.thermocouples
    tc_lines = [f"  {first.name + ':':<{width}} &tc {{table: input, address: {first.address}, "
                "type: int16, scale: 0.1, sentinels: [32767], range: [-50, 1600]}"]
    tc_lines += [f"  {p.name + ':':<{width}} {{<<: *tc, address: {p.address}}}" for p in rest]
    zw = max(len(z) for z in furnace.zones) + 1
    mb_lines, can_lines = [], []
    for b in served.burners:
        last = b.address + b.count - 1
        mb_lines.append(f"    {b.name + ':':<{zw}} {{table: discrete, address: {b.address}}}"
                        f"   # {b.count} burners: {b.address}-{last}")
        can_lines.append(f"    {b.name + ':':<{zw}} {{id: 0x180, start_bit: {b.address}}}")
    assert served.ambient is not None and served.clock is not None \
        and served.heartbeat is not None
    burner_lines = [
        "burners:",
        "  source: modbus         # modbus, can, or both",
        "  modbus:                # burner flame-on states, one bit per burner, 1 = firing",
        *mb_lines,
        "  can:                   # flame scanners: bit n of the frame = burner n - start_bit",
        "    interface: virtual",
        "    channel: furnace",
        *can_lines,
        "",
    ] if served.burners else []
    lines = [
        "# furnace-daq run --config THIS_FILE   (written by `furnace-daq config`)",
        "#",
        f"# The register map of furnace '{furnace.name}' as the gateway polls it: the default",
        "# map derived from its description (docs/operations.md, \"The default register",
        "# map\"), which `furnace-daq sim-plc --furnace` serves. For a real PLC change",
        "# addresses, types and orders to match the PLC program's export; the keys under",
        "# thermocouples and burners must stay the description's thermocouples and zones.",
        "# Table, type and order settings are those of config/gateway.yaml.",
        "",
        f"furnace: {furnace_ref}",
        "",
        "plc:",
        "  host: 127.0.0.1        # --plc HOST:PORT overrides host and port",
        f"  port: {port}",
        "  device_id: 1",
        "  timeout_s: 1.0",
        "",
        "poll_period_s: 1.0",
        "stale_after_s: 5.0",
        "status_interval_s: 10.0",
        "",
        f"# The {n} thermocouples, 0.1 degC per count, 32767 = open circuit.",
        "thermocouples:",
        *tc_lines,
        "",
        f"ambient: {{table: input, address: {served.ambient.address}, type: int16, "
        "scale: 0.1, range: [-60, 200]}",
        "ambient_default_c: 30.0",
        f"clock: {{table: input, address: {served.clock.address}, type: uint32, "
        "word_order: big}",
        f"heartbeat: {{table: input, address: {served.heartbeat.address}, type: uint16}}",
        "",
        *_analog_lines(served),
        *burner_lines,
        "log:",
        "  prefix: furnace",
        "  flush_interval_s: 5.0",
        "  rotate_s: 3600.0",
        "",
        "# Online identification of the furnace's thermal network (docs/operations.md).",
        "refit:",
        "  enabled: true",
        "  period_s: 900",
        "  window_s: 86400",
        "  step_s: 60",
        "  budget_s: 30",
        "",
    ]
    return "\n".join(lines)


def _analog_lines(served: ServedMap) -> list[str]:
    """The `heat:` and `disturbances:` sections of a furnace that has rate-fired zones or
    declares disturbances (none otherwise), each point with the range of its description."""
    furnace = served.furnace
    out: list[str] = []
    sections = (
        ("heat", "# The heat input of each zone fired at a modulated rate, FLOAT32 in the unit "
                 "of the description.", served.heat,
         [(furnace.zones[i], furnace.heat_inputs[i].unit, (0.0, furnace.heat_inputs[i].max))
          for i in furnace.rated]),
        ("disturbances", "# The measured disturbances the description declares, FLOAT32 in "
                         "their units.", served.disturbances,
         [(d.name, d.unit, d.range) for d in furnace.disturbances]))
    for key, comment, points, named in sections:
        if not points:
            continue
        width = max(len(name) for name, _, _ in named) + 1
        out += [comment, f"{key}:"]
        for p, (name, unit, span) in zip(points, named, strict=True):
            rng = "" if span is None else f", range: [{span[0]:g}, {span[1]:g}]"
            out.append(f"  {name + ':':<{width}} {{table: input, address: {p.address}, "
                       f"type: float32, word_order: big{rng}}}   # {unit}")
        out.append("")
    return out
