"""The error a fit's own parameter uncertainty carries onto its predictions of other records.

A model fitted to one heat-up predicts another with its parameters fixed. Even a perfect
model then misses the held-out readings by more than their noise: its parameters are
estimates, and an error of a few percent in an exchange rate moves a 1300 °C heat-up by
degrees. With the paper's six parameters that share is small beside the noise; with the
twenty-two of a six-zone network fired unevenly it is not (seen: a control whose fitted
rates were all within 3.4% of the truth missed its held-out heat-up by twice the noise
floor in every zone, and the fit's covariance said 1.3-1.7 °C of it was to be expected).
So a held-out error is a gap only when it stands clear of the noise *and* of what the
parameters' uncertainty carries.

The carried error is the linearised propagation of the fit's covariance to the held-out
predictions, with each held-out record's own initial state and offsets re-estimated (their
Jacobian columns are projected out, as refitting them would), as a quantile: the squared
error a zone picks up is a weighted sum of chi-squares (the covariance's directions as the
zone's readings see them), taken by Satterthwaite's scaled chi-square.

A held-out tail of a fitted record (the last part of one window) is not re-estimated: it
continues the fitted run from the initial state and offsets the fitted rows gave together
with the parameters. Given the parameters, those own unknowns follow them (their least
squares on the fitted rows) and keep a spread of their own (the noise over what the fitted
rows see of them), independent of the parameters'; the tail's prediction moves with both
(`carried_onto_tail`). Without it, a window in closed loop whose held-out hours step the
setpoints to where the fitted hours never went misses them by what its loosely determined
rates carry, and that would read as an effect left out.

Two choices keep it from hiding what the diagnosis looks for. The covariance is the white
one scaled to the records' noise floor, not the residual's: an unmodelled effect inflates
the residual and colours it, and that is the misfit to find, not uncertainty to allow for.
And directions the fitted data leave wider than `LINEAR_HALF_WIDTH` are left out: there the
linearisation says nothing (a clipped direction's variance is huge by construction), and
what the fitted data do not see at all is estimated on the held-out records instead
(`diagnosis.fitting.unseen_by_fit`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.special import chdtri, ndtr

from ..experiment import Experiment
from .problem import Problem
from .result import FitResult
from .uncertainty import Z95, Uncertainty

LINEAR_HALF_WIDTH = 0.5
"""A direction of the parameters (log scale for rates) whose 95% half-width is wider than
this, a factor of 1.65 either way, is past where a linear propagation means anything."""


def carried_error(fr: FitResult, records: list[Experiment], x0: list[np.ndarray],
                  offsets: list[np.ndarray], noise_sd_c: float, z: float) -> dict[str, float]:
    """Per zone, the RMSE (°C) over `records` that the fitted parameters' uncertainty alone
    reaches with probability norm.cdf(z); `x0` and `offsets` per record: its re-estimated
    initial state and zone offsets. `noise_sd_c`: the noise a residual of the fitted records
    has at their floor. Zero where nothing is fitted or nothing is held out."""
    zones = fr.structure.furnace.zones
    out = dict.fromkeys(zones, 0.0)
    unc = fr.uncertainty
    if unc is None or not records or not unc.names or unc.cov_white is None:
        return out
    prob, Jp, N = _jacobian(fr, records, x0, offsets)
    Jp = Jp - N @ np.linalg.lstsq(N, Jp, rcond=None)[0]  # the records' own unknowns refitted
    root = _root(unc, noise_sd_c)
    if root is None:
        return out
    zone_of = np.concatenate([r.zone_of for r in prob.records])
    return _quantiles(zones, zone_of, Jp @ root, z)


def carried_onto_tail(fr: FitResult, joined: Experiment, n_head: int, x0: np.ndarray,
                      offsets: np.ndarray, noise_sd_c: float, z: float,
                      refitted: Sequence[str] = ()) -> dict[str, float]:
    """Per zone, the RMSE (°C) over the rows of `joined` from `n_head` on (a held-out tail
    continuing a fitted record, the fitted rows before it) that the fit's uncertainty alone
    reaches with probability norm.cdf(z): the parameters' and, given them, the fitted
    record's own initial state `x0` and `offsets` (see the module's docstring). The
    parameters in `refitted` (those the fitted rows do not see, set on the tail itself)
    carry nothing; the others' directions wider than `LINEAR_HALF_WIDTH` are held to it."""
    zones = fr.structure.furnace.zones
    out = dict.fromkeys(zones, 0.0)
    unc = fr.uncertainty
    if unc is None or not unc.names or unc.cov_white is None or n_head >= len(joined):
        return out
    prob, Jp, N = _jacobian(fr, [joined], [x0], [offsets])
    record = prob.records[0]
    head = np.nonzero(record.mask)[0] < n_head
    if not head.any() or head.all():
        return out
    # the own unknowns given the parameters: their least squares on the fitted rows ...
    follow = np.linalg.lstsq(N[head], Jp[head], rcond=None)[0]
    seen = np.array([n not in refitted for n in unc.names])
    Jp_tail = (Jp[~head] - N[~head] @ follow)[:, seen]
    # ... and their own spread there, independent of the parameters'
    w, V = np.linalg.eigh(np.linalg.pinv(N[head].T @ N[head]))
    own = V[:, w > 0] * (noise_sd_c * np.sqrt(w[w > 0]))
    root = _root(unc, noise_sd_c, wide="clip", among=seen)
    rows = N[~head] @ own if root is None else np.hstack([Jp_tail @ root, N[~head] @ own])
    return _quantiles(zones, record.zone_of[~head], rows, z)


def _jacobian(fr: FitResult, records: list[Experiment], x0: Sequence[np.ndarray],
              offsets: Sequence[np.ndarray]) -> tuple[Problem, np.ndarray, np.ndarray]:
    """The residual's Jacobian over `records` at the fit's parameters and each record's
    `x0` and `offsets`, split into the fitted parameters' columns and the records' own."""
    unc = fr.uncertainty
    fixed = {n: v for n, v in fr.params.items() if n not in unc.names}
    prob = Problem(records, fr.structure, fixed, {}, zone_offsets=True)
    J = np.nan_to_num(prob.jac(prob.start(unc.z.copy(), offsets, x0)))
    return prob, J[:, :prob.k], J[:, prob.k:]


def _root(unc: Uncertainty, noise_sd_c: float, wide: str = "drop",
          among: np.ndarray | None = None) -> np.ndarray | None:
    """R with R R' the white covariance of the parameters (`among` them, a mask: the others
    marginalised) scaled to the noise floor; the directions wider than `LINEAR_HALF_WIDTH`
    left out (`wide` "drop": the held-out records estimate them) or held to that width
    ("clip": nothing estimates them again, and they carry at least that much). None when
    nothing is left."""
    cov = unc.cov_white if among is None else unc.cov_white[np.ix_(among, among)]
    w, V = np.linalg.eigh(cov)
    scale = min(1.0, (noise_sd_c / unc.sigma) ** 2) if unc.sigma > 0 else 1.0
    var = np.maximum(w, 0.0) * scale
    widest = (LINEAR_HALF_WIDTH / Z95) ** 2
    if wide == "clip":
        var = np.minimum(var, widest)
    keep = (var > 0) & (var <= widest)
    if not keep.any():
        return None
    return V[:, keep] * np.sqrt(var[keep])


def _quantiles(zones: tuple[str, ...], zone_of: np.ndarray, rows: np.ndarray,
               z: float) -> dict[str, float]:
    """Per zone, the norm.cdf(z) quantile of the RMS of `rows` @ e over that zone's rows, e
    standard normal: a weighted sum of chi-squares, by Satterthwaite's scaled chi-square."""
    out = dict.fromkeys(zones, 0.0)
    p = float(ndtr(z))
    for k, zone in enumerate(zones):
        mine = rows[zone_of == k]
        if mine.shape[0] == 0:
            continue
        lam = np.linalg.svd(mine, compute_uv=False) ** 2 / mine.shape[0]
        mean, spread = float(lam.sum()), float((lam ** 2).sum())
        if mean <= 0.0:
            continue
        dof = mean ** 2 / spread
        out[zone] = float(np.sqrt(spread / mean * chdtri(dof, 1.0 - p)))
    return out
