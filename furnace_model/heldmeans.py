"""Time means of held inputs over rows: what a logger that resamples to rows records of an
input that holds each value until the next (a firing rate, a pulse-fired zone's count, a
disturbance). The log's resampler and the plant simulator's records both write rows this
way, so that a simulated record and an exported log say the same of the same inputs."""

from __future__ import annotations

import numpy as np


def row_edges(t: np.ndarray, single: float) -> np.ndarray:
    """Where each row's span ends: the next row's time; the last row as long as the one
    before (`single` when there is one row)."""
    if t.size == 0:
        return t.copy()
    last = t[-1] + (t[-1] - t[-2] if t.size > 1 else single)
    return np.append(t, last)


def held_means(t: np.ndarray, values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """The time mean over each span [edges[i], edges[i+1]) of `values` ((J,) or (J, m))
    held from each time t[j] (ascending) until the next, the first also before it; a span of
    no length takes the value at its instant. Times in any unit, integer nanoseconds
    included: they are taken relative to the first."""
    values = np.asarray(values, dtype=float)
    n = max(edges.size - 1, 0)
    if t.size == 0:
        return np.full((n, *values.shape[1:]), np.nan)
    s = (t - t[0]).astype(float)
    x = (edges - t[0]).astype(float)
    wide = (slice(None),) + (None,) * (values.ndim - 1)  # times against values' columns
    area = np.concatenate([np.zeros((1, *values.shape[1:])),
                           np.cumsum(values[:-1] * np.diff(s)[wide], axis=0)])
    j = np.clip(np.searchsorted(s, x, side="right") - 1, 0, None)
    integral = area[j] + values[j] * (x - s[j])[wide]
    width = np.diff(x)[wide]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(width > 0, np.diff(integral, axis=0) / np.where(width > 0, width, 1.0),
                        values[j[:-1]])
