"""What a record's own unknowns may physically be: a thermocouple's bias and the furnace's
temperatures where the record starts.

A fit estimates, besides the model's parameters, each record's initial zone temperatures
and (by default) a constant offset per zone, the mean bias of its thermocouples. Left free,
both take up whatever the model cannot express: on a record whose physics the model lacks
they reach a hundred degrees and the fitted error all but vanishes, which hides exactly the
error a fit is asked to show. So each is held to what it can physically be:

- An offset is a thermocouple's bias: no larger than its tolerance. The default is the
  class 2 tolerance of IEC 60584-1 (types K, N, J, E; +-2.5 °C or +-0.75% of the
  temperature, whichever is larger) at the hottest reading the thermocouple gave in the
  record: 9.8 °C at 1300 °C, 2.5 °C at room temperature. A furnace description sets its
  own (`max_bias_c`, for every thermocouple, a zone's, or each one). A zone's offset is the
  mean of its thermocouples' biases, so its bound is the mean of theirs.
- The initial temperature of a zone is what its first reading says, up to that reading's
  bias and noise: within the bias bound and `START_NOISE_SD` noise sds of the first reading
  (the noise read off the zone's second differences, which a real change at the sample rate
  can only widen), and never below the lowest ambient temperature of the record less
  `AMBIENT_MARGIN_C`: nothing in a furnace cools it below its surroundings. A zone whose
  first reading comes after the record's first sample is bounded by ambient alone.

A value that the data push onto its bound is not an estimate of a bias or a start: it is the
model's error pushing against a physical limit, and the fit says so (`flags`). One that
merely wanders there, because the record cannot tell it from the start or the parameters (a
short window of a furnace at rest), is held there at no cost and not flagged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..simulation.furnace import Furnace
from .noisefloor import second_difference_sd

TOLERANCE_C = 2.5
TOLERANCE_SHARE = 0.0075
"""IEC 60584-1 class 2: +-2.5 °C or +-0.0075 |t|, whichever is larger."""
AMBIENT_MARGIN_C = 10.0
"""How far below the lowest ambient reading a zone may start: the ambient sensor's own
error and a draught."""
START_NOISE_SD = 5.0
"""Noise sds of a zone's first reading that its initial temperature may lie from it."""
FLAG_LEVEL = 0.999
"""A value on its bound is flagged when holding it there costs the fit more than noise
would with this probability: a flag is evidence, not one window in twenty of a furnace the
model describes (a record whose model misses by degrees passes it by orders of
magnitude)."""


def sensor_bias_bounds(furnace: Furnace, tc: np.ndarray) -> np.ndarray:
    """The largest plausible bias of each thermocouple (n_tc,), °C: the description's, or
    the default tolerance at the hottest reading it gave in `tc` (N, n_tc)."""
    tc = np.asarray(tc, dtype=float).reshape(-1, len(furnace.sensors))
    hottest = np.where(np.isfinite(tc), np.abs(tc), 0.0).max(axis=0, initial=0.0)
    default = np.maximum(TOLERANCE_C, TOLERANCE_SHARE * hottest)
    given = furnace.max_bias_c or (None,) * default.size
    return np.array([d if g is None else float(g) for g, d in zip(given, default, strict=True)])


def zone_bias_bounds(furnace: Furnace, tc: np.ndarray) -> np.ndarray:
    """The largest plausible offset of each zone's reading (zones,), °C: the mean of its
    thermocouples' bounds."""
    return furnace.zone_sums(sensor_bias_bounds(furnace, tc)) / np.array(furnace.thermocouples)


def start_band(zone_temp: np.ndarray, t_air: np.ndarray, bias: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest plausible initial temperature of each zone (zones,) of a record:
    its readings (N, zones), ambient (N,) and zone bias bounds (zones,)."""
    y = np.asarray(zone_temp, dtype=float)
    air = np.asarray(t_air, dtype=float)
    floor = (float(np.nanmin(air)) if np.isfinite(air).any() else -np.inf) - AMBIENT_MARGIN_C
    nz = y.shape[1]
    lo, hi = np.full(nz, floor), np.full(nz, np.inf)
    for w in range(nz):
        seen = np.nonzero(np.isfinite(y[:, w]))[0]
        if seen.size == 0 or seen[0] != 0:
            continue
        noise = second_difference_sd(y[:, w])[0]
        half = float(bias[w]) + START_NOISE_SD * (noise if np.isfinite(noise) else 0.0)
        first = float(y[0, w])
        # an ambient reading above the furnace's first is not its surroundings' temperature
        lo[w] = first - half if floor > first else max(first - half, floor)
        hi[w] = first + half
    return lo, hi


@dataclass(frozen=True)
class Flag:
    """A record's unknown that ended on its physical bound: the model's error, not a bias
    or a start."""

    kind: str  # offset | initial_state
    record: str
    zone: str
    value_c: float
    lo_c: float
    hi_c: float

    def words(self) -> str:
        if self.kind == "offset":
            return (f"{self.record}: the {self.zone} zone's offset of {self.value_c:+.1f} °C "
                    f"sits on the bound of a plausible thermocouple bias (+-{self.hi_c:.1f} "
                    "°C): it is not a thermocouple bias; the model misses something here; "
                    "run diagnose")
        return (f"{self.record}: the {self.zone} zone's initial temperature of "
                f"{self.value_c:.1f} °C sits on the edge of what the record allows "
                f"({self.lo_c:.1f} to {self.hi_c:.1f} °C, from its first readings and "
                "ambient): the model misses something at the record's start; run diagnose")

    def to_json(self) -> dict:
        """The edges as `low_c` and `high_c`, each absent where unbounded (a log's schema
        keeps a number a number)."""
        return {"kind": self.kind, "record": self.record, "zone": self.zone,
                "value_c": self.value_c,
                **{k: v for k, v in (("low_c", self.lo_c), ("high_c", self.hi_c))
                   if np.isfinite(v)}}
