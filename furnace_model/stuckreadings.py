"""Readings stuck at one value: one thermocouple's value repeated row after row, unchanged to
the last digit, far longer than its own record lets readings repeat (a logger or a historian
that fills a dead sensor's cells with its last value, a transmitter frozen on a fault). A
fit takes such a run as a zone that stood still while its heat input moved, and bends to
it; the diagnosis then looks for an effect that holds a zone still. The run's readings
after its first are left out (blank, as a missing reading is) and named.

How long is too long depends on the record: readings of a zone held at its setpoint and
logged to a whole degree repeat most rows, a room's to a tenth of a degree few. So the test
is the column's own. The share of its rows that repeat the row before (outside the run
tested) must make a run of so many repeats less likely than `STUCK_CHANCE` anywhere in it;
and elsewhere in the column the readings must move by `STUCK_QUANTA` of its steps or more
over as many rows, as a rule (the median over the column). The second part holds where
repeats are not independent: a room logged to a whole degree every minute stays on one
value for hours because it moves slowly, and over hours moves by a degree or two; a room
logged to a tenth moves by tens of tenths in the two days a dead sensor stays on one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .experiment import Experiment, listed, resolution

STUCK_CHANCE = 1e-6
"""A run of repeats is taken as stuck when the column's repeats, at its own rate and as if
independent, would make a run so long anywhere in it less often than this."""
STUCK_QUANTA = 10.0
"""...and when the column's readings, over as many rows elsewhere, typically span this many
of its smallest steps (its rounding)."""
MIN_STUCK_REPEATS = 5
"""...and only a run of at least this many repeats: a short run says nothing either way."""


@dataclass(frozen=True)
class Stuck:
    column: str
    first: int  # the row of the run's first reading, which is kept
    last: int  # its last row
    value: float
    t_first: float
    t_last: float


def stuck_readings(exp: Experiment) -> list[Stuck]:
    """The runs of each thermocouple column's readings repeated longer than chance allows
    (`STUCK_CHANCE`), its rows counted as the record gives them (a missing cell ends a run)."""
    out = []
    for c, column in enumerate(exp.furnace.tc_columns):
        x = exp.tc[:, c]
        same = (x[1:] == x[:-1]) & np.isfinite(x[1:])
        steps = int(np.sum(np.isfinite(x[1:]) & np.isfinite(x[:-1])))
        if steps < 2 * MIN_STUCK_REPEATS:
            continue
        edges = np.flatnonzero(np.diff(np.concatenate(([0], same.astype(np.int8), [0]))))
        repeats = int(same.sum())
        quantum = resolution(x) or np.inf  # a column of one value has no steps to count
        for start, end in zip(edges[::2], edges[1::2], strict=True):
            run = int(end - start)  # repeats in a row: steps start..end-1
            if run < MIN_STUCK_REPEATS:
                continue
            rate = (repeats - run) / max(steps - run, 1)
            if rate < 1.0 and steps * rate ** run < STUCK_CHANCE \
                    and _span(x, run + 1) >= STUCK_QUANTA * quantum:
                out.append(Stuck(column, int(start), int(end), float(x[start]),
                                float(exp.t_min[start]), float(exp.t_min[end])))
    return out


def _span(x: np.ndarray, rows: int) -> float:
    """The median range of x over windows of `rows` rows (every quarter window apart), NaN
    where a window holds fewer than two readings."""
    starts = np.arange(0, max(x.size - rows + 1, 1), max(rows // 4, 1))
    ranges = [np.ptp(w[np.isfinite(w)]) if np.isfinite(w).sum() > 1 else np.nan
              for w in (x[i:i + rows] for i in starts)]
    return float(np.nanmedian(ranges)) if np.isfinite(ranges).any() else 0.0


def without_stuck(exp: Experiment) -> tuple[Experiment, list[str]]:
    """exp with each stuck run's readings after its first blank, and a warning naming each."""
    found = stuck_readings(exp)
    if not found:
        return exp, []
    shown = listed([f"{s.column} {s.value:g} °C for {s.last - s.first + 1} rows from "
                    f"{exp.time_words(s.t_first)} to {exp.time_words(s.t_last)}" for s in found])
    return exp.without_readings((s.column, slice(s.first + 1, s.last + 1)) for s in found), [
        f"{exp.name}: {len(found)} run(s) of a reading repeated unchanged, each far longer "
        f"than the column's own readings repeat, left out after their first: {shown}; "
        "a logger that holds a dead sensor's last value writes such runs; blank them in the "
        "file to silence this"]
