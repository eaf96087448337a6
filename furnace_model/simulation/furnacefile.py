"""A furnace description read from YAML, every key checked: a file, a string, a key of a
larger file, or the name of a shipped description (config/furnaces/, `furnace_model.shipped`).

Here rather than beside `Furnace`, because checking a description needs the network
built from it (parameter names must not collide), and the network needs `Furnace`.
"""

from __future__ import annotations

import re
from pathlib import Path

from ..config import Node, load_yaml, parse_yaml
from ..shipped import FURNACES, shipped_named, shipped_names
from .furnace import BURNER_HEAT, HEAT_KINDS, Disturbance, Furnace, HeatInput
from .network import parameter_names

_ZONE_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


def load_furnace(path: str | Path) -> Furnace:
    """A furnace description from YAML, every key checked (errors name the key path)."""
    return furnace_from_node(load_yaml(path), Path(path).stem)


def parse_furnace(text: str, file: str = "<string>", name: str = "furnace") -> Furnace:
    return furnace_from_node(parse_yaml(text, file), name)


def furnace_from_node(node: Node, default_name: str) -> Furnace:
    """`zones` (name, burners, thermocouples, max_bias_c, heat), `links` (`chain`, the
    default, or a list of pairs of zone names), `ambient` (zone names; default the last
    zone), `burner_heat`, `max_bias_c` (every thermocouple's, unless its zone gives its own),
    `disturbances` (measured inputs that are not burners)."""
    root = node.mapping({"name", "description", "zones", "links", "ambient", "burner_heat",
                         "max_bias_c", "disturbances"})
    name = root.get_string("name", default_name)
    every = (root.child("max_bias_c").number(lo=0.0, hi=500.0) if root.has("max_bias_c")
             else None)
    zones, burners, tcs, bias, heat = [], [], [], [], []
    for z in root.child("zones").elements(min_len=1, max_len=64):
        z.mapping({"name", "burners", "thermocouples", "max_bias_c", "heat"})
        zname = z.child("name").string()
        if not _ZONE_NAME.match(zname):
            raise z.child("name").error(f"'{zname}' is not a zone name: lower-case letters, "
                                        "digits and _, starting with a letter")
        if zname in zones:
            raise z.child("name").error(f"zone '{zname}' appears twice")
        zones.append(zname)
        kind = (z.child("heat").mapping({"kind", "unit", "max"}).get_string(
            "kind", choices=HEAT_KINDS) if z.has("heat") else "burners")
        burners.append(z.get_integer("burners", *((1,) if kind == "rate" else ()),
                                     lo=1 if kind == "rate" else 0, hi=1000))
        heat.append(_heat_input(z, kind, burners[-1]))
        tcs.append(z.get_integer("thermocouples", 2, lo=1, hi=64))
        bias += _max_bias(z, tcs[-1], every)
    n = len(zones)

    def index(node: Node) -> int:
        zname = node.string()
        if zname not in zones:
            raise node.error(f"unknown zone '{zname}' (zones: {', '.join(zones)})")
        return zones.index(zname)

    links_node = root.child("links", "chain")
    if isinstance(links_node.value, str):
        links_node.string(("chain",))
        links = [(i, i + 1) for i in range(n - 1)]
    else:
        links = []
        for pair in links_node.elements():
            ends = pair.elements(2, 2)
            i, j = index(ends[0]), index(ends[1])
            if i == j:
                raise pair.error(f"a link joins two zones, got '{zones[i]}' twice")
            if (i, j) in links or (j, i) in links:
                raise pair.error(f"the link {zones[i]}-{zones[j]} appears twice")
            links.append((i, j))
    ambient_node = root.child("ambient", [zones[-1]])
    ambient = [index(a) for a in ambient_node.elements(min_len=1)]
    if len(set(ambient)) != len(ambient):
        raise ambient_node.error("a zone appears twice")
    burner_heat = root.get_string("burner_heat", "first_zone", choices=BURNER_HEAT)
    if sum(burners) == 0:
        raise root.child("zones").error("no zone has burners: nothing heats the furnace")
    units = {h.unit for h, n in zip(heat, burners, strict=True) if n > 0}
    if burner_heat == "first_zone" and len(units) > 1:
        raise root.child("burner_heat", "first_zone").error(
            f"first_zone adds every zone's heat input into the first zone, but the inputs "
            f"are in different units ({', '.join(sorted(units))}): use burner_heat: own_zone")
    disturbances = _disturbances(root, zones) if root.has("disturbances") else ()
    modulated = any(not h.whole for h in heat)
    furnace = Furnace(name, tuple(zones), tuple(burners), tuple(tcs), tuple(links),
                      tuple(sorted(ambient)), burner_heat,
                      tuple(bias) if any(b is not None for b in bias) else (),
                      tuple(heat) if modulated else (), disturbances)
    _check_connected(furnace, links_node)
    names = parameter_names(furnace)
    dup = sorted({p for p in names if names.count(p) > 1})
    if dup:
        raise root.child("zones").error(f"zone names make parameter names collide: "
                                        f"{', '.join(dup)}; rename a zone")
    return furnace


def _heat_input(zone: Node, kind: str, burners: int) -> HeatInput:
    """A zone's `heat`: `kind` burners (the default), pulse (burners fired on and off with a
    duty, so a row holds a fraction of them), or rate with its `unit` and `max`."""
    if kind != "rate":
        if zone.has("heat") and (zone.child("heat").has("unit") or zone.child("heat").has("max")):
            raise zone.child("heat").error(f"a {kind} zone's input is counted in burners (0 "
                                           f"to 'burners'): unit and max belong to a rate")
        return HeatInput(kind, "burners", float(burners))
    node = zone.child("heat")
    return HeatInput("rate", node.get_string("unit"),
                     node.get_number("max", lo=1e-9, hi=1e12))


_TABLE_COLUMNS = ("timestamp", "t_min", "t_air")


def _disturbances(root: Node, zones: list[str]) -> tuple[Disturbance, ...]:
    """`disturbances`: each a `name`, `unit`, `zones` (whose heat balance it enters),
    optional `column` (default its name) and `range` [lo, hi]."""
    out: list[Disturbance] = []
    for node in root.child("disturbances").elements(max_len=64):
        node.mapping({"name", "unit", "zones", "column", "range"})
        name = node.get_string("name")
        if not _ZONE_NAME.match(name):
            raise node.child("name").error(f"'{name}' is not a disturbance name: lower-case "
                                           "letters, digits and _, starting with a letter")
        column = node.get_string("column", name)
        if (column in _TABLE_COLUMNS or column.startswith(("tc_", "burners_", "heat_"))
                or not column.strip()):
            raise node.child("column" if node.has("column") else "name").error(
                f"column '{column}' is taken by the tabular contract (timestamp, t_min, "
                "t_air, tc_*, burners_*, heat_*): name it otherwise")
        if any(d.name == name or d.column == column for d in out):
            raise node.error(f"disturbance '{name}' (column '{column}') appears twice")
        where = []
        for z in node.child("zones").elements(min_len=1):
            zname = z.string()
            if zname not in zones:
                raise z.error(f"unknown zone '{zname}' (zones: {', '.join(zones)})")
            if zones.index(zname) in where:
                raise z.error(f"zone '{zname}' appears twice")
            where.append(zones.index(zname))
        span = None
        if node.has("range"):
            ends = node.child("range").elements(2, 2)
            span = (ends[0].number(), ends[1].number())
            if not span[0] < span[1]:
                raise node.child("range").error("needs [low, high] with low < high")
        out.append(Disturbance(name, node.get_string("unit"), tuple(where), column, span))
    return tuple(out)


def _max_bias(zone: Node, n_tc: int, every: float | None) -> list[float | None]:
    """A zone's `max_bias_c`: one number for its thermocouples, or one per thermocouple."""
    if not zone.has("max_bias_c"):
        return [every] * n_tc
    node = zone.child("max_bias_c")
    if isinstance(node.value, list):
        return [b.number(lo=0.0, hi=500.0) for b in node.elements(n_tc, n_tc)]
    return [node.number(lo=0.0, hi=500.0)] * n_tc


def _check_connected(furnace: Furnace, node: Node) -> None:
    """Every zone must reach an ambient zone through links, or its temperature would have
    nowhere to go: a model without a steady state, and parameters no data determine."""
    reach = set(furnace.ambient)
    grew = True
    while grew:
        grew = False
        for i, j in furnace.links:
            if (i in reach) != (j in reach):
                reach |= {i, j}
                grew = True
    cut = [furnace.zones[i] for i in range(furnace.n_zones) if i not in reach]
    if cut:
        raise node.error(f"zone(s) {', '.join(cut)} reach no zone that loses heat to "
                         "ambient: add links or ambient zones")


def furnace_file(text: str, base: Path | None = None) -> Path | None:
    """The description a name or path stands for: a file relative to `base` (the naming
    file's directory), or to the working directory, or the name of a shipped description
    (`six-zone`, `paper`); None when it is none of these."""
    for candidate in ([] if base is None else [base / text]) + [Path(text)]:
        if candidate.is_file():
            return candidate
    return shipped_named(FURNACES, text)


def shipped_furnaces() -> str:
    """The shipped descriptions' names, for an error message."""
    return ", ".join(shipped_names(FURNACES))


def named_furnace(node: Node, base: Path | None = None, what: str = "the file") -> Furnace:
    """The furnace a `furnace:` key names, in every file that has one (a daemon config, a
    scenario, a fleet file): `furnace_file` from the naming file's directory (`base`)."""
    text = node.string()
    path = furnace_file(text, base)
    if path is None:
        raise node.error(f"no furnace description '{text}' (a YAML file relative to {what}'s "
                         f"directory or the working directory, or a shipped description: "
                         f"{shipped_furnaces()})")
    return load_furnace(path)
