"""The noise floor of a record: the RMSE a perfect model would reach on it, per zone.

A model that predicts the furnace exactly still misses each reading by the thermocouples'
noise, so a model's error means something only against that floor, and only against the
floor of the record it is measured on: thermocouples are replaced between campaigns, and a
noisier one makes a held-out record's floor higher than the fitted record's.

The two thermocouples of a zone see the same gas, so their difference holds only their noise,
their biases and any drift. Biases and drifts are slow: the difference minus its slow trend (a
running median) keeps the noise, whatever its colour. Real thermocouples are
low-pass (sheath, transmitter filter, turbulence), so nothing here differences the signal:
a first or second difference sees only the fast part of coloured noise and reads it low.
The variance of the detrended pair difference is the sum of the two sensors' variances, and
a quarter of it is the variance of their mean, the zone temperature. How sure that number is
comes from the same difference: its autocorrelation (a low-order autoregression fitted to
it) says how many independent samples it holds.

A zone of three thermocouples has two pairs of neighbours, whose estimates are pooled.
A zone read by one thermocouple has no partner to compare with. Its floor is then borrowed
from the record's pairs (a thermocouple of the same kind in another zone), or, with no pair
anywhere in the record, read off its own reading: the one-step error of a first-order fit
of it (`equation_error_sd`) or its second differences, whichever is lower. Each reads the
noise plus whatever of the signal it cannot follow, never less in expectation: second
differences are the signal's curvature where the inputs move every sample (a zone held by
its loop, heat modulated every hour on hourly rows), which the fit follows; a fit of one
state misses a slower second one (a wall, a sensor's lag), whose curvature is small. Both
assume white noise and read low where it is low-pass, and the report says so.

Readings logged to a coarse step (a historian's whole degrees) hold still between steps, and
a robust spread of their differences, a pair's or a lone reading's, can read no noise at
all: a thermocouple's noise is taken as at least the rounding's, step / sqrt(12).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..experiment import Experiment, resolution
from .autoregression import acf, fit_ar

GAP_RATIO = 1.25
"""A zone's RMSE above this multiple of its noise floor misses it (or further, where the
records hold few independent samples: `GAP_Z`): a diagnosis's gap on held-out records, a
refit's misfit, a fit whose intervals are not profiled."""
GAP_Z = 3.0
"""Standard errors of the RMSE-to-floor ratio a miss must also exceed (`limits`)."""

TREND_MIN = 360.0
"""Minutes of the running median taken as a pair difference's slow trend. Long against the
correlation time of thermocouple noise (minutes), so that the noise is kept (the median of
W samples takes about (pi/2) tau / W of a noise of integrated correlation time tau, and that
share is given back: `TREND_TAKES`), and short against a drift's growth. A median follows a
monotone drift exactly, its onset's kink included, where a mean or block medians cut
across it."""
TREND_SAMPLES = 30
"""The fewest samples of the running median, however long they span (hourly rows)."""
TREND_PARTS = 3
"""The running median spans at most this share (1/TREND_PARTS) of a record's samples, so
that a short window's drift (a gateway's six hours) is followed, not read as noise."""
TREND_TAKES = np.pi / 2
"""The share of the noise's variance, times W / tau, that a running median of W samples
takes with the trend: a median's variance is pi/2 times a mean's."""
MAD_TO_SD = 1.482602218505602
"""The median absolute deviation of normal noise times this is its sd."""
CLIP_SD = 5.0
"""Samples further than this many robust sd from the trend are left out (a loose junction's
drop, a spike): the floor is the noise of working sensors, not of their faults."""
MIN_PAIR = 20
"""Samples with both thermocouples below which a pair does not give a floor."""
LONE = (", the lower of a lone reading's two estimates (each reads the noise plus what of "
        "the signal it cannot follow); it assumes white noise and reads low if the noise is "
        "low-pass")
"""How a lone thermocouple's floor was read, for the report."""


@dataclass
class ZoneFloor:
    """One zone of one record."""

    floor_c: float  # sd of the zone temperature's noise: the perfect model's RMSE
    tc_sd_c: float  # sd of one thermocouple's noise
    how: str  # pair | borrowed | equation_error | second_difference | none
    rel_sd: float  # relative standard error of floor_c (nan when unknown)
    lag1: float  # autocorrelation of the noise one sample apart
    n_eff: float  # independent samples the estimate rests on
    samples: int  # readings of the zone in the record

    def to_json(self) -> dict:
        return {"floor_c": _r(self.floor_c), "tc_sd_c": _r(self.tc_sd_c), "how": self.how,
                "rel_sd": _r(self.rel_sd), "lag1": _r(self.lag1), "n_eff": _r(self.n_eff),
                "samples": self.samples}

    def words(self) -> str:
        """How the floor was estimated and how sure it is, for a reader of the report."""
        sure = (f"+-{100 * self.rel_sd:.0f}%" if np.isfinite(self.rel_sd) else "uncertain")
        return {"pair": f"from the thermocouple pair's difference ({sure})",
                "borrowed": f"one thermocouple: borrowed from the record's pairs, assuming "
                            f"thermocouples of one kind ({sure})",
                "equation_error": "one thermocouple and no pair in the record: from the "
                                  f"one-step error of a first-order fit of its reading{LONE}",
                "second_difference": "one thermocouple and no pair in the record: from the "
                                     f"second differences of its reading{LONE}",
                "none": "no readings"}[self.how]


@dataclass
class RecordFloor:
    """The floor of one record, per zone."""

    record: str
    zones: dict[str, ZoneFloor]

    @property
    def floor_c(self) -> dict[str, float]:
        return {z: f.floor_c for z, f in self.zones.items()}

    def to_json(self) -> dict:
        return {"record": self.record, "zones": {z: f.to_json() for z, f in self.zones.items()}}


def record_floor(exp: Experiment) -> RecordFloor:
    """The noise floor of one record, each zone from its own thermocouples where it can."""
    pairs: dict[str, tuple[float, float, float, int]] = {}
    furnace = exp.furnace
    first = np.concatenate(([0], np.cumsum(furnace.thermocouples)[:-1])).astype(int)
    for w, zone in enumerate(furnace.zones):
        est = _zone_pairs(exp, int(first[w]), furnace.thermocouples[w])
        if est is not None:
            pairs[zone] = est
    zones = {}
    for w, zone in enumerate(furnace.zones):
        a = int(first[w])
        counts = np.isfinite(exp.tc[:, a:a + furnace.thermocouples[w]]).sum(axis=1)
        present = counts[counts > 0]
        samples = int(present.size)
        if not samples:
            zones[zone] = ZoneFloor(np.nan, np.nan, "none", np.nan, np.nan, 0.0, 0)
            continue
        mean_inv = float(np.mean(1.0 / present))  # a zone mean of k takes 1/k of the variance
        if zone in pairs:
            var_d, lag1, n_eff, _ = pairs[zone]
            how = "pair"
        elif pairs:
            # Another zone's pair, weighted by how many independent samples each holds.
            w_eff = np.array([p[2] for p in pairs.values()])
            var_d = float(np.average([p[0] for p in pairs.values()], weights=w_eff))
            lag1 = float(np.average([p[1] for p in pairs.values()], weights=w_eff))
            n_eff, how = float(w_eff.sum()), "borrowed"
        else:
            tc_sd, how = lone_sd(exp, w)
            var_d, lag1, n_eff = 2.0 * tc_sd * tc_sd, np.nan, np.nan
        tc_sd = max(float(np.sqrt(var_d / 2.0)),
                    resolution(exp.tc[:, a:a + furnace.thermocouples[w]]) / np.sqrt(12.0))
        rel = 1.0 / np.sqrt(2.0 * n_eff) if np.isfinite(n_eff) and n_eff > 0 else np.nan
        zones[zone] = ZoneFloor(tc_sd * np.sqrt(mean_inv), tc_sd, how, float(rel), lag1,
                                float(n_eff), samples)
    return RecordFloor(exp.name, zones)


def pooled_floor(floors: list[RecordFloor]) -> dict[str, float]:
    """Per zone, the floor of several records scored together: the RMS of their floors
    weighted by their readings, as a pooled RMSE weights them, so the two compare."""
    out = {}
    for zone in (floors[0].zones if floors else ()):
        num = den = 0.0
        for f in floors:
            zf = f.zones[zone]
            if zf.samples and np.isfinite(zf.floor_c):
                num += zf.samples * zf.floor_c ** 2
                den += zf.samples
        out[zone] = float(np.sqrt(num / den)) if den else float("nan")
    return out


def _zone_pairs(exp: Experiment, a: int, k: int) -> tuple[float, float, float, int] | None:
    """`_pair_variance` of a zone whose k thermocouples start at column a: its one pair, or
    its pairs of neighbours pooled (weighted by their independent samples)."""
    ests = [e for e in (_pair_variance(exp, a + i) for i in range(k - 1)) if e is not None]
    if len(ests) <= 1:
        return ests[0] if ests else None
    w = np.array([e[2] for e in ests])
    if not w.sum() > 0:
        w = np.ones(len(ests))
    return (float(np.average([e[0] for e in ests], weights=w)),
            float(np.average([e[1] for e in ests], weights=w)),
            float(sum(e[2] for e in ests)), int(sum(e[3] for e in ests)))


def _pair_variance(exp: Experiment, a: int) -> tuple[float, float, float, int] | None:
    """(variance of the pair difference's noise, its lag-1 autocorrelation, effective
    samples, samples) of the thermocouples in columns a and a + 1, or None when they are no
    working pair."""
    pair = exp.tc[:, a:a + 2]
    both = np.all(np.isfinite(pair), axis=1)
    if both.sum() < MIN_PAIR:
        return None
    t = exp.t_min[both]
    d = pair[both, 0] - pair[both, 1]
    trend, width = _slow_trend(t, d)
    e = d - trend
    robust = _robust_sd(e)
    if not np.isfinite(robust):
        return None
    if robust == 0.0:
        return 0.0, 0.0, float(e.size), int(e.size)
    kept = np.abs(e) <= CLIP_SD * robust
    e = np.where(kept, e, 0.0)  # a left-out sample leaves a zero, not a gap in the series
    tau = fit_ar(e).correlation_time
    var = float(e @ e / max(kept.sum() - 1, 1)) / max(1.0 - TREND_TAKES * tau / width, 0.5)
    n_eff = float(kept.sum()) / tau
    return var, float(acf(e, 1)[1]), n_eff, int(kept.sum())


def _slow_trend(t: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, int]:
    """The running median of d (`TREND_MIN`), and its width in samples. Medians at knots a
    quarter of a half-width apart, linear between them. Where a knot's window would run off
    the record, the trend is the line through the medians of the two halves of the window
    nearest it: a drift running to the record's end is followed to the end, where a
    truncated window's median would lag it by a quarter of its width."""
    n = d.size
    step_min = float(np.median(np.diff(t))) if n > 1 else 1.0
    width = int(min(max(TREND_MIN / max(step_min, 1e-9), TREND_SAMPLES), n / TREND_PARTS))
    h = max(width // 2, 1)
    knots = np.unique(np.r_[np.arange(0, n, max(h // 4, 1)), n - 1])
    level = np.empty(knots.size)
    head, tail = knots < h, knots >= n - h
    inner = ~(head | tail)
    if inner.any():
        windows = np.lib.stride_tricks.sliding_window_view(d, 2 * h + 1)
        level[inner] = np.median(windows[knots[inner] - h], axis=1)
    for at, lo in ((head, 0), (tail, max(n - (2 * h + 1), 0))):
        hi = min(n, lo + 2 * h + 1)
        mid = (lo + hi) // 2
        m1, m2 = np.median(d[lo:mid]), np.median(d[mid:hi])
        c1, c2 = np.median(t[lo:mid]), np.median(t[mid:hi])
        slope = (m2 - m1) / (c2 - c1) if c2 > c1 else 0.0
        level[at] = m1 + slope * (t[knots[at]] - c1)
    return np.interp(t, t[knots], level), 2 * h + 1


def _robust_sd(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    if x.size < 3:
        return float("nan")
    return float(MAD_TO_SD * np.median(np.abs(x - np.median(x))))


def lone_sd(exp: Experiment, w: int) -> tuple[float, str]:
    """A lone thermocouple's noise sd (zone w of `exp`), and how it was read: the lower of
    the two estimates (module docstring), nan where neither has the samples."""
    y = exp.zone_temp[:, w]
    found = [(sd, how) for sd, how in ((equation_error_sd(exp, w), "equation_error"),
                                       (second_difference_sd(y)[0], "second_difference"))
             if np.isfinite(sd)]
    return min(found) if found else (float("nan"), "second_difference")


def equation_error_sd(exp: Experiment, w: int) -> float:
    """Zone w's noise sd from the one-step error of its reading fitted as a first-order
    system of its own last reading, the other zones', the inputs held over the step and a
    constant, T(k+1) = a T(k) + sum b_j T_j(k) + c u(k) + d. With readings y = T + e the
    error is e(k+1) - a e(k) - sum b_j e_j(k) plus what the fit cannot follow, so its
    variance over 1 + a^2 + sum b_j^2 (the other zones' noise taken as this one's) is the
    noise variance or more. Only steps of the record's usual interval are used."""
    t = np.asarray(exp.t_min, dtype=float)
    if t.size < 3:
        return float("nan")
    y = np.asarray(exp.zone_temp, dtype=float)
    h = exp.sample_period_min()
    X = np.concatenate([y[:-1, [w]], np.delete(y[:-1], w, axis=1), exp.inputs_over_steps(),
                        np.ones((t.size - 1, 1))], axis=1)
    b = y[1:, w]
    used = np.isfinite(X).any(axis=0)  # a zone with no reading at all is no regressor
    used[0] = True
    X = X[:, used]
    keep = (np.abs(np.diff(t) - h) <= 1e-6 * h) & np.isfinite(X).all(axis=1) & np.isfinite(b)
    X, b = X[keep], b[keep]
    if b.size < X.shape[1] + MIN_PAIR:
        return float("nan")
    scale = np.abs(X).max(axis=0)
    scale[scale == 0] = 1.0
    coef = np.linalg.lstsq(X / scale, b, rcond=None)[0] / scale
    readings = int(used[:y.shape[1]].sum())  # this zone's and its neighbours' columns
    spread = 1.0 + float(np.sum(coef[:readings] ** 2))
    dof = b.size / (b.size - X.shape[1])
    return _robust_sd(b - X @ coef) * float(np.sqrt(dof / spread))


def second_difference_sd(y: np.ndarray) -> tuple[float, float]:
    """A lone thermocouple's noise sd from its second differences (sd sqrt(6) s for white
    noise on a signal smooth at the sample rate), and nan for its colour, which this cannot
    see."""
    d2 = np.diff(y, 2)
    d2 = d2[np.isfinite(d2)]
    if d2.size < MIN_PAIR:
        return float("nan"), float("nan")
    return _robust_sd(d2) / np.sqrt(6.0), float("nan")


def _r(x: float) -> float | None:
    x = float(x)
    return round(x, 6) if np.isfinite(x) else None


def limits(floors: list[RecordFloor], ratio: float, z: float) -> dict[str, float]:
    """Per zone, the RMSE above which records scored together are off their floor: `ratio`
    times the pooled floor, or further where the records hold few independent samples.

    A perfect model's RMSE and the floor are both estimates from the same noise, each with a
    relative standard error of about 1/sqrt(2 n_eff), so their ratio scatters by
    1/sqrt(n_eff); `z` of those are allowed. With white noise over a long record that is a
    few percent and `ratio` decides; with low-pass noise a record of a thousand samples holds
    some fifty independent ones, and a ratio of 1.25 would call noise a gap in one zone of
    ten."""
    floor = pooled_floor(floors)
    out = {}
    for zone in floor:
        n_eff = sum(f.zones[zone].n_eff if np.isfinite(f.zones[zone].n_eff)
                    else f.zones[zone].samples for f in floors)
        spread = 1.0 / np.sqrt(n_eff) if n_eff > 0 else np.inf
        out[zone] = floor[zone] * max(ratio, 1.0 + z * spread)
    return out
