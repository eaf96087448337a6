"""Perturbations outside the effect library, for the selfcheck: no candidate can express
them, so the honest verdict is `unexplained` with the place located.

A fault is drawn with the case (`draw`: its truth record), may run the plant its own way
(`run`) or what the thermocouples read (`read`), and says whether a diagnosis located it
(`located`). The selfcheck's cases and its judge loop over `FAULTS` and never name one.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ..effects import ZoneLosses
from ..simulation.furnace import Furnace
from ..simulation.network import terms
from ..simulation.plant import Plant, PlantRun
from ..simulation.structure import Inputs, ModelStructure


class Fault:
    name: ClassVar[str]
    ranges: ClassVar[dict[str, tuple[float, float]]] = {}
    """Where its strengths are drawn from. Rates compare with the furnace's own: a =
    0.02/min couples the paper's soaking and heating zones, e = 0.73/min is its preheating
    zone's loss to ambient."""

    def draw(self, rng: np.random.Generator, durations: np.ndarray,
             furnace: Furnace) -> dict[str, Any]:
        """Its truth record for a case of two heat-ups of `durations` minutes."""
        raise NotImplementedError

    def run(self, plant: Plant, inputs: Inputs, t: np.ndarray, x0: np.ndarray,
            truth: dict[str, Any], j: int) -> PlantRun | None:
        """Heat-up `j` of the plant with the fault; None when the plant runs as it is."""
        return None

    def read(self, run: PlantRun, truth: dict[str, Any], j: int) -> None:
        """Change what the thermocouples of heat-up `j` read, in place."""

    def located(self, truth: dict[str, Any], where) -> tuple[bool, str]:
        """Whether the diagnosis's first place (`Where` or None) is the fault's, and if not
        what it located instead."""
        raise NotImplementedError


class DoorOpen(Fault):
    """A furnace door stands open for an hour in one zone, once in each heat-up: the zone
    loses heat to ambient at rate g_door (1/min) for 60 minutes. Simulated with the
    library's own pieces: the plant up to the opening, the same plant with a wall loss in
    that zone (for a zone that already loses heat to ambient: a larger loss) for the hour,
    then the plant again from the state reached."""

    name = "door_open"
    ranges = {"g_door": (0.005, 0.02)}
    EQ11 = ((0.0005, 0.0015), (0.005, 0.02), (0.1, 0.3))
    """The loss rate on eq. 11's network, zone by zone (the paper's soaking, heating and
    preheating zones): each on the scale of the zone's own rates; on any other network,
    `ranges`."""

    def draw(self, rng: np.random.Generator, durations: np.ndarray,
             furnace: Furnace) -> dict[str, Any]:
        i = int(rng.integers(furnace.n_zones))
        opens = [float(np.round(rng.uniform(0.3, 0.9) * d)) for d in durations]
        lo, hi = self.EQ11[i] if furnace.paper_structure else self.ranges["g_door"]
        return {"zone": furnace.zones[i], "g_door": float(rng.uniform(lo, hi)),
                "t_open": opens, "minutes": 60.0}

    def run(self, plant: Plant, inputs: Inputs, t: np.ndarray, x0: np.ndarray,
            truth: dict[str, Any], j: int) -> PlantRun:
        """Three runs of the library's simulator joined at the states reached, then read by
        the plant's own thermocouples."""
        lo = truth["t_open"][j]
        hi = lo + truth["minutes"]
        zone, g = truth["zone"], truth["g_door"]
        base, values = plant.structure, plant.values
        furnace = base.furnace
        z = furnace.zones.index(zone)
        if z in furnace.ambient:  # a zone losing heat to ambient loses more (the paper's: e)
            loss = next(t.name for t in terms(furnace) if t.kind == "loss" and t.to == z)
            door_structure, door_values = base, {**values, loss: values[loss] + g}
        else:
            door_structure = ModelStructure([*base.effects,
                                             ZoneLosses(zones=(zone,), furnace=furnace)],
                                            furnace=furnace)
            door_values = {**values, f"g_{zone}": g}
        states = np.empty((t.size, base.n_states))
        x = base.full_state(x0)[0]
        t_from = float(t[0])
        for structure, vals, end in ((base, values, lo), (door_structure, door_values, hi),
                                     (base, values, float(t[-1]) + 1.0)):
            idx = np.nonzero((t >= t_from) & (t < end))[0]
            grid = np.append(t[idx], min(end, float(t[-1]) + 1.0))
            piece = structure.simulate(vals, inputs, grid, x[None], t0=t_from,
                                       states=True).states[0]
            states[idx] = piece[:-1]
            x, t_from = piece[-1], end
        C = base.system(base.theta(values)).C[0]
        j_in = np.searchsorted(inputs.t, t, side="right") - 1
        return PlantRun(t, states[:, :furnace.n_zones], plant.read(states @ C.T, t),
                        inputs.burners[j_in], inputs.t_air[j_in], furnace=furnace)

    def located(self, truth: dict[str, Any], where) -> tuple[bool, str]:
        zone = truth["zone"]
        ok = where is not None and where.zone == zone and where.sensor is None
        return ok, "" if ok else f"located {_where(where)}, not the {zone} zone"


class ReadsLow(Fault):
    """One thermocouple intermittently reads low (a loose junction): in a handful of
    episodes of 5-40 minutes its reading drops by 15-60 °C. Applied to the recorded readings
    after the plant run, since the furnace itself is unaffected."""

    name = "tc_reads_low"
    ranges = {"drop_c": (15.0, 60.0), "episodes": (4, 10), "minutes": (5.0, 40.0)}

    def draw(self, rng: np.random.Generator, durations: np.ndarray,
             furnace: Furnace) -> dict[str, Any]:
        sensor = furnace.sensors[int(rng.integers(len(furnace.sensors)))]
        lo_n, hi_n = self.ranges["episodes"]
        episodes = []
        for d in durations:
            n = int(rng.integers(lo_n, hi_n + 1))
            starts = np.sort(rng.uniform(0.1 * d, 0.95 * d, n))
            lengths = rng.uniform(*self.ranges["minutes"], n)
            drops = rng.uniform(*self.ranges["drop_c"], n)
            episodes.append([(float(s), float(s + m), float(c))
                             for s, m, c in zip(np.round(starts), np.round(lengths), drops,
                                                strict=True)])
        return {"sensor": sensor, "episodes": episodes}

    def read(self, run: PlantRun, truth: dict[str, Any], j: int) -> None:
        drop = np.zeros(run.t_min.size)
        for lo, hi, c in truth["episodes"][j]:
            drop[(run.t_min >= lo) & (run.t_min < hi)] = c
        run.tc[:, run.furnace.sensors.index(truth["sensor"])] -= drop

    def located(self, truth: dict[str, Any], where) -> tuple[bool, str]:
        sensor = truth["sensor"]
        ok = where is not None and where.sensor == sensor
        return ok, "" if ok else f"located {_where(where)}, not thermocouple {sensor}"


FAULTS: dict[str, Fault] = {f.name: f for f in (DoorOpen(), ReadsLow())}
"""In the order a case draws them."""


def _where(w) -> str:
    if w is None:
        return "nothing"
    return f"thermocouple {w.sensor}" if w.sensor else f"the {w.zone} zone"
