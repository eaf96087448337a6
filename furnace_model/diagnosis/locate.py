"""Where the baseline's error lies: thermocouples at fault, the residual's sharpest step and
the spans holding most of a zone's squared error; and the lines in which the verdict, the
report and the text summary say it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..experiment import Experiment
from ..identification.noisefloor import RecordFloor
from ..identification.residuals import (
    SUDDEN_WINDOW_MIN,
    ZONE_WORDS,
    error_spans,
    iso,
    regime,
    sudden_change,
)
from .words import and_words, temp_c, zones_words

MIN_SHARE = 0.02
"""A located span holds at least this share of its zone's squared error."""


@dataclass
class Located:
    zone: str
    sensor: str | None
    experiment: str
    start_min: float
    end_min: float
    start: str | None
    end: str | None
    share_of_error: float
    regime: str
    kind: str = "span"
    """sensor (a thermocouple departing from its partner), change (the sharpest step of the
    residual in any zone), span (a stretch holding much of a zone's error) or throughout (the
    zone's error runs through the whole record: `residuals.THROUGHOUT_SHARE`)."""


def locate(experiments: list[Experiment], residuals: list[np.ndarray],
           floors: list[RecordFloor], faults) -> list[Located]:
    """The located error: thermocouples at fault first, then the residual's sharpest step if
    it stands out of the noise (where a disturbance entered), then the spans that hold most
    of the residual's squared error above the floor, by their share of it (`ordered`)."""
    zones = experiments[0].furnace.zones if experiments else ()
    total = {z: 0.0 for z in zones}
    for r in residuals:
        for w, z in enumerate(zones):
            v = r[:, w]
            total[z] += float(np.nansum(v * v))

    def share(j: int, z: str, i0: int, i1: int) -> float:
        sse = float(np.nansum(residuals[j][i0:i1, zones.index(z)] ** 2))
        return sse / total[z] if total[z] > 0 else 0.0

    causes: list[Located] = []
    for f in faults:
        exp = experiments[f.experiment]
        z = f.sensor.rsplit("_", 1)[0]
        what = (f"{f.sensor} drifts {temp_c(f.size_c, sign=True)} °C from its partner"
                if f.kind == "drift" else
                f"{f.sensor} departs by about {temp_c(f.size_c, 0)} °C from its partner at times")
        causes.append(_located(exp, z, f.sensor, f.i0, f.i1,
                               share(f.experiment, z, f.i0, f.i1), what, "sensor"))
    spans = [s for s in error_spans(experiments, residuals, [f.floor_c for f in floors])
             if total[s.zone] > 0 and s.sse / total[s.zone] >= MIN_SHARE]  # else a burst of noise
    change = sudden_change(experiments, residuals, floors)
    if change is not None:
        exp = experiments[change.experiment]
        # The step is where a disturbance entered; the error it opens runs on to the end of
        # the stretch of its zone's error that the step's window reaches into. The entry
        # spans both, so that its share of the error is the error the step starts, not the
        # fraction of it within the step's own half hour (a slow zone's step holds well
        # under 1%).
        i1 = max([change.i1, *(s.i1 for s in spans if s.experiment == change.experiment
                               and s.zone == change.zone
                               and s.i0 < change.i1 and change.i0 < s.i1)])
        what = (f"the sharpest change in any zone: {temp_c(change.size_c, 0, sign=True)} °C "
                f"within {SUDDEN_WINDOW_MIN:g} min at its start; "
                f"{regime(exp, change.i0, change.i1, change.zone)}")
        causes.append(_located(exp, change.zone, None, change.i0, i1,
                               share(change.experiment, change.zone, change.i0, i1),
                               what, "change"))
    out = [_located(experiments[s.experiment], s.zone, None, s.i0, s.i1, s.sse / total[s.zone],
                    regime(experiments[s.experiment], s.i0, s.i1, s.zone),
                    "throughout" if s.throughout else "span") for s in spans]
    return ordered(causes, out)


def ordered(causes: list[Located], spans: list[Located]) -> list[Located]:
    """The located causes (a thermocouple at fault, then the sharpest change) lead, since
    they say what the error's size alone would blame on the wrong zone (a door's zone against
    the slower zones it drains); then every other entry by its share of the error, largest
    first. An entry whose share rounds to 0% is never first: a cause that holds none of the
    error joins the rest in its place by share."""
    lead: list[Located] = []
    rest: list[Located] = []
    for c in causes:
        (lead if round(100 * c.share_of_error) >= 1 else rest).append(c)
    return (sorted(lead, key=lambda w: (w.kind != "sensor", -w.share_of_error))
            + sorted(rest + spans, key=lambda w: -w.share_of_error))


def _located(exp: Experiment, zone: str, sensor: str | None, i0: int, i1: int, share: float,
             words: str, kind: str = "span") -> Located:
    a, b = float(exp.t_min[i0]), float(exp.t_min[max(i1 - 1, i0)])
    return Located(zone, sensor, exp.name, a, b, iso(exp, a), iso(exp, b), share, words, kind)


@dataclass
class WhereLine:
    """One line of 'where the error lies' as the verdict, the report and the text summary
    say it: the zones whose error runs throughout the same record are said once."""

    who: str  # "thermocouple heat_1", "heating zone", "soaking and heating zones"
    experiment: str
    span: str  # "120-300 min"; the whole record's for kind "throughout"
    clock: str  # "2026-03-10T06:00:00Z to 2026-03-10T09:00:00Z", or "" without a start time
    share: str  # of the zone's squared error: "41%", or "92%, 93% and 93%" for zones
    regime: str
    kind: str


def where_lines(where: list[Located], zones: tuple[str, ...]) -> list[WhereLine]:
    """`zones`: the furnace's, in order."""
    order = zones
    out: list[WhereLine] = []
    done: set[str] = set()
    for w in where:
        clock = f"{w.start} to {w.end}" if w.start and w.end else ""
        span = f"{w.start_min:.0f}-{w.end_min:.0f} min"
        if w.kind != "throughout":
            who = f"thermocouple {w.sensor}" if w.sensor else f"{ZONE_WORDS[w.zone]} zone"
            out.append(WhereLine(who, w.experiment, span, clock,
                                 f"{100 * w.share_of_error:.0f}%", w.regime, w.kind))
            continue
        if w.experiment in done:
            continue
        done.add(w.experiment)
        same = sorted((x for x in where if x.kind == "throughout" and x.experiment == w.experiment),
                      key=lambda x: order.index(x.zone) if x.zone in order else len(order))
        zones = zones_words([x.zone for x in same]) + (" zones" if len(same) > 1 else " zone")
        share = and_words([f"{100 * x.share_of_error:.0f}%" for x in same])
        out.append(WhereLine(zones, w.experiment, span, clock, share,
                             _common_regime([x.regime for x in same]), w.kind))
    return out


def _common_regime(regimes: list[str]) -> str:
    """The regime of several zones over one record: burners and steps are the record's,
    said once; the temperature bands (the last part) are the zones' own."""
    parts = [r.split("; ") for r in regimes]
    if len(parts) == 1 or any(p[:-1] != parts[0][:-1] or not p[-1].endswith(" °C")
                              for p in parts):
        return " / ".join(regimes)
    bands = [p[-1].removesuffix(" °C") for p in parts]
    return "; ".join([*parts[0][:-1], f"{and_words(bands)} °C"])
