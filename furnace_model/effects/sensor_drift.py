"""One thermocouple of a pair drifts away from its partner."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..identification.noisefloor import record_floor
from ..identification.residuals import SensorFault, sensor_faults
from ..simulation.furnace import Furnace
from ..simulation.parameters import Param
from .base import Effect, Option, pinned, within
from .drawn import Drawn
from .tried import Clues, Trial, Tried

if TYPE_CHECKING:
    from ..experiment import Experiment

MAX_RATE = 0.2
"""°C/min: a drift faster than 12 °C an hour is a broken thermocouple, not a drift."""

ONSET_STARTS = 8
"""Onsets a lone thermocouple's drift is started from, evenly over the fitted records: an
onset nothing places has a side valley wherever it meets a step of the record, and the
start from the baseline alone can stop in one that closes little of the gap."""


class TriedSensorDrift(Tried):
    def laws_for(self, furnace):
        """Each thermocouple of a zone of one: with no partner to show it, a drift of one is
        found only by fitting it there (a baseline bent to absorb it spreads its error over
        every zone). None on the paper's furnace, whose pairs show a drift."""
        return tuple({"sensor": f"{z}_1"}
                     for z, k in zip(furnace.zones, furnace.thermocouples, strict=True) if k == 1)

    def starts(self, effect, given, bounds):
        """A thermocouple alone in its zone: no partner's difference shows where its drift
        starts, and a baseline bent to absorb the drift hides it from the residual, so the
        onset is started across the fitted records. One of a pair whose difference placed
        the drift (`trial`): the difference cannot say which of the two drifts, and on the
        zone's mean the other drifting the other way is the same drift with the opposite
        sign, so that sign is started too."""
        furnace = effect.furnace
        zone = furnace.sensor_zone[furnace.sensors.index(effect.options["sensor"])]
        if furnace.thermocouples[zone] == 1 and "t_drift" in bounds:
            lo, hi = bounds["t_drift"]
            return [{"t_drift": lo + (i + 0.5) / ONSET_STARTS * (hi - lo)}
                    for i in range(ONSET_STARTS)]
        if "t_drift" in given and given.get("drift_rate"):
            return [{"drift_rate": -given["drift_rate"]}]
        return []

    def named(self, options, params, records):
        """On a zone's mean any of its thermocouples drifting at the fitted rate is the same
        fit; the one drifting is the one whose departure from its partners' mean grows at
        that rate after the onset (a pair's difference moves one way for the one, the other
        way for its partner). The rate stays: on the mean it is the same for each."""
        sensor, rate = options.get("sensor"), params.get("drift_rate", 0.0)
        if not records or sensor is None or not rate:
            return options
        furnace = records[0].furnace
        zone = furnace.sensor_zone[furnace.sensors.index(sensor)]
        own = np.flatnonzero(furnace.sensor_zone == zone)
        if own.size < 2:
            return options
        slopes = np.zeros(own.size)
        for e in records:
            ramp = np.maximum(np.asarray(e.t_min, dtype=float) - params["t_drift"], 0.0)
            for k, i in enumerate(own):
                partners = e.tc[:, own[own != i]]
                seen = np.isfinite(partners).sum(axis=1)  # a missed poll leaves none
                away = e.tc[:, i] - np.where(seen > 0, np.nansum(partners, axis=1), np.nan) \
                    / np.maximum(seen, 1)
                ok = np.isfinite(away)
                if ok.sum() < 3 or np.ptp(ramp[ok]) == 0:
                    continue
                slopes[k] += np.polyfit(ramp[ok], away[ok], 1)[0] * ok.sum()
        return {**options, "sensor": furnace.sensors[own[int(np.argmax(slopes * np.sign(rate)))]]}

    def trial(self, clues: Clues) -> Trial:
        """On the thermocouple found drifting, from the onset and rate of the hinge fitted to
        its pair's difference; else on the one whose pair's difference changes most (or, in
        a zone of one thermocouple, whose residual against the baseline does)."""
        for f in pair_faults(clues):
            if f.kind == "drift":
                exp = clues.records[f.experiment]
                t0, t1 = float(exp.t_min[f.i0]), float(exp.t_min[-1])
                return Trial({"sensor": f.sensor},
                             {"t_drift": t0, "drift_rate": f.size_c / max(t1 - t0, 1.0)})
        return Trial({"sensor": most_changed_pair(clues.records, clues.furnace,
                                                  clues.residuals)})

    def search_bounds(self, fit_data):
        """The onset lies within the fitted records (minutes from each record's start)."""
        return {"t_drift": (min(float(e.t_min[0]) for e in fit_data),
                            max(float(e.t_min[-1]) for e in fit_data)),
                "drift_rate": (-MAX_RATE, MAX_RATE)}


class DrawnSensorDrift(Drawn):
    def draw(self, rng, form, duration_min, furnace):
        sensors = furnace.sensors
        effect = self.effect(sensor=sensors[int(rng.integers(len(sensors)))], furnace=furnace)
        sign = 1.0 if rng.uniform() < 0.5 else -1.0
        return effect, {"drift_rate": sign * self.uniform(rng, "drift_rate"),
                        "t_drift": round(self.uniform(rng, "t_drift_frac") * duration_min)}


class SensorDrift(Effect):
    name = "sensor_drift"
    physics = "one thermocouple of a pair drifts away from its partner"
    tried = TriedSensorDrift(null={"drift_rate": 0.0}, one_place_at_a_time=True)
    told = ("drift_rate", "t_drift")
    drawn = DrawnSensorDrift(ranges={"drift_rate": (0.005, 0.03), "t_drift_frac": (0.15, 0.6)})

    @classmethod
    def specs(cls, furnace):
        return {"sensor": Option(default_sensor(furnace), "choice", choices=furnace.sensors,
                                 doc="the drifting thermocouple")}

    @classmethod
    def physics_for(cls, furnace):
        if all(n == 2 for n in furnace.thermocouples):
            return cls.physics
        return ("one thermocouple drifts away from the gas temperature it reads (from its "
                "zone's other thermocouples, where the zone has more than one)")

    @classmethod
    def found(cls, params, options):
        return cls.found_within(params, options, {})

    @classmethod
    def found_within(cls, params, options, ci95):
        """The thermocouple to check and since when: the sensor changed, not the furnace."""
        rate, onset = 60.0 * params["drift_rate"], params["t_drift"]
        rate_ci = ci95.get("drift_rate")
        rate_ci = None if rate_ci is None else (60.0 * rate_ci[0], 60.0 * rate_ci[1])
        since = f"from minute {within(onset, ci95.get('t_drift'), '{:.0f}')}"
        if pinned(rate, rate_ci):
            return (f"thermocouple {options['sensor']} drifts "
                    f"{within(rate, rate_ci, '{:+.2f}', ' °C/h')} {since}")
        return (f"thermocouple {options['sensor']} drifts {since}, at a rate the record does "
                f"not pin down: {within(rate, rate_ci, '{:+.2f}', ' °C/h')}")

    def _params(self):
        return (
            Param("drift_rate", 0.01, -1.0, 1.0, log=False, unit="°C/min",
                  doc="rate at which the sensor's error grows"),
            Param("t_drift", 0.0, 0.0, 1e6, log=False, unit="min", doc="when the drift starts"),
        )

    def sensor_offsets(self, theta, t):
        P = theta["drift_rate"].shape[0]
        sensors = self.furnace.sensors
        out = np.zeros((P, t.size, len(sensors)))
        ramp = np.maximum(t[None, :] - theta["t_drift"][:, None], 0.0)
        out[:, :, sensors.index(self.options["sensor"])] = theta["drift_rate"][:, None] * ramp
        return out


def pair_faults(clues: Clues) -> list[SensorFault]:
    """The thermocouples departing from their partner against the baseline, as the
    diagnosis reads them to locate its error (`identification.residuals.sensor_faults`, with
    each record's thermocouple noise from its own pairs); none without the baseline's
    predictions."""
    if not clues.predictions:
        return []
    zones = clues.furnace.zones
    tc_noise = [{z: f.zones[z].tc_sd_c for z in zones} for f in map(record_floor, clues.records)]
    return sensor_faults(clues.records, clues.predictions, tc_noise)


def default_sensor(furnace: Furnace) -> str:
    """On eq. 11's network the second thermocouple of the middle zone where it has two (the
    paper's heat_2); elsewhere the second thermocouple of the first zone with two, or the
    last thermocouple."""
    if furnace.paper_structure and furnace.thermocouples[1] >= 2:
        return f"{furnace.zones[1]}_2"
    for z, n in zip(furnace.zones, furnace.thermocouples, strict=True):
        if n >= 2:
            return f"{z}_2"
    return furnace.sensors[-1]


def most_changed_pair(records: Sequence[Experiment], furnace: Furnace,
                      residuals: Sequence[np.ndarray] = ()) -> str:
    """The thermocouple whose difference from its zone's first one changes most from a
    record's start to its end (for the zone mean any thermocouple of a zone is the same
    candidate at the same rate); in a zone of one thermocouple, the change
    of the zone's residual against the baseline (`residuals`, when given)."""
    best, name = -1.0, default_sensor(furnace)
    first = 0
    for w, (z, k) in enumerate(zip(furnace.zones, furnace.thermocouples, strict=True)):
        for j, e in enumerate(records):
            if k >= 2:
                series = [(e.tc[:, first] - e.tc[:, first + i], f"{z}_{i + 1}")
                          for i in range(1, k)]
            elif j < len(residuals):
                series = [(residuals[j][:, w], f"{z}_1")]
            else:
                series = []
            for d, sensor in series:
                ok = np.isfinite(d)
                if ok.sum() < 50:
                    continue
                d = d[ok]
                n = d.size // 5
                change = abs(np.median(d[-n:]) - np.median(d[:n]))
                if change > best:
                    best, name = change, sensor
        first += k
    return name
