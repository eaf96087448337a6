"""What the data say about the fitted parameters: intervals, correlations, and which
combinations of parameters they actually pin down.

Everything is read off the Jacobian of the residual at the optimum, on the scale the search
uses (log for positive parameters), so an interval is symmetric in log and never crosses
zero. The paper's runs scatter d and e by a factor of four while d/e barely moves: that is a
flat valley of the SSE, and it shows here as a tiny eigenvalue of the Fisher information
whose eigenvector is about log d + log e. The well-determined eigen-directions are named as
readable combinations ("d/e") and the parameters moving along the flat ones are reported as
undetermined rather than given a confident value.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

from ..blas import held
from .autoregression import fit_ar

Z95 = 1.959963984540054
WIDE = 0.05
"""A 95% half-width above this (on the log scale: beyond about +-5%) is 'not determined'."""
STRONG_CORR = 0.99
_EPS = 1e-13


def within(interval: tuple[float, float], value: float) -> tuple[float, float]:
    """The interval widened to hold its own estimate: an estimate on its bound, taken to the
    parameter's units (exp of the log-scale bound), can land an ulp beyond the bound the
    interval is cut to, and a published value outside its own interval reads as a false one."""
    return min(interval[0], value), max(interval[1], value)


@dataclass
class Uncertainty:
    names: list[str]  # the fitted (free) parameters, in order
    log: np.ndarray  # (k,) bool: searched on the log scale
    z: np.ndarray  # (k,) estimate on that scale
    cov: np.ndarray  # (k, k) covariance on that scale, initial states marginalised out
    sigma: float  # residual standard deviation, degC
    eigvals: np.ndarray = field(default_factory=lambda: np.zeros(0))  # Fisher information
    eigvecs: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    cov_white: np.ndarray | None = None
    """The covariance were the residuals white: what the data would pin down under the
    model's own noise, the question a candidate effect's 'determined' asks."""
    correlation_time: float = 1.0
    """Samples per independent sample of the residual, the worst series'."""
    nuisance_sd: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """Standard deviations of the other unknowns (initial states, offsets), in order, with
    the residual's colour as `cov`."""

    @property
    def sd(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))

    @property
    def cov_own_units(self) -> np.ndarray:
        """The covariance in the parameters' own units, by the delta method: a parameter
        searched on the log scale, p = exp(z), moves by dp = p dz, so its row and column are
        scaled by p (its sd is p times its sd on the log scale). Linear where the intervals
        are not: an sd above about 0.3 of p says more about the log scale than about p."""
        p = np.where(self.log, np.exp(np.where(self.log, self.z, 0.0)), 1.0)
        return self.cov * np.outer(p, p)

    @property
    def corr(self) -> np.ndarray:
        sd = np.where(self.sd > 0, self.sd, 1.0)
        c = self.cov / np.outer(sd, sd)
        return np.clip(c, -1.0, 1.0)

    def ci95(self, lo: np.ndarray, hi: np.ndarray,
             white: bool = False) -> list[tuple[float, float]]:
        """Intervals in the parameters' own units, cut to the search box (an interval that
        reaches the box edge says: anywhere in the range the search was allowed) but never
        past the estimate (`within`); `white`: as if the residuals were white (`cov_white`)."""
        cov = self.cov_white if white and self.cov_white is not None else self.cov
        half = Z95 * np.sqrt(np.maximum(np.diag(cov), 0.0))
        a, b = self.z - half, self.z + half
        out = []
        for i in range(self.z.size):
            if self.log[i]:
                with np.errstate(over="ignore"):
                    pair = (float(np.exp(a[i])), float(np.exp(b[i])))
                value = float(np.exp(self.z[i]))
            else:
                pair = (float(a[i]), float(b[i]))
                value = float(self.z[i])
            out.append(within((max(pair[0], float(lo[i])), min(pair[1], float(hi[i]))), value))
        return out

    def undetermined(self, values: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> list[str]:
        half = Z95 * self.sd
        out = []
        for i, name in enumerate(self.names):
            if self.log[i]:
                wide = half[i] > WIDE
            else:
                wide = half[i] > max(WIDE * abs(values[i]), 0.01 * (hi[i] - lo[i]))
            if wide:
                out.append(name)
        return out

    def unseen(self, lo: np.ndarray, hi: np.ndarray) -> list[str]:
        """Parameters the data do not see at all: even were every other parameter known
        (the initial states still estimated), the 95% interval would span the search box.
        Not those that merely trade with another (d and e along d/e). Asked of the
        information under white residuals: whether the data see a parameter at all is a
        question of the records' excitation, not of the residual's colour."""
        if self.eigvals.size == 0:
            return []
        # The Fisher information's diagonal, from the covariance's eigen-decomposition. That
        # resolves eigenvalues only to about 1e-16 of the largest, which for a parameter the
        # data do not see is huge: below that a direction is as good as exact, and the
        # reciprocal of rounding noise would swamp every parameter's information (seen: a
        # heat per burner of a zone that never fired, called seen with a half-width of 1e-133).
        wc, Vc = np.linalg.eigh(self.cov_white if self.cov_white is not None else self.cov)
        info = (Vc ** 2) @ (1.0 / np.maximum(wc, 1e-14 * max(float(wc.max()), 1e-300)))
        half = Z95 / np.sqrt(np.maximum(info, 1e-300))
        zlo = np.where(self.log, np.log(np.maximum(lo, 1e-300)), lo)
        zhi = np.where(self.log, np.log(np.maximum(hi, 1e-300)), hi)
        return [n for i, n in enumerate(self.names)
                if self.z[i] - half[i] <= zlo[i] and self.z[i] + half[i] >= zhi[i]]

    def n_flat_directions(self) -> int:
        """Eigen-directions of the Fisher information the data leave wider than WIDE."""
        if self.eigvals.size == 0:
            return 0
        return int(np.sum(Z95 / np.sqrt(np.maximum(self.eigvals, 1e-300)) > WIDE))

    def combination_sd(self, coef: np.ndarray) -> float:
        return float(np.sqrt(max(coef @ self.cov @ coef, 0.0)))

    def determined_combinations(self, undetermined: list[str]) -> list[tuple[str, np.ndarray]]:
        """(name, coefficients on the log scale): the determined parameters alone, then
        readable products/ratios of undetermined log-scale parameters along the
        well-determined eigen-directions."""
        out = []
        for i, n in enumerate(self.names):
            if n not in undetermined:
                coef = np.zeros(len(self.names))
                coef[i] = 1.0
                out.append((n, coef))
        U = [i for i, n in enumerate(self.names) if n in undetermined and self.log[i]]
        if not U:
            return out
        found: list[np.ndarray] = []
        for i, j in combinations(U, 2):  # the simple ones first: ratios and products of two
            for sgn in (-1.0, 1.0):
                coef = np.zeros(len(self.names))
                coef[i], coef[j] = 1.0, sgn
                if Z95 * self.combination_sd(coef) <= WIDE:
                    found.append(coef)
        for w, v in zip(self.eigvals, self.eigvecs.T, strict=True):
            if Z95 / np.sqrt(max(w, 1e-300)) > WIDE:
                continue
            vu = np.zeros_like(v)
            vu[U] = v[U]
            if np.linalg.norm(vu) < 0.3:
                continue
            coef = np.round(2.0 * vu / np.abs(vu).max()) / 2.0
            if Z95 * self.combination_sd(coef) <= WIDE * np.abs(coef).max():
                found.append(coef)
        basis = np.array([c for _, c in out]).reshape(-1, len(self.names))
        for coef in found:
            trial = np.vstack([basis, coef])
            if np.linalg.matrix_rank(trial, tol=1e-8) == basis.shape[0]:
                continue  # already implied by the ones named
            basis = trial
            if coef[np.nonzero(coef)[0][0]] < 0:
                coef = -coef
            out.append((self.name_of(coef), coef))
        return out

    def combination_value(self, coef: np.ndarray) -> tuple[float, tuple[float, float]]:
        """Value and 95% interval of prod p_i^coef_i (a sum for linear-scale parameters)."""
        v = float(coef @ self.z)
        half = Z95 * self.combination_sd(coef)
        if np.all(self.log[coef != 0]):
            return float(np.exp(v)), (float(np.exp(v - half)), float(np.exp(v + half)))
        return v, (v - half, v + half)

    def name_of(self, coef: np.ndarray) -> str:
        """'d/e' for log d - log e, 'd*e' for the sum, 'd^0.5/e' for other weights."""
        if coef[np.nonzero(coef)[0][0]] < 0:
            coef = -coef

        def term(i: int) -> str:
            p = abs(coef[i])
            return self.names[i] if p == 1 else f"{self.names[i]}^{p:g}"

        num = [term(i) for i in range(coef.size) if coef[i] > 0]
        den = [term(i) for i in range(coef.size) if coef[i] < 0]
        text = "*".join(num) or "1"
        if den:
            text += "/" + (den[0] if len(den) == 1 else "(" + "*".join(den) + ")")
        return text

    def strong_correlations(self) -> list[tuple[str, str, float]]:
        c = self.corr
        return [(self.names[i], self.names[j], float(c[i, j]))
                for i, j in combinations(range(len(self.names)), 2)
                if abs(c[i, j]) > STRONG_CORR]


_GRAM_ROWS = 256
"""Rows per block of `gram`: small enough that OpenBLAS keeps each product on one thread."""


def gram(J: np.ndarray, blocked: bool = False) -> np.ndarray:
    """J'J. `blocked`: summed over blocks of rows unless BLAS is held to one thread already
    (`blas.one_thread`, as in every fit). A Jacobian with a few dozen columns (a network of
    many zones) crosses OpenBLAS's threshold for threads, and on a machine whose cores are
    busy its threads wait on each other, a hundred times slower than one thread. The blocks
    stay below the threshold, at a third more than the one product on one thread; the sum
    differs from the plain product by rounding."""
    if not blocked or held():
        return J.T @ J
    H = np.zeros((J.shape[1], J.shape[1]))
    for a in range(0, J.shape[0], _GRAM_ROWS):
        b = J[a:a + _GRAM_ROWS]
        H += b.T @ b
    return H


def from_jacobian(J: np.ndarray, residual: np.ndarray, names: list[str], log: np.ndarray,
                  z: np.ndarray, series: list[np.ndarray] | None = None,
                  blocked: bool = False) -> Uncertainty:
    """Linearised uncertainty of the first len(names) unknowns; the rest (initial states,
    offsets) are nuisance parameters, marginalised out. Flat directions get a huge but
    finite variance instead of being dropped by a pseudo-inverse (which would report them as
    exact).

    `series`: the residual's positions, one array per sensor series in time order. Each
    series then gets its own autoregression (its own variance and colour), and the
    covariance is the sandwich (J'J)^-1 J' Sigma J (J'J)^-1 under that noise: residuals that
    move together carry less information than as many independent ones, and intervals that
    assume white residuals exclude the truth (seen: b, c and f on a heat-up with low-pass
    thermocouples). Without `series` the residual is taken as white. `blocked`: as `gram`."""
    k = len(names)
    m, n = J.shape
    J = np.nan_to_num(J, nan=0.0, posinf=0.0, neginf=0.0)
    sigma2 = float(residual @ residual) / max(m - n, 1)
    JtJ = gram(J, blocked)
    d = np.diag(JtJ)
    scale = np.where(d > 0, np.sqrt(np.where(d > 0, d, 1.0)), 1.0)  # a dead column stays 0
    S = JtJ / np.outer(scale, scale)
    w, V = np.linalg.eigh((S + S.T) / 2)
    clipped = w < _EPS * max(float(w.max()), 1.0)
    w = np.maximum(w, _EPS * max(float(w.max()), 1.0))
    white = sigma2 * (V / w) @ V.T / np.outer(scale, scale)
    cov, tau = white, 1.0
    if series:
        meat = np.zeros((n, n))
        dof = m / max(m - n, 1)
        for idx in series:
            if idx.size < 2:
                continue
            ar = fit_ar(residual[idx])
            tau = max(tau, ar.correlation_time)
            B = ar.adjoint(J[idx] / scale)
            meat += dof * ar.innovation_var * gram(B, blocked)
        # In the eigenbasis of the scaled J'J: W^-1 V' M V W^-1. A direction the data do not
        # see at all (clipped) keeps the white variance, huge: the sandwich would multiply
        # two roundings there.
        inner = (V.T @ meat @ V) / np.outer(w, w)
        inner[clipped, :] = 0.0
        inner[:, clipped] = 0.0
        inner[clipped, clipped] = sigma2 / w[clipped]
        cov = V @ inner @ V.T / np.outer(scale, scale)
    cov_p = (cov[:k, :k] + cov[:k, :k].T) / 2
    # Directions on the parameters' (log) scale: the covariance's eigenvectors are those of
    # the Fisher information, its eigenvalues the reciprocals.
    wc, Vc = np.linalg.eigh(cov_p) if k else (np.zeros(0), np.zeros((0, 0)))
    fisher_w = 1.0 / np.maximum(wc, 1e-300)
    order = np.argsort(fisher_w)
    return Uncertainty(list(names), np.asarray(log, dtype=bool), np.asarray(z, dtype=float),
                       cov_p, float(np.sqrt(sigma2)), fisher_w[order], Vc[:, order],
                       (white[:k, :k] + white[:k, :k].T) / 2, tau,
                       np.sqrt(np.maximum(np.diag(cov)[k:], 0.0)))
