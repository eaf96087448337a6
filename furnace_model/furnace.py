"""A furnace description: its zones, burners, thermocouples, and how heat moves between them.

The model is a linear thermal network (docs/model.md): one temperature per zone, heat
exchanged along links, lost to ambient from some zones, and brought by burners. The paper's
three-zone furnace (config/furnaces/paper.yaml, `PAPER`) is one description among others;
every layer that names zones, thermocouples, burner columns or parameters reads them from
here, so that another furnace is a YAML file, not a code change.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .config import Node, load_yaml, parse_yaml

BURNER_HEAT = ("first_zone", "own_zone")
"""Where burner heat enters: the paper's convention (every burner heats the first zone,
q1 = the total count) or each zone's burners their own zone."""

_ZONE_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


@dataclass(frozen=True)
class Furnace:
    """Zones in order, with their burners and thermocouples; links between zones (pairs of
    zone indices, in the order given); the zones that lose heat to ambient; where burner
    heat enters."""

    name: str
    zones: tuple[str, ...]
    burners: tuple[int, ...]
    thermocouples: tuple[int, ...]
    links: tuple[tuple[int, int], ...]
    ambient: tuple[int, ...]
    burner_heat: str = "first_zone"
    max_bias_c: tuple[float | None, ...] = ()
    """Per thermocouple (`sensors` order), the largest bias it can have, °C; None (or an
    empty tuple: every one) takes the default of `furnace_model.plausible`."""

    @property
    def n_zones(self) -> int:
        return len(self.zones)

    @property
    def sensors(self) -> tuple[str, ...]:
        """Thermocouple names `<zone>_<k>` (k from 1), zone by zone."""
        return tuple(f"{z}_{k}" for z, n in zip(self.zones, self.thermocouples, strict=True)
                     for k in range(1, n + 1))

    @property
    def sensor_zone(self) -> np.ndarray:
        """The zone index of each thermocouple, in `sensors` order."""
        return np.repeat(np.arange(self.n_zones), self.thermocouples)

    @property
    def tc_columns(self) -> tuple[str, ...]:
        return tuple(f"tc_{s}" for s in self.sensors)

    @property
    def burner_columns(self) -> tuple[str, ...]:
        return tuple(f"burners_{z}" for z in self.zones)

    @property
    def heated(self) -> tuple[int, ...]:
        """Zones that burner heat enters: the first, or every zone with burners."""
        if self.burner_heat == "first_zone":
            return (0,)
        return tuple(i for i, n in enumerate(self.burners) if n > 0)

    @property
    def paper_structure(self) -> bool:
        """Eq. 11's network: three zones in a chain, the last losing heat, every burner into
        the first. Its parameters keep the paper's names a..f, whatever the zones are
        called."""
        return (self.n_zones == 3 and self.links == ((0, 1), (1, 2))
                and self.ambient == (2,) and self.burner_heat == "first_zone")

    @property
    def model_label(self) -> str:
        """The model's name in a fit's JSON: the paper's for its structure."""
        return "paper-3zone" if self.paper_structure else f"network-{self.name}"

    def weights(self, good: np.ndarray) -> np.ndarray:
        """How each thermocouple enters its zone's reading (N, n_tc), from which read: the
        mean of the good ones, none where a zone has none."""
        g = np.asarray(good, dtype=float)
        count = np.add.reduceat(g, self._starts, axis=1)
        return g / np.maximum(count, 1)[:, self.sensor_zone]

    def zone_means(self, tc: np.ndarray) -> np.ndarray:
        """Zone temperatures (N, n_zones): the mean of each zone's good thermocouples, NaN
        where a zone has none."""
        tc = np.asarray(tc, dtype=float)
        good = np.isfinite(tc)
        total = np.add.reduceat(np.where(good, tc, 0.0), self._starts, axis=1)
        count = np.add.reduceat(good.astype(float), self._starts, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(count > 0, total / np.maximum(count, 1), np.nan)

    def zone_sums(self, per_sensor: np.ndarray) -> np.ndarray:
        """Sum over each zone's thermocouples of (..., n_tc) -> (..., n_zones)."""
        return np.add.reduceat(per_sensor, self._starts, axis=-1)

    @property
    def _starts(self) -> np.ndarray:
        return np.concatenate(([0], np.cumsum(self.thermocouples)[:-1])).astype(int)

    def describe(self) -> dict:
        """The description as plain data (a log's metadata, a fit's JSON)."""
        return {"name": self.name,
                "zones": [{"name": z, "burners": b, "thermocouples": t}
                          for z, b, t in zip(self.zones, self.burners, self.thermocouples,
                                             strict=True)],
                "links": [[self.zones[i], self.zones[j]] for i, j in self.links],
                "ambient": [self.zones[i] for i in self.ambient],
                "burner_heat": self.burner_heat,
                **({"max_bias_c": list(self.max_bias_c)} if any(
                    b is not None for b in self.max_bias_c) else {})}


def load_furnace(path: str | Path) -> Furnace:
    """A furnace description from YAML, every key checked (errors name the key path)."""
    return furnace_from_node(load_yaml(path), Path(path).stem)


def parse_furnace(text: str, file: str = "<string>", name: str = "furnace") -> Furnace:
    return furnace_from_node(parse_yaml(text, file), name)


def furnace_from_node(node: Node, default_name: str) -> Furnace:
    """`zones` (name, burners, thermocouples, max_bias_c), `links` (`chain`, the default, or
    a list of pairs of zone names), `ambient` (zone names; default the last zone),
    `burner_heat`, `max_bias_c` (every thermocouple's, unless its zone gives its own)."""
    root = node.mapping({"name", "description", "zones", "links", "ambient", "burner_heat",
                         "max_bias_c"})
    name = root.get_string("name", default_name)
    every = (root.child("max_bias_c").number(lo=0.0, hi=500.0) if root.has("max_bias_c")
             else None)
    zones, burners, tcs, bias = [], [], [], []
    for z in root.child("zones").elements(min_len=1, max_len=64):
        z.mapping({"name", "burners", "thermocouples", "max_bias_c"})
        zname = z.child("name").string()
        if not _ZONE_NAME.match(zname):
            raise z.child("name").error(f"'{zname}' is not a zone name: lower-case letters, "
                                        "digits and _, starting with a letter")
        if zname in zones:
            raise z.child("name").error(f"zone '{zname}' appears twice")
        zones.append(zname)
        burners.append(z.get_integer("burners", lo=0, hi=1000))
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
    heat = root.get_string("burner_heat", "first_zone", choices=BURNER_HEAT)
    if sum(burners) == 0:
        raise root.child("zones").error("no zone has burners: nothing heats the furnace")
    furnace = Furnace(name, tuple(zones), tuple(burners), tuple(tcs), tuple(links),
                      tuple(sorted(ambient)), heat,
                      tuple(bias) if any(b is not None for b in bias) else ())
    _check_connected(furnace, links_node)
    from .network import parameter_names  # names must not collide (zone names with _)

    names = parameter_names(furnace)
    dup = sorted({p for p in names if names.count(p) > 1})
    if dup:
        raise root.child("zones").error(f"zone names make parameter names collide: "
                                        f"{', '.join(dup)}; rename a zone")
    return furnace


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


FURNACES_DIR = Path(__file__).resolve().parent.parent / "config" / "furnaces"


def named_furnace(node: Node, base: Path | None = None, what: str = "the file") -> Furnace:
    """The furnace a `furnace:` key names, in every file that has one (a daemon config, a
    scenario, a fleet file): a description's path relative to the naming file's directory
    (`base`), or to the working directory, or the name of one in config/furnaces/
    (`six-zone`, `paper`)."""
    text = node.string()
    candidates = [] if base is None else [base / text]
    candidates += [Path(text), FURNACES_DIR / text, FURNACES_DIR / f"{text}.yaml"]
    for candidate in candidates:
        if candidate.is_file():
            return load_furnace(candidate)
    raise node.error(f"no furnace description '{text}' (a YAML file relative to {what}'s "
                     f"directory or the working directory, or a name in {FURNACES_DIR})")

PAPER = Furnace(
    name="paper",
    zones=("soak", "heat", "preheat"),
    burners=(10, 8, 8),
    thermocouples=(2, 2, 2),
    links=((0, 1), (1, 2)),
    ambient=(2,),
    burner_heat="first_zone",
)
"""The paper's furnace (config/furnaces/paper.yaml): soaking, heating and preheating zones
in a chain, 10/8/8 burners, two thermocouples per zone, the preheating zone losing heat to
ambient, every burner counted as zone-1 input. The default wherever no furnace is named."""
