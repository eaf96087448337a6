"""Per-zone goodness of fit, as the paper's tables report it and beyond.

The paper's 'mean error' per zone is kept as the mean absolute error; RMSE is what the noise
floor is compared with; fit % = 100 (1 - NRMSE) says how much of the zone's variation over
the record the model explains (100 is perfect, 0 is no better than the record's mean).
Missing readings (NaN) are left out, never filled.
"""

from __future__ import annotations

import numpy as np


def zone_metrics(measured: np.ndarray, model: np.ndarray,
                 zones: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """{zone: {mae_c, rmse_c, fit_pct, n}} over the finite entries of measured (N, zones)."""
    out: dict[str, dict[str, float]] = {}
    for w, zone in enumerate(zones):
        y, m = measured[:, w], model[:, w]
        ok = np.isfinite(y) & np.isfinite(m)
        if not ok.any():
            out[zone] = {"mae_c": float("nan"), "rmse_c": float("nan"),
                         "fit_pct": float("nan"), "n": 0}
            continue
        r = y[ok] - m[ok]
        spread = np.linalg.norm(y[ok] - y[ok].mean())
        fit = 100.0 * (1.0 - np.linalg.norm(r) / spread) if spread > 0 else float("nan")
        out[zone] = {"mae_c": float(np.abs(r).mean()), "rmse_c": float(np.sqrt(np.mean(r * r))),
                     "fit_pct": float(fit), "n": int(ok.sum())}
    return out


def pooled_metrics(measured: list[np.ndarray], model: list[np.ndarray],
                   zones: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """zone_metrics over several experiments taken together."""
    return zone_metrics(np.concatenate(measured), np.concatenate(model), zones)
