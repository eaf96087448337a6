"""Exact derivatives of a linear system's zero-order-hold response with respect to its
matrices and input levels, from the same closed form the response is computed in.

With x' = A x + B u and a parameter p that moves A, B and the input levels (but not the
times the input steps at), the sensitivity s = dx/dp obeys s' = A s + A_p x + B_p u + B u_p.
In the eigenbasis of A (x = V zeta, s = V sigma, W = V^-1) that is

    sigma_i' = lam_i sigma_i + sum_j F_ij zeta_j + g_i,   F = W A_p V,  g = W (B_p u + B u_p),

and on a segment of constant input zeta_j = c_j exp(lam_j tau) + steady_j, so sigma is a
sum of the same exponentials: with G_ij = F_ij c_j / (lam_j - lam_i) (j != i) and
h = F steady + g,

    sigma_i(tau) = e_i (sigma_i(0) - sum_j G_ij + h_i / lam_i) + sum_j G_ij e_j
                   + F_ii c_i tau e_i - h_i / lam_i,          e_j = exp(lam_j tau).

No eigenvector derivative is needed, and one pass gives every parameter's column, where a
finite difference needs a simulation per column and is good to about the square root of
the rounding. Modes that (nearly) coincide, as the lags of several zones with one time
constant do, take the quotient's limit as a series (`_coefficients`).

A parameter that moves the instant s_k of a step du_k (a dead time, a fuel switch) moves
the input by -du_k ds_k/dp over an instant: an impulse, so sigma jumps by -W B du_k ds_k/dp
at s_k and decays from there as from any other segment's start.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .lti import Drive, Modes, carrier, segment_bounds, segment_starts

_BLOCK = 4096
"""Samples per block of the per-sample coefficient tables."""


class NoClosedForm(ValueError):
    """The system has no trustworthy eigenbasis (a defective A) or a mode too slow for the
    closed form: its derivatives must be taken otherwise."""


def response_sensitivity(A: np.ndarray, B: np.ndarray, C: np.ndarray, dA: np.ndarray,
                         dB: np.ndarray, drive: Drive, d_u0: np.ndarray | None,
                         d_du: np.ndarray | None, x0: np.ndarray, dx0: np.ndarray,
                         t0: float, t: np.ndarray, modes: Modes | None = None,
                         d_s: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The outputs' derivatives for one parameter set.

    A (n, n), B (n, m), C (q, n); dA (p, n, n) and dB (p, n, m) their derivatives with
    respect to p parameters; `drive` with shared step times (one set); d_u0 (p, m) and
    d_du (p, K, m) the derivatives of its levels (None: the levels do not move); x0 (n,)
    the state at t0 and dx0 (r, n) directions of it. Returns dy/dp (p, N, q) and dy/dx0
    along each direction (r, N, q). Raises NoClosedForm where `response` itself
    would leave the eigenbasis. `modes`: A's, when several records share it. d_s (p, K):
    the derivatives of the drive's step times (None: they do not move); a step at or
    before t0 is in the state there already, and moving it moves nothing.
    """
    t = np.asarray(t, dtype=float)
    modes = modes or Modes.of(A[None])
    lam, V, W = modes.lam[0], modes.V[0], modes.Vinv[0]
    n = lam.size
    cx = np.nonzero(np.imag(lam) != 0)[0]  # modes of conjugate pairs
    span = max(float(t[-1] - t0), 1.0) if t.size else 1.0
    if np.linalg.cond(V) > 1e9 or np.any(np.abs(lam) * span <= 1e-6):
        raise NoClosedForm("no closed form for this system")
    s = np.ravel(drive.s) if np.ndim(drive.s) == 1 or np.shape(drive.s)[0] == 1 else None
    if s is None:
        raise NoClosedForm("step times differ between parameter sets")
    p, m = dA.shape[0], B.shape[1]
    du = np.asarray(drive.du)[0]  # (K, m)
    u0 = np.asarray(drive.u0)[0]
    order, bounds, last = segment_bounds(s, t0)
    du = du[order]
    Kb = bounds.size
    U = _held(u0, du, last)  # (Kb, m)
    steady = -(U @ (W @ B).T) / lam  # (Kb, n)
    F = W @ dA @ V  # (p, n, n)
    # (p, Kb, n) each, as matrix products: a record in closed loop has thousands of segments
    driven = _rows_times(U, dB)
    if d_u0 is not None or d_du is not None:  # the levels move with the parameters
        d_u0 = np.zeros((p, m)) if d_u0 is None else d_u0
        d_du = (np.zeros((p,) + du.shape) if d_du is None else d_du)[:, order]
        driven = driven + _held(d_u0, d_du, last) @ B.T
    h = _rows_times(steady, F) + driven @ W.T
    gaps = np.diff(bounds)
    decay = _exp(lam[None, :] * gaps[:, None])  # (Kb-1, n)
    zeta = W @ np.asarray(x0, dtype=float)
    # one carrier for the state's starts and for sigma's: the exponentials are half a walk
    carry = carrier(lam[None], np.append(bounds, bounds[-1]), Kb)
    c = segment_starts(lam[None], zeta[None], steady[None], bounds, carry)[0] - steady  # (Kb, n)
    longest = max(float(gaps.max()) if gaps.size else 0.0,
                  float(t[-1] - bounds[-1]) if t.size else 0.0, 1e-300)
    coef = _coefficients(F, lam, c, h, longest)
    jump = None if d_s is None else _jumps(np.asarray(d_s, dtype=float)[:, order], du,
                                           W @ B, last)
    sig = np.zeros((p, Kb, n), np.result_type(coef.Fg, c, h))
    if Kb > 1:
        basis = _basis(lam, gaps, coef.M.shape[2]).reshape(Kb - 1, -1, n)
        step = (_summed(coef.M, slice(0, -1), basis)
                + coef.apart(decay * c[:-1]) + coef.const[:, :-1])
        if jump is not None:  # a segment's start jumped: the jump decays through it
            step = step + decay * jump[:, :-1]
        # sig[k + 1] = decay[k] sig[k] + step[k], in blocks
        sig = carry(np.concatenate([step, np.zeros_like(step[:, :1])], axis=1))
    if jump is not None:
        sig = sig + jump
    CVt = (C @ V).T  # (n, q)
    nb = coef.M.shape[2]
    q = C.shape[0]
    M = coef.M.copy()
    M[:, :, 0] += sig
    seg = np.searchsorted(bounds, t, side="right") - 1
    dy = np.empty((t.size, q, p))
    if Kb <= max(t.size // 16, 1):  # few long segments: a product each
        # dy = sum over the basis of its coefficients times C V, per segment; laid out
        # (basis, output, parameter) so that each segment is one matrix product
        out_M = np.einsum("pkbj,jq->kbjqp", M, CVt)
        G = coef.Fg[:, None] * c[None, :, None, :]  # (p, Kb, i, j): few segments here
        out_M[:, 0] += np.einsum("pkij,iq->kjqp", G, CVt)
        out_M = out_M.reshape(Kb, nb * n, q * p)
        out_c = np.einsum("pkj,jq->kqp", coef.const, CVt).reshape(Kb, q * p)
        real_M = _real_coefficients(out_M, out_c, cx, n)
        flat = dy.reshape(t.size, q * p)
        runs = np.searchsorted(seg, np.arange(Kb + 1))
        X = _real_basis(lam, t - bounds[seg], nb, cx)  # every sample's, in one pass
        for k in range(Kb):
            lo, hi = runs[k], runs[k + 1]
            if hi > lo:
                np.matmul(X[lo:hi], real_M[k], out=flat[lo:hi])
    else:  # many short ones (a furnace in closed loop): each sample's modal sensitivity
        for b0 in range(0, t.size, _BLOCK):
            blk = slice(b0, b0 + _BLOCK)
            k = seg[blk]
            X = _basis(lam, t[blk] - bounds[k], nb).reshape(-1, nb, n)  # (T, nb, n)
            sigma = (_summed(M, k, X) + coef.apart(c[k] * X[:, 0])
                     + np.take(coef.const, k, axis=1))
            dy[blk] = np.real(sigma @ CVt).transpose(1, 2, 0)
    free = _real_basis(lam, t - t0, 1, cx, constant=False)  # the response to the start
    start = np.asarray(dx0, dtype=float) @ W.T  # (r, n)
    dy0 = free @ _real_coefficients(
        np.einsum("rj,jq->jqr", start, CVt).reshape(n, -1), None, cx, n)
    return (dy.transpose(2, 0, 1),
            dy0.reshape(t.size, q, start.shape[0]).transpose(2, 0, 1))


def _summed(M: np.ndarray, k: np.ndarray | slice, X: np.ndarray) -> np.ndarray:
    """sum_b M[:, k, b] X[:, b] (p, T, n): segments k's coefficients (p, Kb, nb, n) at the
    basis X (T, nb, n) of each of their T instants. Written out over the few basis
    functions: einsum's general loop costs twice the products and their sum, and `take`
    gathers the segments' rows (a basis function at a time: no table of them all) at a
    third of what indexing them costs."""
    def rows(b: int) -> np.ndarray:
        return M[:, k, b] if isinstance(k, slice) else np.take(M[:, :, b], k, axis=1)
    out = rows(0) * X[:, 0]
    for b in range(1, X.shape[1]):
        out += rows(b) * X[:, b]
    return out


def _held(u0: np.ndarray, du: np.ndarray, last: np.ndarray) -> np.ndarray:
    """The level in force on each segment (..., Kb, m): u0 (..., m) plus the steps du
    (..., K, m), in time order, up to the segment's last (`segment_bounds`)."""
    if du.shape[-2] == 0:
        return np.broadcast_to(u0[..., None, :], u0.shape[:-1] + (last.size, u0.shape[-1]))
    summed = (u0[..., None, :] + np.cumsum(du, axis=-2))[..., np.maximum(last, 0), :]
    return np.where((last >= 0)[:, None], summed, u0[..., None, :])


def _jumps(d_s: np.ndarray, du: np.ndarray, WB: np.ndarray, last: np.ndarray
           ) -> np.ndarray | None:
    """sigma's jump at each segment's start (p, Kb, n) as its steps' instants move: d_s
    (p, K) and du (K, m) in time order, `last` the last step at or before each start
    (`segment_bounds`). None where no instant after the first start moves."""
    first = int(last[0]) + 1  # the steps before it are in the start state
    if last.size < 2 or not np.any(d_s[:, first:]):
        return None
    kick = -d_s[:, first:, None] * (du[first:] @ WB.T)[None]  # (p, steps after t0, n)
    jump = np.zeros((d_s.shape[0], last.size, WB.shape[0]), kick.dtype)
    # each start after the first holds the steps since the one before
    jump[:, 1:] = np.add.reduceat(kick, last[:-1] + 1 - first, axis=1)
    return jump


CLOSE = 1e-3
"""Modes whose rates differ by less than this over the longest segment are summed as one
mode with a polynomial factor: their difference quotient would cancel to rounding."""


@dataclass(frozen=True)
class _Coefficients:
    """sigma(tau) on segment k = sum_b M[k, b] basis_b(tau) + sum_j Fg_ij c_kj e_j(tau)
    + const[k], the basis being e, tau e and, where modes are close, tau^2 e, tau^3 e
    (elementwise in the modes); M[0] without sigma(0). The modes apart are kept as Fg and
    the segments' c apart: their product per segment, (p, segments, n, n), would be the
    largest table of a record whose input changes every minute, and is never needed whole."""

    M: np.ndarray  # (p, Kb, 2 or 4, n)
    Fg: np.ndarray  # (p, i, j): F_ij / (lam_j - lam_i) for modes apart, 0 for close ones
    const: np.ndarray  # (p, Kb, n)

    def apart(self, ce: np.ndarray) -> np.ndarray:
        """sum_j Fg_ij ce_j per row of ce (T, n): the modes apart, each e_j's share already
        in ce (c_j, or c_j times e_j at some tau). (p, T, n)."""
        return _rows_times(ce, self.Fg)


def _coefficients(F: np.ndarray, lam: np.ndarray, c: np.ndarray, h: np.ndarray,
                  longest: float) -> _Coefficients:
    """For modes apart, F_ij c_j (e_j - e_i) / (lam_j - lam_i); for modes close (a mode with
    itself, or the lags of several zones sharing one time constant), the same quotient as
    the series e_i (tau + d tau^2 / 2 + d^2 tau^3 / 6), d = lam_j - lam_i, which is exact to
    rounding while |d| tau stays under CLOSE."""
    n = lam.size
    gap = lam[None, :] - lam[:, None]  # (i, j): lam_j - lam_i
    close = np.abs(gap) * longest <= CLOSE
    Fg = np.where(close, 0.0, F / np.where(close, 1.0, gap))  # (p, i, j)
    near = np.where(close, F, 0.0)
    series = close.sum() > n  # modes close to others than themselves
    M = np.empty((F.shape[0], c.shape[0], 4 if series else 2, n), np.result_type(F, c, h))
    const = -h / lam
    M[:, :, 0] = -_rows_times(c, Fg) - const
    M[:, :, 1] = _rows_times(c, near)
    if series:
        M[:, :, 2] = _rows_times(c, near * gap) / 2.0
        M[:, :, 3] = _rows_times(c, near * gap * gap) / 6.0
    return _Coefficients(M, Fg, const)


def _rows_times(rows: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """sum_j Q_pij rows_kj: each row (K, j) through each of the p matrices, (p, K, i)."""
    return rows[None] @ Q.swapaxes(1, 2)


def _real_basis(lam: np.ndarray, tau: np.ndarray, nb: int, cx: np.ndarray,
                constant: bool = True) -> np.ndarray:
    """`_basis` as real columns (T, .): its real part, the imaginary part of the modes `cx`
    (the others' is zero), and with `constant` a column of ones. Times `_real_coefficients`
    it is the real part of the complex product, at a third of its arithmetic and without
    the complex result's passes (its real part and a constant added cost as much as the
    product itself). Built as its transpose, a column per row, and returned as a view of
    it: filled column by column, a row-major table would stride through memory at every
    write, which costs more than the arithmetic."""
    n, m = lam.size, cx.size
    out = np.empty((nb * (n + m) + int(constant), tau.size))
    re, im = out[:n], out[nb * n:nb * n + m]
    np.exp(np.maximum(np.real(lam)[:, None] * tau[None, :], FLOOR), out=re)
    if m:
        angle = np.imag(lam)[cx][:, None] * tau[None, :]
        np.multiply(re[cx], np.sin(angle), out=im)
        re[cx] *= np.cos(angle)
    for b in range(1, nb):
        power = tau ** b
        np.multiply(re, power, out=out[b * n:(b + 1) * n])
        np.multiply(im, power, out=out[nb * n + b * m:nb * n + (b + 1) * m])
    if constant:
        out[-1] = 1.0
    return out.T


def _real_coefficients(M: np.ndarray, const: np.ndarray | None, cx: np.ndarray, n: int
                       ) -> np.ndarray:
    """Coefficients (..., nb n, cols) of a basis of n modes, and a constant (..., cols), as
    the rows that `_real_basis`'s columns multiply: Re(X M + const) = real X @ these."""
    parts = [np.real(M)]
    if np.iscomplexobj(M) and cx.size:
        parts.append(-np.imag(M[..., _columns(cx, n, M.shape[-2] // n), :]))
    if const is not None:
        parts.append(np.real(const)[..., None, :])
    return np.concatenate(parts, axis=-2)


def _columns(cx: np.ndarray, n: int, nb: int) -> np.ndarray:
    """The columns of modes cx in a basis of nb blocks of n modes."""
    return (np.arange(nb)[:, None] * n + cx[None, :]).ravel()


def _basis(lam: np.ndarray, tau: np.ndarray, nb: int) -> np.ndarray:
    """e, tau e, tau^2 e, tau^3 e (the first nb) at each tau, flattened: (T, nb n)."""
    X = np.empty((tau.size, nb, lam.size), np.result_type(lam, float))
    X[:, 0] = _exp(lam[None, :] * tau[:, None])
    for b in range(1, nb):
        X[:, b] = tau[:, None] * X[:, b - 1]
    return X.reshape(tau.size, -1)


FLOOR = -600.0
"""exp() of anything lower is taken at this: e^-600 (1e-261) weighs nothing beside any
coefficient, while the subnormal numbers below e^-708 would slow every product they enter
by a hundredfold."""


def _exp(x: np.ndarray) -> np.ndarray:
    return np.exp(np.maximum(x.real, FLOOR) + 1j * x.imag) if np.iscomplexobj(x) else \
        np.exp(np.maximum(x, FLOOR))
