"""Lone readings that no furnace or room makes: one thermocouple reading far from the two
beside it, which agree with each other (a junction that opened for one poll, a value
logged in the wrong unit, a transmission error). A thermal capacity cannot go there and
back within a sample period, but a least-squares fit follows such a reading as if it
could: a single reading tens of degrees off a record whose noise is a tenth of a degree
weighs more than all the rest, and moves every parameter and every verdict. Such a
reading is left out (its cell made blank, as a missing reading is) and named, so that
nothing is changed unsaid.

The test is on the reading's departure from the mean of its neighbours, measured against
that same departure's spread over the whole column (its median absolute value), and
against the neighbours' own difference: a fast ramp or a kink at a burner's start moves
the neighbours apart as much as the middle, an input pulse a room follows recurs and sets
the spread. Only departures many times beyond both are taken.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .experiment import OUTAGE_PERIODS, Experiment, listed, resolution

GLITCH_SPREADS = 15.0
"""A departure from the neighbours' mean this many times the column's typical one (its
median absolute departure, as a standard deviation: x 1.4826): Gaussian noise's largest
in a million readings is about 5."""
GLITCH_NEIGHBOURS = 5.0
"""...and this many times the difference between the two neighbours, so that the reading
is not the middle of a ramp they span."""


@dataclass(frozen=True)
class Glitch:
    column: str
    row: int
    t_min: float
    value: float
    expected: float  # the mean of the two readings beside it


def glitches(exp: Experiment) -> list[Glitch]:
    """The lone readings of each thermocouple column that depart from both readings beside
    it, which lie next to it in time (no outage between) and agree with each other."""
    out = []
    if len(exp) < 3:
        return []
    step = np.diff(exp.t_min)
    near = OUTAGE_PERIODS * exp.row_spacing_min()
    beside = (step[:-1] <= near) & (step[1:] <= near)  # no outage on either side
    for c, column in enumerate(exp.furnace.tc_columns):
        x = exp.tc[:, c]
        i = np.flatnonzero(np.isfinite(x[:-2]) & np.isfinite(x[1:-1]) & np.isfinite(x[2:])
                           & beside) + 1
        if i.size < 20:
            continue
        mid = 0.5 * (x[i - 1] + x[i + 1])
        dev = x[i] - mid
        typical = 1.4826 * float(np.median(np.abs(dev)))
        typical = max(typical, resolution(x))  # a logger's rounding
        if typical <= 0.0:
            continue
        far = (np.abs(dev) > GLITCH_SPREADS * typical) \
            & (np.abs(dev) > GLITCH_NEIGHBOURS * np.abs(x[i + 1] - x[i - 1]))
        out += [Glitch(column, int(k), float(exp.t_min[k]), float(x[k]), float(m))
                for k, m in zip(i[far], mid[far], strict=True)]
    return out


def without_glitches(exp: Experiment) -> tuple[Experiment, list[str]]:
    """exp with its `glitches` blank, and a warning naming each."""
    found = glitches(exp)
    if not found:
        return exp, []
    shown = listed([f"{g.column} at {exp.time_words(g.t_min)} ({g.value:g} °C where the "
                    f"readings beside it average {g.expected:.4g})" for g in found])
    return exp.without_readings((g.column, g.row) for g in found), [
        f"{exp.name}: {len(found)} lone reading(s) left out, each far from the two beside it, "
        f"which agree: {shown}; a thermal capacity cannot go there and back within a "
        "sample, so these are the sensor's or the logging's; blank them in the file to "
        "silence this"]
