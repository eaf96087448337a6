"""Measured against modelled zone temperatures, one PNG per zone and experiment, residuals
underneath: the paper's Fig. 8-10 (and 12-20), with what they leave out.

Drawn on a private Agg canvas, so importing this never changes a caller's matplotlib backend;
the numerics never import it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .experiment import Experiment

ZONE_TITLES = {"soak": "zone 1 (soaking)", "heat": "zone 2 (heating)",
               "preheat": "zone 3 (preheating)"}


def plot_zone(t_min: np.ndarray, measured: np.ndarray, model: np.ndarray, title: str,
              path: Path) -> Path:
    fig = Figure(figsize=(8, 5.5), dpi=100)
    FigureCanvasAgg(fig)
    top, bottom = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    top.plot(t_min, measured, ".", ms=1.5, color="0.45", label="measured")
    top.plot(t_min, model, "-", lw=1.2, color="C3", label="model")
    top.set_ylabel("temperature (°C)")
    top.set_title(title)
    top.legend(loc="upper left")
    top.grid(alpha=0.3)
    resid = measured - model
    bottom.plot(t_min, resid, ".", ms=1.5, color="C0")
    bottom.axhline(0.0, color="k", lw=0.8)
    bottom.set_ylabel("residual (°C)")
    bottom.set_xlabel("time (min)")
    bottom.grid(alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    return path


def plot_fit(exp: Experiment, model: np.ndarray, out_dir: Path, label: str = "") -> list[Path]:
    """One PNG per zone, <experiment>_<zone>.png, for model zone temperatures (N, zones)."""
    measured = exp.zone_temp
    paths = []
    for w, zone in enumerate(exp.furnace.zones):
        ok = np.isfinite(measured[:, w])
        rmse = float(np.sqrt(np.mean((measured[ok, w] - model[ok, w]) ** 2))) if ok.any() else np.nan
        where = ZONE_TITLES.get(zone, f"zone {w + 1} ({zone})")  # another furnace's zones
        title = f"{exp.name}: {where}{', ' + label if label else ''}  (RMSE {rmse:.2f} °C)"
        paths.append(plot_zone(exp.t_min, measured[:, w], model[:, w], title,
                               Path(out_dir) / f"{exp.name}_{zone}.png"))
    return paths
