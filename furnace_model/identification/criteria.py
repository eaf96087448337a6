"""Information criteria of a fit, as System Identification Toolbox defines them for a model
with several outputs (its `aic` and `fpe`): the three zone temperatures are the outputs.

With e(t) the vector of the three zone residuals at sample t, N samples and the residual
covariance V = det(1/N sum e e'), MATLAB writes

    AIC  = N log V + 2 np + N ny (log 2 pi + 1)       (-2 log L + 2 np, Gaussian errors)
    AICc = AIC + 2 np (np + 1) / (N - np - 1)
    BIC  = N log V + N ny (log 2 pi + 1) + np log N
    nAIC = log V + 2 np / N
    FPE  = V (1 + np/N) / (1 - np/N)

so that the numbers here are the ones an engineer would get there for the same residuals
and parameter count. Readings may be missing here, which MATLAB's data cannot be: -2 log L
is then the Gaussian likelihood of the readings present (each sample's present zones with
their block of the covariance, estimated from the pairs present), and N counts readings
divided by the number of outputs. With every reading present both are MATLAB's formulas.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True)
class Criteria:
    aic: float
    aicc: float
    bic: float
    naic: float
    fpe: float  # in the outputs' units to the power ny (°C^6 for three zones)
    n_params: int  # np: every estimated unknown (parameters, initial states, offsets)
    n_samples: float  # N
    loss: float  # V = det of the residual covariance


def criteria(residuals: np.ndarray, n_params: int) -> Criteria:
    """Criteria of residuals (N, ny), NaN where a reading is missing, for np = n_params."""
    e = np.asarray(residuals, dtype=float)
    present = np.isfinite(e)
    ny = e.shape[1]
    n = float(present.sum()) / ny
    e0 = np.where(present, e, 0.0)
    pairs = present.T.astype(float) @ present
    with np.errstate(invalid="ignore", divide="ignore"):
        cov = (e0.T @ e0) / pairs
    sign, logdet = np.linalg.slogdet(cov) if np.all(np.isfinite(cov)) else (0.0, np.nan)
    if sign <= 0 or n <= 0:
        nan = float("nan")
        return Criteria(nan, nan, nan, nan, nan, n_params, n, nan)
    m2ll = 0.0  # -2 log L
    # The patterns of present readings, each row's as one integer: np.unique over rows
    # (axis=0) sorts them as records, a few ms a call on a refit window.
    codes = present.astype(np.int64) @ (1 << np.arange(ny, dtype=np.int64)) if ny < 63 \
        else np.unique(present, axis=0, return_inverse=True)[1].ravel()
    kinds, first, which = np.unique(codes, return_index=True, return_inverse=True)
    for p in range(kinds.size):
        pattern = present[first[p]]
        if not pattern.any():
            continue
        rows = e[which == p][:, pattern]
        block = cov[np.ix_(pattern, pattern)]
        _, ld = np.linalg.slogdet(block)
        quad = np.einsum("ti,ij,tj->", rows, np.linalg.inv(block), rows)
        m2ll += rows.shape[0] * (pattern.sum() * LOG_2PI + ld) + quad
    k = float(n_params)
    aic = m2ll + 2.0 * k
    aicc = aic + 2.0 * k * (k + 1.0) / (n - k - 1.0) if n - k - 1.0 > 0 else float("nan")
    fpe = float(np.exp(logdet)) * (1.0 + k / n) / (1.0 - k / n) if k < n else float("nan")
    return Criteria(aic=float(aic), aicc=float(aicc), bic=float(m2ll + k * np.log(n)),
                    naic=float(logdet + 2.0 * k / n), fpe=fpe, n_params=int(n_params),
                    n_samples=n, loss=float(np.exp(logdet)))
