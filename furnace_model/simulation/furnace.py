"""A furnace description: its zones, burners, thermocouples, and how heat moves between them.

The model is a linear thermal network (docs/model.md): one temperature per zone, heat
exchanged along links, lost to ambient from some zones, and brought by burners. The paper's
three-zone furnace (config/furnaces/paper.yaml, `PAPER`) is one description among others;
every layer that names zones, thermocouples, burner columns or parameters reads them from
here, so that another furnace is a YAML file, not a code change (read by
`furnace_model.simulation.furnacefile`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BURNER_HEAT = ("first_zone", "own_zone")
"""Where burner heat enters: the paper's convention (every burner heats the first zone,
q1 = the total count) or each zone's burners their own zone."""

HEAT_KINDS = ("burners", "pulse", "rate")
"""How a zone is fired, and so what its heat-input column holds: whole burners switched on
and off (a count), pulse-fired burners (the count's time mean over each row: duty times
burners, a fraction), or a modulated firing rate or fuel flow (a number in its own unit,
from 0 to a maximum)."""


@dataclass(frozen=True)
class HeatInput:
    """A zone's heat input as its PLC reports it. `max` is the largest value the input can
    take: the zone's burner count for burners and pulse firing, the declared maximum of a
    rate (100 for a firing rate in %, the fuel flow at full fire in Nm3/h)."""

    kind: str = "burners"
    unit: str = "burners"
    max: float = 0.0

    @property
    def whole(self) -> bool:
        """Whether the column holds whole numbers (burners switched on and off)."""
        return self.kind == "burners"


@dataclass(frozen=True)
class Disturbance:
    """A measured input that is not a burner (slab throughput, charging, door openings,
    combustion-air temperature): logged by the PLC, entering the heat balance of `zones`
    with one fitted gain per zone. `column` is its name in a table and on the log;
    `range` the values it can take (a reading outside is refused with its row)."""

    name: str
    unit: str
    zones: tuple[int, ...]
    column: str = ""
    range: tuple[float, float] | None = None

    @property
    def scale(self) -> float:
        """The largest magnitude the input takes (1 when no range is declared): it sets the
        search box of the gains, so that a gain per tonne and one per degree are searched
        alike."""
        if self.range is None:
            return 1.0
        return max(abs(self.range[0]), abs(self.range[1]), 1e-12)


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
    empty tuple: every one) takes the default of `furnace_model.identification.plausible`."""
    heat: tuple[HeatInput, ...] = ()
    """Per zone, how it is fired; empty: every zone by whole burners (the paper's)."""
    disturbances: tuple[Disturbance, ...] = ()

    @property
    def heat_inputs(self) -> tuple[HeatInput, ...]:
        """Each zone's heat input, whole burners where the description says nothing."""
        if self.heat:
            return self.heat
        return tuple(HeatInput("burners", "burners", float(n)) for n in self.burners)

    @property
    def modulated(self) -> bool:
        """Whether some zone's input is not a whole burner count."""
        return any(not h.whole for h in self.heat_inputs)

    @property
    def switched(self) -> tuple[int, ...]:
        """Zones fired by burners switched on and off, whole or pulse-fired: a PLC reports
        each of their burners as one bit. A rate-fired zone reports its rate instead."""
        return tuple(i for i, h in enumerate(self.heat_inputs) if h.kind != "rate")

    @property
    def switched_zones(self) -> tuple[str, ...]:
        return tuple(self.zones[i] for i in self.switched)

    @property
    def rated(self) -> tuple[int, ...]:
        """Zones fired at a modulated rate: a PLC reports the rate, an analog value."""
        return tuple(i for i, h in enumerate(self.heat_inputs) if h.kind == "rate")

    @property
    def burner_equivalents(self) -> np.ndarray:
        """Per zone, the burners one unit of its input stands for (1 for burner counts,
        burners / max for a rate): effects written for burner counts (a nonlinearity in the
        number firing) read every zone in burners through it."""
        return np.array([1.0 if h.kind != "rate" else n / h.max
                         for h, n in zip(self.heat_inputs, self.burners, strict=True)])

    @property
    def n_inputs(self) -> int:
        """Model input channels: each zone's heat input, ambient, each disturbance."""
        return self.n_zones + 1 + len(self.disturbances)

    @property
    def disturbance_columns(self) -> tuple[str, ...]:
        return tuple(d.column for d in self.disturbances)

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
        """Each zone's heat-input column: `burners_<zone>` for burners switched on and off
        or pulse-fired, `heat_<zone>` for a modulated rate (in the input's own unit)."""
        return tuple(f"heat_{z}" if h.kind == "rate" else f"burners_{z}"
                     for z, h in zip(self.zones, self.heat_inputs, strict=True))

    @property
    def heated(self) -> tuple[int, ...]:
        """Zones that burner heat enters: the first, or every zone with burners."""
        if self.burner_heat == "first_zone":
            return (0,)
        return tuple(i for i, n in enumerate(self.burners) if n > 0)

    @property
    def paper_structure(self) -> bool:
        """Eq. 11's network: three zones in a chain, the last losing heat, every burner into
        the first, heat counted in burners. Its parameters keep the paper's names a..f, whatever the zones are
        called."""
        return (self.n_zones == 3 and self.links == ((0, 1), (1, 2))
                and self.ambient == (2,) and self.burner_heat == "first_zone"
                and all(h.kind != "rate" for h in self.heat_inputs))

    @property
    def model_label(self) -> str:
        """The model's name in a fit's JSON: the paper's for its structure and inputs."""
        if self.paper_structure and not self.disturbances and not self.modulated:
            return "paper-3zone"
        return f"network-{self.name}"

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
                "zones": [{"name": z, "burners": b, "thermocouples": t,
                           **({"heat": {"kind": h.kind} | ({"unit": h.unit, "max": h.max}
                                                           if h.kind == "rate" else {})}
                              if not h.whole else {})}
                          for z, b, t, h in zip(self.zones, self.burners, self.thermocouples,
                                                self.heat_inputs, strict=True)],
                "links": [[self.zones[i], self.zones[j]] for i, j in self.links],
                "ambient": [self.zones[i] for i in self.ambient],
                "burner_heat": self.burner_heat,
                **({"max_bias_c": list(self.max_bias_c)} if any(
                    b is not None for b in self.max_bias_c) else {}),
                **({"disturbances": [
                    {"name": d.name, "unit": d.unit, "column": d.column,
                     "zones": [self.zones[i] for i in d.zones],
                     **({"range": list(d.range)} if d.range is not None else {})}
                    for d in self.disturbances]} if self.disturbances else {})}


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
