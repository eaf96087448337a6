"""Low-order autoregressions of noise series: how correlated neighbouring samples are.

Thermocouple noise and a model's residual are rarely white: a sheath and a transmitter
filter low-pass the reading, and an unmodelled effect leaves slow structure. Both the noise
floor's uncertainty and the fit's intervals need to know how many independent samples a
series holds, and the intervals need the correlation itself to weigh the Jacobian. An
autoregression of low order, chosen by AIC, describes both; its spectrum at zero frequency
is what slow quantities (a parameter of a step response, a variance) feel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_ORDER = 8
MAX_TAU = 1e4
"""Samples per independent sample, at most: a residual that wanders like a random walk
makes any finite record one sample, and the intervals then span what the search allowed."""


@dataclass
class AR:
    """e_t = sum_i phi_i e_(t-i) + u_t, var(u) = innovation_var."""

    phi: np.ndarray
    innovation_var: float
    variance: float

    @property
    def correlation_time(self) -> float:
        """Samples per independent sample for slow quantities: the spectrum at zero
        frequency over the variance (1 for white noise)."""
        if self.variance <= 0:
            return 1.0
        gain = 1.0 - float(self.phi.sum())
        if gain <= 1.0 / np.sqrt(MAX_TAU):
            return MAX_TAU
        return float(np.clip(self.innovation_var / (gain * gain) / self.variance, 1.0, MAX_TAU))

    def adjoint(self, x: np.ndarray) -> np.ndarray:
        """A^-T x along axis 0, where A is the whitening filter (e = A^-1 u): the
        autoregression run backwards in time, so that x' Sigma x = innovation_var
        |A^-T x|^2 for the series' covariance Sigma."""
        if not self.phi.size:
            return x
        # A^T is unit upper triangular with -phi_i on its i-th superdiagonal: LAPACK's banded
        # triangular solve is that backward recursion, without scipy.signal's import (half a
        # second, paid again by every forked worker that first needs it).
        from scipy.linalg.lapack import dtbtrs

        p = self.phi.size
        b = np.asarray(x, dtype=float).reshape(len(x), -1)
        band = np.empty((p + 1, b.shape[0]))
        band[:p] = -self.phi[::-1, None]
        band[p] = 1.0
        y, _ = dtbtrs(band, b, uplo="U", trans="N", diag="U")  # a unit diagonal: never singular
        return y.reshape(np.shape(x))


def acf(e: np.ndarray, lags: int) -> np.ndarray:
    """Sample autocorrelation of e at lags 0..lags (e's mean removed)."""
    e = e - e.mean()
    den = float(e @ e)
    if den <= 0:
        return np.r_[1.0, np.zeros(lags)]
    return np.array([1.0] + [float(e[k:] @ e[:-k]) / den if k < e.size else 0.0
                             for k in range(1, lags + 1)])


def fit_ar(e: np.ndarray, max_order: int = MAX_ORDER) -> AR:
    """Yule-Walker autoregression of e, order 0..max_order by AIC."""
    e = np.asarray(e, dtype=float)
    n = e.size
    var = float(np.mean((e - e.mean()) ** 2)) if n else 0.0
    if n < 10 or var <= 0:
        return AR(np.zeros(0), var, var)
    rho = acf(e, min(max_order, n // 5))
    best, best_phi, best_s2 = n * np.log(1.0), np.zeros(0), 1.0
    # Levinson-Durbin: each order's Yule-Walker solution from the one before, in one pass
    # (a Toeplitz solve per order cost ten times as much on a refit's residual series).
    phi, s2 = np.zeros(0), 1.0
    for p in range(1, rho.size):
        k = (rho[p] - phi @ rho[p - 1:0:-1]) / s2
        phi = np.r_[phi - k * phi[::-1], k]
        s2 = float(s2 * (1.0 - k * k))
        if not np.isfinite(s2) or s2 <= 1e-9:
            break
        aic = n * np.log(s2) + 2.0 * p
        if aic < best:
            best, best_phi, best_s2 = aic, phi, s2
    return AR(best_phi, best_s2 * var, var)

