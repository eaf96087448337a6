"""The residual's colour: autoregressions of known series, and the interval of a mean under
low-pass noise (the textbook case the fit's sandwich covariance must reproduce)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from furnace_model.identification.autoregression import AR, fit_ar
from furnace_model.identification.uncertainty import from_jacobian


def _ar1(phi: float, n: int, seed: int) -> np.ndarray:
    u = np.random.default_rng(seed).normal(0.0, 1.0, n)
    return lfilter([1.0], [1.0, -phi], u)


@pytest.mark.parametrize("phi", [0.0, 0.5, 0.9])
def test_an_autoregression_finds_the_correlation_time(phi):
    ar = fit_ar(_ar1(phi, 20000, 1))
    assert ar.correlation_time == pytest.approx((1 + phi) / (1 - phi), rel=0.15)


@pytest.mark.parametrize("phi", [[0.9], [1.2, -0.4], [0.5, 0.2, -0.1, 0.05, 0.1]])
def test_the_adjoint_is_the_whitening_filters_transpose_inverse(phi):
    """A^-T x against A written out: A is unit lower triangular, -phi_i on its i-th
    subdiagonal (u = A e), so a vector and every column of a matrix come out as
    solve(A^T, x), and x' Sigma x = innovation_var |A^-T x|^2 for Sigma = s2 A^-1 A^-T."""
    n, phi = 60, np.asarray(phi)
    A = np.eye(n)
    for i, p in enumerate(phi, start=1):
        A -= p * np.eye(n, k=-i)
    ar = AR(phi, 2.0, 3.0)
    rng = np.random.default_rng(len(phi))
    x, X = rng.normal(size=n), rng.normal(size=(n, 4))
    np.testing.assert_allclose(ar.adjoint(x), np.linalg.solve(A.T, x), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ar.adjoint(X), np.linalg.solve(A.T, X), rtol=1e-12, atol=1e-12)
    inv = np.linalg.inv(A)
    sigma = 2.0 * inv @ inv.T
    assert x @ sigma @ x == pytest.approx(2.0 * float(ar.adjoint(x) @ ar.adjoint(x)), rel=1e-10)


def test_white_noise_has_no_colour():
    ar = fit_ar(np.random.default_rng(2).normal(0.0, 2.0, 5000))
    assert ar.phi.size <= 1 and ar.correlation_time < 1.15


def test_the_interval_of_a_mean_allows_for_low_pass_noise():
    """A constant fitted to AR(1) noise: its variance is sigma^2 tau / n, not sigma^2 / n.
    Over 200 series the white interval misses far more than 5%, the coloured one does not."""
    phi, n = 0.8, 2000
    miss_white = miss_coloured = 0
    for seed in range(200):
        y = _ar1(phi, n, 100 + seed)
        mean = float(y.mean())
        J = np.ones((n, 1))
        unc = from_jacobian(J, y - mean, ["m"], np.array([False]), np.array([mean]),
                            [np.arange(n)])
        half_c = 1.96 * np.sqrt(unc.cov[0, 0])
        half_w = 1.96 * np.sqrt(unc.cov_white[0, 0])
        miss_coloured += abs(mean) > half_c
        miss_white += abs(mean) > half_w
    assert miss_white > 40  # about half the draws: the white interval is 3 times too narrow
    assert 2 <= miss_coloured <= 20
