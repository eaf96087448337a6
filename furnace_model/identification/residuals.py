"""Where a model's error lies, measured against each record's noise floor
(furnace_model.identification.noisefloor): the time spans and operating regimes that hold
the error, thermocouples that disagree with their partner, and the whiteness and input
cross-correlation tests of the residual (as MATLAB's `resid` draws them).

Everything here reads measured data and a model's predictions; nothing is fitted except
straight lines and hinges to the difference of a thermocouple pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.ndimage import median_filter
from scipy.special import ndtri

from ..experiment import Experiment
from .noisefloor import RecordFloor

Z99 = 2.5758293035489004
MAX_LAG = 25
"""Lags (in samples) of the whiteness and cross-correlation tests, MATLAB's default."""
EPISODE_WINDOW = 121
"""Samples of the running median a thermocouple pair's difference is compared with."""
MIN_SPAN = 5
"""Samples: a shorter run of large residuals is a spike, not a span."""
THROUGHOUT_SHARE = 0.8
"""A zone's stretches that together cover this share of a record's samples are one entry,
the whole record: an error that runs through most of a record is not localised by cutting
it where the residual happens to cross the noise band."""


class _ZoneWords(dict):
    """The paper's zones in words; any other zone by its name, `_` read as a space."""

    def __missing__(self, zone: str) -> str:
        return zone.replace("_", " ")


ZONE_WORDS = _ZoneWords(soak="soaking", heat="heating", preheat="preheating")


@dataclass
class Span:
    """A contiguous stretch of one zone's residual in one experiment."""

    zone: str
    experiment: int  # index into the experiments given
    i0: int
    i1: int  # exclusive
    sse: float
    excess: float  # squared error above the noise floor
    throughout: bool = False  # the whole record (`THROUGHOUT_SHARE`)


def error_spans(experiments: list[Experiment], residuals: list[np.ndarray],
                floors: list[dict[str, float]], max_spans: int = 6) -> list[Span]:
    """The stretches that hold most of the error above the noise floor, largest first.

    Per zone and experiment, the maximum-sum run of (r^2 - 4 floor^2) is a stretch where
    the residual stays well above the noise of that record (`floors`, one per experiment;
    noise-level samples count against it), found in one pass; it is taken out and the search repeated for a second and third stretch.
    """
    spans: list[Span] = []
    for j, r in enumerate(residuals):
        for w, zone in enumerate(experiments[j].furnace.zones):
            rz = r[:, w]
            sq = np.where(np.isfinite(rz), rz * rz, 0.0)
            fl = floors[j][zone]
            fl2 = fl * fl if np.isfinite(fl) else 0.0
            gain = sq - 4.0 * fl2
            used = np.zeros(sq.size, dtype=bool)
            found: list[Span] = []
            for _ in range(3):
                g = np.where(used, -np.inf, gain)
                i0, i1, total = _max_subarray(g)
                if total <= 0 or i1 - i0 < MIN_SPAN:
                    break
                used[i0:i1] = True
                found.append(Span(zone, j, i0, i1, float(sq[i0:i1].sum()),
                                 float((sq[i0:i1] - fl2).sum())))
            spans += _throughout(found, sq, fl2, np.isfinite(rz))
    spans.sort(key=lambda s: -s.excess)
    return spans[:max_spans]


def _throughout(found: list[Span], sq: np.ndarray, fl2: float,
                finite: np.ndarray) -> list[Span]:
    """One zone's stretches in one record, or the whole record in their place when they
    cover `THROUGHOUT_SHARE` of its samples with a residual."""
    covered = sum(int(finite[s.i0:s.i1].sum()) for s in found)
    if not found or covered < THROUGHOUT_SHARE * finite.sum():
        return found
    s = found[0]
    return [Span(s.zone, s.experiment, 0, sq.size, float(sq.sum()),
                 float((sq[finite] - fl2).sum()), throughout=True)]


SUDDEN_WINDOW_MIN = 15.0
SUDDEN_SIGNIFICANCE = 8.0
"""A step between window means counts when it exceeds this many of its own noise sd (the
sd of a window's mean of the record's noise, times sqrt(2)): the largest of some 1300 steps of pure
noise (two 3500-minute records, three zones) is about 4 of them."""


@dataclass
class Change:
    zone: str
    experiment: int
    i0: int  # the sample the step starts at (first of the window before it)
    i1: int  # end (exclusive) of the window after it
    size_c: float  # later window mean minus earlier one
    score: float  # |size| over its noise sd


def sudden_change(experiments: list[Experiment], residuals: list[np.ndarray],
                  floors: list[RecordFloor]) -> Change | None:
    """The sharpest step of the residual between consecutive 15-minute means, over every
    zone and record, if it stands out of the noise. A disturbance entering one zone (a door
    left open) moves that zone's residual first and most steeply; the zones it drains follow
    more slowly and, with larger capacities, may hold more squared error for longer, so the
    error's size alone points at the wrong zone."""
    best: Change | None = None
    for j, (e, r) in enumerate(zip(experiments, residuals, strict=True)):
        if len(e) < 4:
            continue
        dt = float(np.median(np.diff(e.t_min)))
        n = max(2, int(round(SUDDEN_WINDOW_MIN / dt)) if dt > 0 else 2)
        m = len(e) // n
        if m < 2:
            continue
        for w, zone in enumerate(e.furnace.zones):
            fl = floors[j].zones[zone].floor_c * _mean_sd_factor(floors[j].zones[zone].lag1, n)
            blocks = r[:m * n, w].reshape(m, n)
            with np.errstate(all="ignore"):
                means = np.nanmean(blocks, axis=1) if np.isfinite(blocks).any() else None
            if means is None or not np.isfinite(fl) or fl <= 0:
                continue
            steps = np.diff(means)
            if not np.isfinite(steps).any():
                continue
            k = int(np.nanargmax(np.abs(steps)))
            score = abs(steps[k]) / (fl * np.sqrt(2.0))
            if score >= SUDDEN_SIGNIFICANCE and (best is None or score > best.score):
                best = Change(zone, j, k * n, (k + 2) * n, float(steps[k]), float(score))
    return best


def _mean_sd_factor(lag1: float, n: int) -> float:
    """sd of the mean of n consecutive noise samples over the noise's own sd: 1/sqrt(n) for
    white noise, more for low-pass noise, whose neighbours move together (first-order
    autoregression with the record's lag-1 correlation)."""
    phi = float(np.clip(lag1, 0.0, 0.999)) if np.isfinite(lag1) else 0.0
    if phi == 0.0:
        return float(1.0 / np.sqrt(n))
    var = ((1 + phi) / (1 - phi) - 2 * phi * (1 - phi ** n) / (n * (1 - phi) ** 2)) / n
    return float(np.sqrt(max(var, 1.0 / n)))


def _max_subarray(g: np.ndarray) -> tuple[int, int, float]:
    """(start, end exclusive, sum) of the maximum-sum contiguous run (Kadane)."""
    best, best_i0, best_i1 = 0.0, 0, 0
    run, run_i0 = 0.0, 0
    for i, v in enumerate(g):
        if not np.isfinite(v):
            run, run_i0 = 0.0, i + 1
            continue
        if run <= 0:
            run, run_i0 = v, i
        else:
            run += v
        if run > best:
            best, best_i0, best_i1 = run, run_i0, i + 1
    return best_i0, best_i1, best


def regime(exp: Experiment, i0: int, i1: int, zone: str) -> str:
    """The operating regime of samples i0:i1 in plain words: which zones' burners fire,
    burner steps inside (or, on a furnace fired by rates, each fired zone's mean input in its
    unit), and the zone's temperature band, in steps its span can tell apart."""
    b = exp.burners[i0:i1]
    furnace = exp.furnace
    zones = furnace.zones
    firing = [ZONE_WORDS[z] for k, z in enumerate(zones) if np.mean(b[:, k] > 0) >= 0.5]
    fired = "burners firing" if not furnace.modulated else "fired"
    if not firing:
        words = ["no burners firing" if not furnace.modulated else "no zone fired"]
    elif len(firing) == 1:
        words = [f"{firing[0]}-zone {fired}"]
    else:
        words = [f"{', '.join(firing[:-1])} and {firing[-1]}-zone {fired}"]
    if furnace.modulated:
        means = [f"{ZONE_WORDS[z]} {np.mean(b[:, k]):.3g} {h.unit}"
                 for k, (z, h) in enumerate(zip(zones, furnace.heat_inputs, strict=True))
                 if b.size and np.mean(b[:, k]) > 0]
        words.append("mean input " + ", ".join(means) if means else "")
    else:
        total = b.sum(axis=1)
        steps = np.nonzero(np.diff(total) != 0)[0]
        if steps.size:
            k = steps[0]
            words.append(f"burners {int(total[k])} -> {int(total[k + 1])} at "
                         f"{exp.t_min[i0 + k + 1]:.0f} min"
                         + (f" (+{steps.size - 1} more step{'s' if steps.size > 2 else ''})"
                            if steps.size > 1 else ""))
        else:
            words.append(f"{int(total[0])} burners on" if total.size else "")
    y = exp.zone_temp[i0:i1, zones.index(zone)]
    if np.isfinite(y).any():
        lo, hi = np.nanmin(y), np.nanmax(y)
        span = hi - lo
        band = 100.0 if span > 150 else 50.0 if span > 40 else 10.0 if span > 8 else 1.0
        words.append(f"{np.floor(lo / band) * band:.0f}-{np.ceil(hi / band) * band:.0f} °C")
    return "; ".join(w for w in words if w)


def iso(exp: Experiment, t_min: float) -> str | None:
    if exp.start_time is None:
        return None
    ts = pd.Timestamp(exp.start_time) + pd.Timedelta(minutes=float(t_min))
    return ts.tz_convert("UTC").strftime("%Y-%m-%dT%H:%M:%SZ")


@dataclass
class SensorFault:
    """A thermocouple that disagrees with its partner in a way noise cannot explain."""

    sensor: str
    experiment: int
    i0: int
    i1: int
    kind: str  # "drift" | "episodes"
    size_c: float  # drift over the span, or the typical departure in the episodes


def sensor_faults(experiments: list[Experiment], predictions: list[np.ndarray],
                  tc_noise: list[dict[str, float]]) -> list[SensorFault]:
    """Pairs whose difference grows over the record (a drifting thermocouple) or jumps away
    for episodes (a loose junction): the sensor, not the furnace, is to blame there.

    `tc_noise`: one thermocouple's noise sd per zone, for each experiment. Which of the two
    is at fault: the one whose reading departs more from the model's
    prediction over the span (the model may be wrong too, but equally for both)."""
    out: list[SensorFault] = []
    for j, exp in enumerate(experiments):
        pred = predictions[j]
        sensors = exp.furnace.sensors
        for w, zone, a in _pairs(exp):
            pair = exp.tc[:, a:a + 2]
            both = np.all(np.isfinite(pair), axis=1)
            s = tc_noise[j].get(zone, float("nan"))
            if both.sum() < 50 or not np.isfinite(s) or s <= 0:
                continue
            t = exp.t_min[both]
            d = pair[both, 0] - pair[both, 1]
            sd_d = s * np.sqrt(2.0)
            dev = (pair - pred[:, w:w + 1]) - np.nanmedian(pair - pred[:, w:w + 1], axis=0)
            # episodes: readings far from the pair's running median (which follows a slow
            # drift but not a departure of minutes), outside its noise band
            smooth = median_filter(d, size=EPISODE_WINDOW, mode="nearest")
            far = np.abs(d - smooth) > 6.0 * sd_d
            if far.sum() >= 3:
                idx = np.nonzero(both)[0][far]
                culprit = int(np.argmax(np.nanmean(np.abs(dev[idx]), axis=0)))
                _add(out, SensorFault(sensors[a + culprit], j, int(idx[0]), int(idx[-1]) + 1,
                                      "episodes", float(np.median(np.abs(d - smooth)[far]))))
            t0, change = _hinge(t[~far], d[~far])
            late_n = max(1.0, float((t >= t0).sum()) / 50.0)
            if abs(change) > max(8.0 * sd_d / np.sqrt(late_n), 2.0):
                i0 = int(np.searchsorted(exp.t_min, t0))
                late = slice(i0, None)
                culprit = int(np.argmax(np.nanmean(np.abs(dev[late]), axis=0)))
                _add(out, SensorFault(sensors[a + culprit], j, i0, len(exp), "drift",
                                      float(change if culprit == 0 else -change)))
    return out


def _pairs(exp: Experiment):
    """(zone index, zone, first column) of each pair of neighbouring thermocouples of a
    zone: one per zone of two (the paper's), two for a zone of three; none for a zone of one,
    which has no partner to disagree with."""
    first = 0
    for w, (zone, k) in enumerate(zip(exp.furnace.zones, exp.furnace.thermocouples,
                                      strict=True)):
        for i in range(k - 1):
            yield w, zone, first + i
        first += k


def _add(out: list[SensorFault], fault: SensorFault) -> None:
    """A thermocouple of three is in two pairs: its fault is said once."""
    if not any(f.sensor == fault.sensor and f.experiment == fault.experiment
               and f.kind == fault.kind for f in out):
        out.append(fault)


def _hinge(t: np.ndarray, d: np.ndarray, n_grid: int = 40) -> tuple[float, float]:
    """Best fit of d = a + b max(t - t0, 0) over a grid of onsets: (t0, change to the end)."""
    best = (float(t[0]), 0.0, np.inf)
    for t0 in np.linspace(t[0], t[0] + 0.9 * (t[-1] - t[0]), n_grid):
        x = np.maximum(t - t0, 0.0)
        X = np.column_stack([np.ones_like(x), x])
        coef, *_ = np.linalg.lstsq(X, d, rcond=None)
        sse = float(np.sum((d - X @ coef) ** 2))
        if sse < best[2]:
            best = (float(t0), float(coef[1] * (t[-1] - t0)), sse)
    return best[0], best[1]


def _xcorr(a: np.ndarray, b: np.ndarray, lags: np.ndarray) -> np.ndarray:
    """Normalised cross-correlation E[a(t+k) b(t)] for each lag k."""
    n = a.size
    sa, sb = np.sqrt(np.mean(a * a)), np.sqrt(np.mean(b * b))
    if sa == 0 or sb == 0:
        return np.zeros(lags.size)
    out = np.empty(lags.size)
    for i, k in enumerate(lags):
        out[i] = (np.sum(a[k:] * b[:n - k]) if k >= 0 else np.sum(a[:n + k] * b[-k:])) / n
    return out / (sa * sb)


def residual_tests(experiments: list[Experiment], residuals: list[np.ndarray],
                   max_lag: int = MAX_LAG) -> dict:
    """Per zone: autocorrelation of the residual with its 99% band (whiteness), and its
    cross-correlation with each input (burners per zone and their changes) with a 99% band
    that allows for the input's own autocorrelation (Bartlett), as `resid` does. The bands
    are pointwise, for drawing; the verdicts `white` and `independent` use the band that
    holds for all lags at once.

    A residual outside the band at lag k > 0 of an input says the model misses how the
    furnace responds to that input k samples later."""
    inputs = {}
    zones = experiments[0].furnace.zones if experiments else ()
    for k, z in enumerate(zones):
        inputs[f"burners_{z}"] = [e.burners[:, k].astype(float) for e in experiments]
        inputs[f"d_burners_{z}"] = [np.diff(e.burners[:, k].astype(float), prepend=e.burners[0, k])
                                    for e in experiments]
    lags_a = np.arange(max_lag + 1)
    lags_x = np.arange(-max_lag, max_lag + 1)
    out: dict = {}
    for w, zone in enumerate(zones):
        parts = []
        for r in residuals:
            e = r[:, w]
            e = np.where(np.isfinite(e), e - np.nanmean(e), 0.0)
            parts.append(e)
        e = np.concatenate(parts)
        n = e.size
        acf = _xcorr(e, e, lags_a)
        bound = Z99 / np.sqrt(max(n, 1))
        z_a, z_x = _simultaneous_z(max_lag), _simultaneous_z(lags_x.size)
        zone_out = {"n": int(n), "lags": lags_a.tolist(),
                    "autocorr": np.round(acf, 5).tolist(), "autocorr_bound": float(bound),
                    "white": bool(np.all(np.abs(acf[1:]) <= bound * z_a / Z99)), "xcorr": {}}
        for name, series in inputs.items():
            u = np.concatenate([s - s.mean() for s in series])
            if not np.any(u):
                continue
            cc = _xcorr(e, u, lags_x)
            acf_u = _xcorr(u, u, lags_a)
            # var of the sample cross-correlation of independent series: sum of the
            # products of their autocorrelations over all lags, divided by n
            var = (1.0 + 2.0 * np.sum(acf[1:] * acf_u[1:])) / n
            b = float(Z99 * np.sqrt(max(var, 1.0 / n)))
            k = int(np.argmax(np.abs(cc)))
            zone_out["xcorr"][name] = {"lags": lags_x.tolist(), "values": np.round(cc, 5).tolist(),
                                       "bound": b, "max_abs": float(abs(cc[k])),
                                       "at_lag": int(lags_x[k]),
                                       "independent": bool(np.all(np.abs(cc) <= b * z_x / Z99))}
        out[zone] = zone_out
    return out


def _simultaneous_z(m: int) -> float:
    """Normal quantile that m lags all stay within with 99% probability when the residual
    is white (Bonferroni): the pointwise 99% band, drawn as `resid` draws it, is crossed
    somewhere among 25 or 51 lags far more often than one time in a hundred."""
    return float(ndtri(1.0 - 0.01 / (2.0 * max(m, 1))))


def lag1(residuals: list[np.ndarray]) -> float:
    """Mean lag-1 autocorrelation of the residual over zones and experiments."""
    vals = []
    for r in residuals:
        for w in range(r.shape[1]):
            e = r[:, w]
            e = e[np.isfinite(e)]
            if e.size > 10:
                e = e - e.mean()
                den = float(e @ e)
                if den > 0:
                    vals.append(float(e[1:] @ e[:-1]) / den)
    return float(np.clip(np.mean(vals), 0.0, 0.999)) if vals else 0.0
