"""Profile-likelihood intervals for the parameters a record leaves wide.

A linearised interval is symmetric on the search scale. For a parameter the data pin down
that is right; for one they leave wide it is not: the paper's d and e ride on the preheating
zone's sub-minute time constant, and their estimates scatter with a long tail towards a slow
zone, which a symmetric interval misses (docs/identification.md has the coverage). The
profile follows the criterion itself: the parameter is held at
trial values, everything else refitted, and the interval ends where the criterion has
risen by as much as the linearised interval allows at its ends, calibrated by the residual's
colour (the sandwich over the white variance, so that autocorrelated residuals widen it).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

MAX_STEPS = 8
"""Criterion evaluations per side: each is a refit of every other unknown."""


def profile_interval(sse_at: Callable[[float], float], z_hat: float, half: float,
                     sse_min: float, rise: float, lo: float, hi: float) -> tuple[float, float]:
    """(low, high) on the search scale where sse_at (the profiled criterion) has risen by
    `rise` above sse_min on each side of z_hat, started from the linearised half-width
    `half` and stopped at the search box [lo, hi].

    Each side first brackets the crossing (stepping out while the criterion stays below,
    by the square-root extrapolation that is exact for a quadratic criterion, at least 1.5
    and at most 4 times further), then narrows the bracket by false position on the square
    root of the rise. The criterion need not be monotone beyond the crossing (another
    parameter may reach its own bound there): only the bracket is trusted."""
    ends = []
    for side in (-1.0, 1.0):
        room = (z_hat - lo) if side < 0 else (hi - z_hat)
        inside, d_in = 0.0, 0.0  # distance known below the rise, and its rise
        outside, d_out = None, np.inf
        t = min(max(half, 1e-9), room)
        steps = 0
        while steps < MAX_STEPS and outside is None:
            steps += 1
            d = sse_at(z_hat + side * t) - sse_min
            if steps == 1 and np.isfinite(d) and abs(d / rise - 1.0) < 0.05:
                inside = outside = min(t * np.sqrt(rise / max(d, 1e-12 * rise)), room)
                break  # quadratic to 5% where the linearised interval ends: it holds
            if np.isfinite(d) and d < rise:
                inside, d_in = t, max(d, 0.0)
                if t >= room:
                    break  # low up to the box: anywhere in the range searched
                grow = np.sqrt(rise / max(d, 1e-12 * rise))
                t = min(t * float(np.clip(grow, 1.5, 4.0)), room)
            else:
                outside, d_out = t, d
        while outside is not None and steps < MAX_STEPS and outside - inside > 0.02 * outside:
            steps += 1
            a, b = np.sqrt(d_in), np.sqrt(d_out) if np.isfinite(d_out) else np.inf
            frac = (np.sqrt(rise) - a) / (b - a) if np.isfinite(b) and b > a else 0.5
            t = inside + float(np.clip(frac, 0.1, 0.9)) * (outside - inside)
            d = sse_at(z_hat + side * t) - sse_min
            if np.isfinite(d) and d < rise:
                inside, d_in = t, max(d, 0.0)
            else:
                outside, d_out = t, d
        end = inside if outside is None else 0.5 * (inside + outside)
        ends.append(z_hat + side * end)
    return ends[0], ends[1]
