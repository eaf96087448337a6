"""The fleet description: which furnaces, which furnace each is, where its logs are, and the
campaigns (named spans of its PLC clock) a diagnosis compares.

Written by hand, like every config here, so it is checked in full at load and every error
names the file and the key path (`fleet.yaml: furnaces[2].campaigns[0].to: ...`). Relative
log directories are taken from the YAML file's own directory, so a fleet file and its logs
can move together. The refit settings are the daemon's `refit:` section (same keys, same
checks, same defaults: docs/operations.md), so a fleet refit of a log gives what the daemon
gave online.

```yaml
furnaces:
  - name: line1
    furnace: paper            # optional: a description's path or a name in config/furnaces/
    logs: [/srv/logs/line1]   # log directories (or log files), one record per directory
    ambient_default_c: 30     # optional: ambient when a log has none
    campaigns:                # optional: named time ranges for diagnosis
      - {name: 2026-01, from: 2026-01-01T00:00Z, to: 2026-02-01T00:00Z}
refit: {period_s: 900, window_s: 86400}   # optional, the daemon's refit: keys
diagnose: {effects: [zone_burners, fuel_change], period_s: 60, seed: 0}   # optional
```
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from furnace_model.config import Node, load_yaml
from furnace_model.simulation.furnace import PAPER, Furnace
from furnace_model.simulation.furnacefile import named_furnace

from ..daqconfig import RefitConfig, parse_refit

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
"""Furnace and campaign names become file names and table keys: no spaces or slashes."""


@dataclass(frozen=True)
class Campaign:
    name: str
    start: pd.Timestamp
    end: pd.Timestamp

    @property
    def start_ns(self) -> int:
        return int(self.start.value)

    @property
    def end_ns(self) -> int:
        return int(self.end.value)


@dataclass(frozen=True)
class FleetFurnace:
    name: str
    description: Furnace
    """Which furnace it is (zones, burners, thermocouples, links): what its logs must record
    and what its refits and diagnoses model."""
    logs: tuple[Path, ...]
    ambient_default_c: float = 30.0
    campaigns: tuple[Campaign, ...] = ()
    where: str = ""
    """Key path of this entry in the fleet file (`furnaces[1]`), for messages."""


@dataclass(frozen=True)
class DiagnoseSettings:
    effects: tuple[str, ...] | None = None
    """Candidates to try (None: every effect, as `furnace-model diagnose`)."""
    period_s: float = 60.0
    seed: int = 0


@dataclass(frozen=True)
class Fleet:
    furnaces: tuple[FleetFurnace, ...]
    refit: RefitConfig = field(default_factory=RefitConfig)
    diagnose: DiagnoseSettings = field(default_factory=DiagnoseSettings)
    file: str = ""

    def furnace(self, name: str) -> FleetFurnace:
        return next(f for f in self.furnaces if f.name == name)


def load_fleet(path: str | Path) -> Fleet:
    """Read and check a fleet file; raises ConfigError naming the file and key path."""
    path = Path(path)
    return parse_fleet(load_yaml(path), base=path.parent)


def parse_fleet(root: Node, base: Path = Path(".")) -> Fleet:
    root.mapping({"furnaces", "refit", "diagnose"})
    furnaces: list[FleetFurnace] = []
    seen: dict[str, str] = {}
    for node in root.child("furnaces").elements(min_len=1):
        f = _furnace(node, base)
        if f.name in seen:
            raise node.child("name").error(f"'{f.name}' is already the name of {seen[f.name]}")
        seen[f.name] = node.path
        furnaces.append(f)
    refit = parse_refit(root.child("refit")) if root.has("refit") else RefitConfig()
    if refit is None:
        raise root.child("refit").child("enabled").error(
            "a fleet refit needs refit settings: remove enabled: false")
    return Fleet(tuple(furnaces), refit, _diagnose(root.child("diagnose", {})), root.file)


def _name(node: Node) -> str:
    name = node.string()
    if not _NAME.match(name):
        raise node.error(f"'{name}' is not a usable name: letters, digits, '_', '.', '-', "
                         "starting with a letter or digit")
    return name


def _furnace(node: Node, base: Path) -> FleetFurnace:
    node.mapping({"name", "furnace", "logs", "ambient_default_c", "campaigns"})
    name = _name(node.child("name"))
    description = (named_furnace(node.child("furnace"), base, "the fleet file")
                   if node.has("furnace") else PAPER)
    logs_node = node.child("logs")
    entries = [logs_node] if isinstance(logs_node.value, str) else logs_node.elements(min_len=1)
    logs = []
    for entry in entries:
        p = Path(entry.string()).expanduser()
        logs.append(p if p.is_absolute() else base / p)
    campaigns: list[Campaign] = []
    for cn in node.child("campaigns", []).elements():
        cn.mapping({"name", "from", "to"})
        c = Campaign(_name(cn.child("name")), cn.child("from").timestamp(),
                     cn.child("to").timestamp())
        if c.start >= c.end:
            raise cn.child("to").error(f"{c.end.isoformat()} is not after from "
                                       f"({c.start.isoformat()})")
        if any(o.name == c.name for o in campaigns):
            raise cn.child("name").error(f"campaign '{c.name}' is named twice for {name}")
        campaigns.append(c)
    return FleetFurnace(name, description, tuple(logs),
                   node.get_number("ambient_default_c", 30.0, lo=-60.0, hi=200.0),
                   tuple(campaigns), node.path)


def _diagnose(node: Node) -> DiagnoseSettings:
    node.mapping({"effects", "period_s", "seed"})
    effects = None
    if node.has("effects"):
        from furnace_model.cli.names import effect_names, is_effect

        names = []
        for e in node.child("effects").elements(min_len=1):
            if not is_effect(e.string()):
                raise e.error(f"unknown effect '{e.value}' (expected one of "
                              f"{', '.join(effect_names())})")
            names.append(e.value)
        effects = tuple(names)
    return DiagnoseSettings(effects, node.get_number("period_s", 60.0, lo=0.001, hi=86400.0),
                            node.get_integer("seed", 0, lo=0))

