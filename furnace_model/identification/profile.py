"""Profile-likelihood intervals for the parameters a record leaves wide.

A linearised interval is symmetric on the search scale. For a parameter the data pin down
that is right; for one they leave wide it is not: the paper's d and e ride on the preheating
zone's sub-minute time constant, and their estimates scatter with a long tail towards a slow
zone, which a symmetric interval misses (docs/identification.md has the coverage). The
profile follows the criterion itself: the parameter is held at
trial values, everything else refitted, and the interval ends where the criterion has
risen by as much as the linearised interval allows at its ends, calibrated by the residual's
colour (the sandwich over the white variance, so that autocorrelated residuals widen it).

A sliding window's refit knows where the window before ended its intervals: windows that
overlap by all but a period have their ends next to each other's, so each search may start
there (`start`) and step tightly around the crossing instead of out from the linearised
half-width. Both searches stop on the same test (a bracket 2% wide, or a trial within 5% of
the rise that is the first, or past the rise, or inside a bracket), so a warm end equals the
cold one to their widths.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

MAX_STEPS = 8
"""Criterion evaluations per side: each is a refit of every other unknown."""
NEAR = 0.008
"""A warm search aims this share of the distance past the crossing it expects, so that
the trial lands on the far side and the bracket closes to within 2% in one more."""


def profile_interval(sse_at: Callable[[float], float], z_hat: float, half: float,
                     sse_min: float, rise: float, lo: float, hi: float,
                     start: tuple[float, float] | None = None) -> tuple[float, float]:
    """(low, high) on the search scale where sse_at (the profiled criterion) has risen by
    `rise` above sse_min on each side of z_hat, started from the linearised half-width
    `half` and stopped at the search box [lo, hi].

    Each side first brackets the crossing (stepping out while the criterion stays below,
    by the square-root extrapolation that is exact for a quadratic criterion, at least 1.5
    and at most 4 times further), then narrows the bracket by false position on the square
    root of the rise. The criterion need not be monotone beyond the crossing (another
    parameter may reach its own bound there): only the bracket is trusted.

    `start` (low, high): where the ends were for a neighbouring record (the previous
    window's). A side whose start lies on it starts there instead, and aims each trial just
    past the crossing the square root predicts, towards the side of the bracket still far
    from it: typically one or two evaluations where the search from the half-width took
    four to eight. A start that is no guide (not finite, on the estimate's other side) is
    not used; one that is far off costs a few steps more, as a poor half-width does."""
    ends = []
    for k, side in enumerate((-1.0, 1.0)):
        room = (z_hat - lo) if side < 0 else (hi - z_hat)
        t0, tight = max(half, 1e-9), False
        if start is not None:
            warm = side * (float(start[k]) - z_hat)
            if np.isfinite(warm) and warm > 1e-9:
                t0, tight = warm, True
        end = _crossing(lambda t, side=side: sse_at(z_hat + side * t) - sse_min,
                        min(t0, room), room, rise, tight)
        ends.append(z_hat + side * end)
    return ends[0], ends[1]


def _crossing(rise_at: Callable[[float], float], t: float, room: float, rise: float,
              tight: bool) -> float:
    """Distance from the estimate, no further than `room`, at which rise_at crosses `rise`,
    starting at t; `tight`: t is a guess of the crossing itself (see profile_interval)."""
    inside, d_in = 0.0, 0.0  # distance known below the rise, and its rise
    outside, d_out = None, np.inf
    steps = 0
    while steps < MAX_STEPS and outside is None:
        steps += 1
        d = rise_at(t)
        if (steps == 1 or d >= rise) and _near(d, rise):
            # the first trial, where the quadratic holds to 5%, or a first one past the rise
            return float(np.clip(t * np.sqrt(rise / d), inside, room))
        if np.isfinite(d) and d < rise:
            inside, d_in = t, max(d, 0.0)
            if t >= room:
                return room  # low up to the box: anywhere in the range searched
            grow = np.sqrt(rise / max(d, 1e-12 * rise))
            if tight:
                t = min(t * float(np.clip(grow * (1.0 + NEAR), 1.0 + NEAR, 4.0)), room)
            else:
                t = min(t * float(np.clip(grow, 1.5, 4.0)), room)
        else:
            outside, d_out = t, d
    while outside is not None and steps < MAX_STEPS and outside - inside > 0.02 * outside:
        steps += 1
        a, b = np.sqrt(d_in), np.sqrt(d_out) if np.isfinite(d_out) else np.inf
        frac = (np.sqrt(rise) - a) / (b - a) if np.isfinite(b) and b > a else 0.5
        if tight and np.isfinite(b) and b > a:
            # just past the predicted crossing, away from the end of the bracket nearer it
            width = outside - inside
            guess = inside + frac * width
            toward = 1.0 if outside - guess > guess - inside else -1.0
            frac = (guess + toward * NEAR * guess - inside) / width
            t = inside + float(np.clip(frac, 0.05, 0.95)) * width
        else:
            t = inside + float(np.clip(frac, 0.1, 0.9)) * (outside - inside)
        d = rise_at(t)
        if _near(d, rise):  # a crossing of the bracket, found as closely as it would be
            return float(np.clip(t * np.sqrt(rise / d), inside, outside))
        if np.isfinite(d) and d < rise:
            inside, d_in = t, max(d, 0.0)
        else:
            outside, d_out = t, d
    return inside if outside is None else 0.5 * (inside + outside)


def _near(d: float, rise: float) -> bool:
    """Whether a trial's rise d is within 5% of `rise`: the square root's extrapolation
    from there puts the crossing within about 1% of its distance, as the 2% bracket's
    middle does."""
    return bool(np.isfinite(d) and abs(d / rise - 1.0) < 0.05)
