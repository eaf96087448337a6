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
