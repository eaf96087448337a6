"""Exact response of linear time-invariant systems to piecewise-constant inputs, batched.

The furnace model is linear in its state for every effect but radiation, and its inputs
(burner counts, ambient temperature) change only in steps. Between steps the solution is
closed-form in the eigenbasis of A, so it is evaluated exactly at the sample times instead of
integrated: no step-size error, no loop over parameter sets, and a cost set by the number of
samples rather than by the stiffness of the preheating zone (its time constant is under a
minute). A is similar to a symmetric matrix for the RC network of the paper, so its
eigenvalues are real; complex ones (possible in some extended structures) are handled too.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm


@dataclass(frozen=True)
class Drive:
    """Piecewise-constant input in increment form: u(t) = u0 + sum_k du_k * H(t - s_k).

    Increments let an effect shift or add steps per parameter set (a fitted dead time, a fuel
    change at a fitted instant) by concatenation, without re-sorting a shared time axis.
    `s` is shared, shape (K,), or per parameter set, shape (P, K); `u0` is (P|1, m) and `du`
    is (P|1, K, m). `u0` holds from `t0`, and before it too.
    """

    t0: float
    u0: np.ndarray
    s: np.ndarray
    du: np.ndarray

    @classmethod
    def from_levels(cls, t: np.ndarray, u: np.ndarray) -> Drive:
        """Levels u[:, j] hold from t[j] until t[j+1]; t ascending, u shaped (P|1, J, m)."""
        t = np.asarray(t, dtype=float)
        u = np.asarray(u, dtype=float)
        if u.ndim == 2:
            u = u[None]
        return cls(float(t[0]), u[:, 0], t[1:], np.diff(u, axis=1))

    def level_at(self, t: float) -> np.ndarray:
        """The input in force at time t (increments at exactly t included), shape (P|1, m)."""
        on = np.asarray(self.s <= t, dtype=float)
        if on.ndim == 1:
            return self.u0 + np.einsum("k,pkm->pm", on, self.du)
        return self.u0 + np.einsum("pk,pkm->pm", on, self.du)

    def levels_at(self, times: np.ndarray, p: int | None = None) -> np.ndarray:
        """`level_at` for many times at once, (P|1, T, m), or (1, T, m) of parameter set p
        alone: one cumulative sum of the steps instead of a pass over them per time (per
        set where each has its own steps: a record whose input moves every minute has as
        many steps as times)."""
        if p is None and self.s.ndim == 1:
            return _levels(self.s, self.du, self.u0, times)
        if p is None:
            return np.concatenate([self.levels_at(times, q) for q in range(self.s.shape[0])])
        i, j = min(p, self.du.shape[0] - 1), min(p, self.u0.shape[0] - 1)
        return _levels(self.s if self.s.ndim == 1 else self.s[p], self.du[i:i + 1],
                       self.u0[j:j + 1], times)

    def breakpoints(self, p: int = 0) -> np.ndarray:
        """Sorted distinct step times of parameter set p."""
        s = self.s if self.s.ndim == 1 else self.s[p]
        return np.unique(s)


def _levels(s: np.ndarray, du: np.ndarray, u0: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Levels (P|1, T, m) at `times` of steps du (P|1, K, m) at s (K,) from u0 (P|1, m)."""
    order = np.argsort(s, kind="stable")
    summed = np.cumsum(du[:, order], axis=1)
    k = np.searchsorted(s[order], times, side="right")
    summed = np.concatenate([np.zeros((summed.shape[0], 1, summed.shape[2])), summed], axis=1)
    return u0[:, None] + summed[:, k]


@dataclass(frozen=True)
class Modes:
    """Eigen-decomposition of a batch of A matrices, reused across experiments in a fit."""

    lam: np.ndarray  # (P, n)
    V: np.ndarray  # (P, n, n)
    Vinv: np.ndarray  # (P, n, n)

    @classmethod
    def of(cls, A: np.ndarray) -> Modes:
        lam, V = np.linalg.eig(A)
        if np.iscomplexobj(lam):
            scale = np.maximum(np.abs(lam).max(axis=-1, keepdims=True), 1e-300)
            if np.all(np.abs(lam.imag) <= 1e-12 * scale):
                lam, V = lam.real, V.real
        return cls(lam, V, np.linalg.inv(V))


def _propagators(lam: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """exp(lam*tau) and (exp(lam*tau) - 1)/lam (tau where lam == 0), by broadcasting."""
    em1 = np.expm1(lam * tau)
    if np.any(lam == 0):
        with np.errstate(divide="ignore", invalid="ignore"):
            phi = np.where(lam == 0, tau, em1 / np.where(lam == 0, 1, lam))
    else:
        phi = em1 / lam
    return em1 + 1.0, phi


def response(A: np.ndarray, B: np.ndarray, x_start: np.ndarray, t_start: float, drive: Drive,
             t: np.ndarray, C: np.ndarray | None = None,
             modes: Modes | None = None) -> np.ndarray:
    """States (or outputs C x) at times t of x' = A x + B u(t), x(t_start) = x_start.

    A (P, n, n), B (P, n, m), x_start (P|1, n), t (N,) ascending and >= t_start,
    C (q, n) or (P, q, n). Returns (P, N, n) or (P, N, q). Increments of the drive at or
    before t_start are folded into the input in force at t_start.
    """
    t = np.asarray(t, dtype=float)
    if t.size and t[0] < t_start:
        raise ValueError(f"sample time {t[0]} precedes the start time {t_start}")
    modes = modes or Modes.of(A)
    lam, V, Vinv = modes.lam, modes.V, modes.Vinv
    P, n = lam.shape
    x_start = np.broadcast_to(np.asarray(x_start, dtype=float), (P, n))
    Bm = Vinv @ B  # modal input matrix (P, n, m)
    z = np.einsum("pij,pj->pi", Vinv, x_start)
    w = np.einsum("pim,pm->pi", Bm, np.broadcast_to(drive.u0, (P, drive.u0.shape[-1])))
    du = np.broadcast_to(drive.du, (P,) + drive.du.shape[1:])
    dw = np.einsum("pim,pkm->pki", Bm, du)  # (P, K, n)
    s = np.maximum(drive.s, t_start)
    out = V if C is None else np.asarray(C) @ V  # (P, q, n)
    span = max(float(t[-1] - t_start), 1.0) if t.size else 1.0
    if s.ndim == 1 and np.all(np.abs(lam) * span > 1e-6):
        Y = _segments(lam, out, z, w, s, dw, t_start, t)
    else:
        Y = out @ _superposed(lam, z, w, s, dw, t_start, t)
    if np.iscomplexobj(Y):  # conjugate modes sum to a real response
        Y = Y.real
    Y = np.swapaxes(Y, 1, 2)
    # A (nearly) defective A -- a lag whose time constant coincides with a furnace mode --
    # has no trustworthy eigenbasis; those parameter sets take the slow, sure path.
    defective = np.nonzero(np.linalg.cond(V) > 1e9)[0]
    for p in defective:
        xs = _stepwise(A[p], B[p], x_start[p], t_start, drive, p, t)
        Y[p] = xs if C is None else xs @ np.asarray(C if np.ndim(C) == 2 else C[p]).T
    return Y


def _stepwise(A, B, x, t_start, drive, p, t):
    """States at t by matrix exponentials of [[A, B], [0, 0]] over each interval between
    samples and input steps: exact for any A, one parameter set at a time."""
    n, m = B.shape
    s = np.maximum(drive.s if drive.s.ndim == 1 else drive.s[p], t_start)
    du = drive.du[min(p, drive.du.shape[0] - 1)]
    order = np.argsort(s, kind="stable")
    s, levels = s[order], drive.u0[min(p, drive.u0.shape[0] - 1)] + np.cumsum(du[order], axis=0)
    events = np.unique(np.concatenate(([t_start], s[s > t_start], t)))
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    cache: dict[float, np.ndarray] = {}
    out = np.empty((t.size, n))
    k = 0
    for a, b in zip(events[:-1], events[1:], strict=True):
        while k < t.size and t[k] == a:
            out[k] = x
            k += 1
        j = np.searchsorted(s, a, side="right") - 1
        u = drive.u0[min(p, drive.u0.shape[0] - 1)] if j < 0 else levels[j]
        h = float(b - a)
        if h not in cache:
            cache[h] = expm(M * h)
        E = cache[h]
        x = E[:n, :n] @ x + E[:n, n:] @ u
    out[k:] = x
    return out


_BLOCK = 256
"""Parameter sets per block: keeps a block's (n, N) work arrays in cache."""


def segment_bounds(s: np.ndarray, t_start: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shared step times s (K,) as constant-input segments from t_start: the order that
    sorts s (stable), each segment's start (t_start, then every distinct step time after
    it) and the sorted steps' index of the last one in force there (-1: none). A record's
    step times come sorted and mostly distinct; with an input change every sample this is
    called with every simulation, so the distinct times are read off the sorted array
    instead of sorted again."""
    order = np.argsort(s, kind="stable")
    s = s[order]
    distinct = s[np.concatenate(([True], s[1:] != s[:-1]))] if s.size else s
    bounds = np.concatenate(([t_start], distinct[distinct > t_start]))
    return order, bounds, np.searchsorted(s, bounds, side="right") - 1


def _segments(lam, out, z, w, s, dw, t_start, t):
    """Shared step times: walk the constant-input segments in order, exact within each.

    On a segment with modal input w, z(tau) = (z0 + w/lam) exp(lam tau) - w/lam, so the
    output is G exp(lam tau) + H with per-segment constants G, H.
    """
    order, bounds, last_idx = segment_bounds(s, t_start)
    dw = dw[:, order]
    w_after = w[:, None, :] + np.cumsum(dw, axis=1)  # modal input after step k
    P, q = out.shape[0], out.shape[1]
    seg_of = np.searchsorted(bounds, t, side="right") - 1
    cells = lam.shape[1] * t.size
    if P * cells <= _DIRECT_CELLS:
        return _direct(lam, out, z, w, w_after, bounds, last_idx, seg_of, t)
    if P * cells < bounds.size * (_WALK_SEGMENT_CELLS + _WALK_MODE_CELLS * lam.size):
        c = max(1, _CHUNK_CELLS // cells)
        return np.concatenate([_direct(lam[p:p + c], out[p:p + c], z[p:p + c], w[p:p + c],
                                       w_after[p:p + c], bounds, last_idx, seg_of, t)
                               for p in range(0, P, c)])
    pieces = []
    for k, b in enumerate(bounds):
        wk = w if last_idx[k] < 0 else w_after[:, last_idx[k]]
        lo, hi = np.searchsorted(seg_of, [k, k + 1])
        steady = -wk / lam
        if hi > lo:
            G = out * (z - steady)[:, None, :]  # (P, q, n)
            pieces.append((lo, hi, t[lo:hi] - b, G, np.einsum("pqn,pn->pq", out, steady)))
        if k + 1 < bounds.size:
            z = (z - steady) * np.exp(lam * (bounds[k + 1] - b)) + steady
    Y = np.empty((P, q, t.size))
    for p0 in range(0, P, _BLOCK):
        blk = slice(p0, p0 + _BLOCK)
        for lo, hi, tau, G, H in pieces:
            Y[blk, :, lo:hi] = _modal_sum(lam[blk], tau, G[blk], H[blk])
    return Y


def segment_starts(lam: np.ndarray, z: np.ndarray, steady: np.ndarray, bounds: np.ndarray,
                   carry: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """Modal states (P, K, n) at each segment's start `bounds` (K,), from z (P, n) at the
    first, with the state settling toward steady[:, k] (P, K, n) on segment k:
    z_(k+1) = e^(lam d_k) z_k + (1 - e^(lam d_k)) steady_k, in blocks (`carried`).
    `carry`: `carrier(lam, bounds and its last again, K)`, where the caller carries other
    contributions over the same segments too."""
    ends = np.append(bounds, bounds[-1])
    fade = -np.expm1(lam[:, None, :] * np.diff(ends)[None, :, None])
    carry = carry or carrier(lam, ends, bounds.size)
    return (carry(fade * steady)
            + np.exp(lam[:, None, :] * (bounds - bounds[0])[None, :, None]) * z[:, None])


def _starts_and_steady(lam, z, w, w_after, bounds, last_idx):
    """(K, P, n) each segment's start less its steady state, and the steady state."""
    inputs = np.concatenate([w[:, None], w_after], axis=1)  # (P, 1 + steps, n)
    steady = -inputs[:, last_idx + 1] / lam[:, None]  # (P, K, n)
    states = segment_starts(lam, z, steady, bounds)
    return np.moveaxis(states - steady, 1, 0), np.moveaxis(steady, 1, 0)


def _direct(lam, out, z, w, w_after, bounds, last_idx, seg_of, t):
    """`_segments` for a few parameter sets: every sample's modal state at once, from its
    segment's start and steady state, then one matrix product, instead of a table product
    per segment. A refit's simulations are of one to a dozen sets over a day of samples with
    a burner change every hour or two: there the per-segment calls cost more than their
    arithmetic."""
    start, steady = _starts_and_steady(lam, z, w, w_after, bounds, last_idx)
    tau = t - bounds[seg_of]
    # laid out (P, n, N), samples last: the product below then reads each set's table as it
    # lies, where a samples-first table is copied into that order first. The samples are in
    # time order: each segment's values repeated over its run of them, not gathered.
    lo = int(seg_of[0]) if seg_of.size else 0
    runs = np.bincount(seg_of - lo)
    start, steady = (np.repeat(np.moveaxis(x, 0, -1)[..., lo:lo + runs.size], runs, axis=-1)
                     for x in (start, steady))  # (P, n, N)
    modal = start * np.exp(lam[..., None] * tau) + steady
    Y = out @ modal  # (P, q, N)
    return Y.real if np.iscomplexobj(Y) else Y


CARRY_SPAN = 500.0
"""The most a mode may decay (in e-folds) within one block of `carried`: e^500 and e^-500
are far inside a float's range, so a block's scaled sums neither overflow nor go
subnormal."""
CARRY_GONE = 60.0
"""A step over which a mode decays by more than this many e-folds (e^-60, 1e-26) leaves of
what came before nothing a double can hold beside what the step adds: `carried` counts such
a step as this long, so that one long step (or a mode of a second on minute samples) does
not shorten every block."""
CARRY_BLOCK_MAX = 256
"""The longest block of `carried` (slow modes): its arrays stay a few times the input's."""
CARRY_SHORT = 16
"""Steps up to which `carrier` takes its recursion step by step: a heat-up's few burner
changes cost less so than as blocks, whose tables cost as much as a dozen steps."""
CARRY_LOOP = 64
"""Blocks of `carried` beyond which their loop costs more than clamping the steps does."""


def carried(lam: np.ndarray, T: np.ndarray, c: np.ndarray) -> np.ndarray:
    """sig (P, K, n) with sig[0] = 0 and sig[k] = e^(lam (T[k] - T[k-1])) sig[k-1] + c[k-1]:
    what steps starting at T[:K] (T[K] the last one's end) carry from one to the next, per
    mode lam (P, n), for contributions c (P, K, n); T ascending. lam (1, n): the same modes
    for every row of c (one system's sensitivities to P parameters), whose exponentials are
    then taken once, not once per row. `carrier` for many c over the same modes and times."""
    return carrier(lam, T, c.shape[1])(c)


def carrier(lam: np.ndarray, T: np.ndarray, K: int) -> Callable[[np.ndarray], np.ndarray]:
    """`carried` over K steps for many contributions against the same modes and times: a
    waveform relaxation's sweeps change the contributions only, and the exponentials are
    nearly half of a walk's cost.

    Why blocks: a step-by-step loop over thousands of steps (a furnace in closed loop
    changes its burners every minute) costs more than all the arithmetic. Within a block,
    e^(lam (T[k] - T[j+1])) = E_k / E_(j+1) with E_k the mode's decay from the block's start
    to T[k], so the block's sums are E_k times a cumulative sum of c[j] / E_(j+1): each term
    keeps its relative precision, and a block is short enough (CARRY_SPAN e-folds of its
    fastest mode) that 1 / E never overflows. Only what each block hands the next is a loop.
    Where that would make more than CARRY_LOOP blocks (a step much longer than the others, or
    a sensor lag of seconds on minute samples), `_clamped_carrier` takes them instead."""
    T = np.asarray(T, dtype=float)
    gaps = np.diff(T[:K + 1])
    if K <= CARRY_SHORT:
        return _stepped_carrier(lam, gaps)
    L = _block_length(float(np.max(np.abs(np.real(lam)), initial=0.0))
                      * float(np.max(gaps, initial=0.0)))
    if -(-K // L) > CARRY_LOOP:
        return _clamped_carrier(lam, T, K)
    nb = -(-K // L)
    Tp = np.concatenate([T[:K + 1], np.full(nb * L - K, T[K])])  # nb * L + 1 times
    first = Tp[0:nb * L:L]  # each block's start
    at = Tp[:-1].reshape(nb, L) - first[:, None]  # T[k] - T0, k in the block
    after = Tp[1:].reshape(nb, L) - first[:, None]  # T[j+1] - T0
    lam4 = lam[:, None, None, :]
    span = Tp[L::L] - first  # (nb,)
    walk = _blocks(np.exp(lam4 * at[None, :, :, None]),
                   np.exp(-lam4 * after[None, :, :, None]) if L > 1 else None,
                   np.exp(lam[:, None, :] * span[None, :, None]),
                   np.exp(lam4 * (span[:, None] - after)[None, :, :, None]))
    return lambda c: walk(_in_rows_of(c, L))[:, :K]


def _stepped_carrier(lam: np.ndarray, gaps: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """`carrier` as its recursion, step by step (`CARRY_SHORT`); a step's decay counted at
    most CARRY_GONE e-folds, as `_clamped_carrier` counts it, so that no product goes
    subnormal."""
    steps = lam[:, None, :] * gaps[None, :, None]  # (P|1, K, n)
    decay = np.exp(np.maximum(np.real(steps), -CARRY_GONE)
                   + (1j * np.imag(steps) if np.iscomplexobj(steps) else 0.0))

    def carry(c: np.ndarray) -> np.ndarray:
        out = np.zeros(c.shape, np.result_type(c, decay))
        for k in range(1, c.shape[1]):
            out[:, k] = decay[:, k - 1] * out[:, k - 1] + c[:, k - 1]
        return out
    return carry


def _block_length(fastest: float) -> int:
    """Steps per block of `carried` whose fastest mode decays by `fastest` e-folds a step."""
    return int(np.clip(CARRY_SPAN // fastest if fastest > 0 else CARRY_BLOCK_MAX, 1,
                       CARRY_BLOCK_MAX))


def _in_rows_of(x: np.ndarray, L: int) -> np.ndarray:
    """x (P, K, n) as blocks (P, nb, L, n), the last padded with zeros."""
    P, K, n = x.shape
    nb = -(-K // L)
    return np.concatenate([x, np.zeros((P, nb * L - K, n), dtype=x.dtype)],
                          axis=1).reshape(P, nb, L, n)


def _blocks(E: np.ndarray, rise: np.ndarray | None, to_end: np.ndarray, fall: np.ndarray
            ) -> Callable[[np.ndarray], np.ndarray]:
    """`carried` on blocks (P, nb, L, n) of contributions, given each mode's decay from its
    block's start to each step's start (E), the inverse of that to each step's end (rise,
    needed only for blocks longer than a step), to the block's end (to_end, (P|1, nb, n)),
    and from each step's end to the block's end (fall): E_k times the cumulative sum of
    c[j] / E_(j+1), and what each block hands the next (its exponents never positive)."""
    def walk(cp: np.ndarray) -> np.ndarray:
        P, nb, L, n = cp.shape
        inner = np.zeros(cp.shape, np.result_type(cp, E))
        if L > 1:  # sums over j < k: the cumulative sum shifted by one within the block
            summed = np.cumsum(cp * rise, axis=2)
            inner[:, :, 1:] = E[:, :, 1:] * summed[:, :, :-1]
        handed = np.sum(cp * fall, axis=2)
        S = np.empty((P, nb, n), dtype=inner.dtype)
        S[:, 0] = 0.0
        for b in range(1, nb):
            S[:, b] = to_end[:, b - 1] * S[:, b - 1] + handed[:, b - 1]
        return (E * S[:, :, None, :] + inner).reshape(P, nb * L, n)
    return walk


def _clamped_carrier(lam: np.ndarray, T: np.ndarray, K: int
                     ) -> Callable[[np.ndarray], np.ndarray]:
    """`carrier` with each step counted at most CARRY_GONE e-folds long, and a mode that
    forgets everything at every step carrying each step's contribution alone: neither then
    sets the blocks' length. Slower per element than `carrier`'s own blocks (each mode's
    exponents are summed step by step), so taken only where those blocks would be many."""
    steps = lam[:, None, :] * np.diff(T[:K + 1])[None, :, None]  # (P|1, K, n) exponents
    decay = np.maximum(np.real(steps), -CARRY_GONE)
    gone = np.all(decay <= -CARRY_GONE, axis=1) if K else np.zeros(lam.shape, dtype=bool)
    decay = np.where(gone[:, None, :], 0.0, decay)
    steps = decay + 1j * np.imag(steps) if np.iscomplexobj(steps) else decay
    L = _block_length(float(np.max(-decay, initial=0.0)))
    # each block's exponents from its start: to the end of step j (after), to its start (at)
    after = np.cumsum(_in_rows_of(steps, L), axis=2)
    at = np.concatenate([np.zeros_like(after[:, :, :1]), after[:, :, :-1]], axis=2)
    span = after[:, :, -1]
    walk = _blocks(np.exp(at), np.exp(-after) if L > 1 else None, np.exp(span),
                   np.exp(span[:, :, None] - after))

    def carry(c: np.ndarray) -> np.ndarray:
        out = walk(_in_rows_of(c, L))[:, :K]
        if gone.any():  # what each step adds, and nothing of before
            alone = np.concatenate([np.zeros_like(c[:, :1]), c[:, :-1]], axis=1)
            out = np.where(gone[:, None, :], alone, out)
        return out
    return carry


_DIRECT_CELLS = 100_000
"""Parameter sets x states x samples up to which `_direct` is the cheaper walk."""
_CHUNK_CELLS = 1_000_000
"""Sets x states x samples of one chunk of `_direct` where segments are many (a furnace in
closed loop): one chunk's work arrays stay within tens of MB."""
_WALK_SEGMENT_CELLS = 1400
_WALK_MODE_CELLS = 10
"""What the walk over segments costs beyond its tables, in the direct way's cells (sets x
modes x samples, one exponential each, about 20 ns): about 28 us per segment, and 0.2 us
per segment for each set and mode (`bench/bench_simulate.py --segments`). Many short
segments (hourly inputs on a grid of minutes, a closed-loop record) go the direct way;
long ones keep the tables, whose exponentials are a few per segment."""


def _modal_sum(lam: np.ndarray, tau: np.ndarray, G: np.ndarray, H: np.ndarray) -> np.ndarray:
    """sum_i G[p, q, i] exp(lam[p, i] tau) + H[p, q], shaped (P, q, N), as matrix products.

    On a regular grid tau = tau0 + h (L m + l), exp(lam tau) factors into a coarse table over
    m and a fine one over l, so the sum for each (p, q) is one (M x n+1) @ (n+1 x L) product:
    about 2 sqrt(N) exponentials instead of N, and no pass of numpy's slow narrow broadcasts.
    The constant H rides along as an extra column of ones.
    """
    N = tau.size
    d = np.diff(tau)
    if N > 16 and d[0] > 0 and np.ptp(d) <= 1e-12 * d[0] * N:
        L = int(np.ceil(np.sqrt(N)))
        M = -(-N // L)
        head, tail = tau[0] + d[0] * L * np.arange(M), d[0] * np.arange(L)
    else:
        L, M, head, tail = 1, N, tau, np.zeros(1)
    P, n = lam.shape
    dtype = np.result_type(lam, G, H, float)  # complex modes (a network with a cycle)
    coarse = np.ones((P, 1, M, n + 1), dtype)
    coarse[:, 0, :, :n] = np.exp(lam[:, None, :] * head[:, None])
    F = np.empty((P, G.shape[1], n + 1, L), dtype)
    F[:, :, :n, :] = G[..., None] * np.exp(lam[:, :, None] * tail)[:, None]
    F[:, :, n, :] = H[:, :, None]
    out = (coarse @ F).reshape(P, G.shape[1], M * L)[:, :, :N]
    return out.real if np.iscomplexobj(out) else out


def _superposed(lam, z, w, s, dw, t_start, t):
    """Per-parameter step times (a fitted dead time or fuel-change instant).

    With steady = -w/lam the modal state is (z - steady) exp(lam tau) + steady, and a step
    dw at s adds (dw/lam)(exp(lam (t - s)) - 1) from s on. Both are a constant part plus an
    exponential that starts at the first sample on or after its step time: an impulse into
    the first-order recursion y_i = exp(lam (t_i - t_{i-1})) y_{i-1} + impulse_i, whose size
    carries the fraction of a sample period between the step and that sample. The recursion
    runs in blocks (`_in_sample_blocks`, or for many steps `_summed_per_sample`), so a call
    costs a few passes over the (P, n, N) result instead of one exponential per sample and
    step. Parameter sets with a (numerically) zero eigenvalue, where dw/lam does not exist,
    are walked one at a time (`_walked`).
    """
    P, n = lam.shape
    if s.ndim == 1:
        s = np.broadcast_to(s, (P, s.size))
    span = max(float(t[-1] - t_start), 1.0) if t.size else 1.0
    flat = np.any(np.abs(lam) * span <= 1e-6, axis=1)
    dtype = np.result_type(lam, z, w, dw, float)
    Z = np.empty((P, n, t.size), dtype)
    for p in np.nonzero(flat)[0]:
        Z[p] = _walked(lam[p:p + 1], z[p:p + 1], w[p:p + 1], s[p], dw[p:p + 1], t_start, t)[0]
    ok = np.nonzero(~flat)[0]
    if ok.size == 0 or t.size == 0:
        return Z
    active = np.nonzero(np.any(dw != 0, axis=(0, 2)))[0]  # steps that change nothing cost nothing
    if ok.size == P <= _BLOCK:
        return _impulse_response(lam, z, w, s[:, active], dw[:, active], t_start, t, dtype)
    for p0 in range(0, ok.size, _BLOCK):
        blk = ok[p0:p0 + _BLOCK]
        Z[blk] = _impulse_response(lam[blk], z[blk], w[blk], s[blk][:, active],
                                   dw[blk][:, active], t_start, t, dtype)
    return Z


_LOCAL_ELEMENTS = 1 << 21
"""Elements of one chunk of `_in_sample_blocks`' in-block impulses (16 MB of complex)."""
PER_SAMPLE_RATIO = 2
"""Impulses per sqrt(samples) above which they are summed per sample and carried: below,
spreading each over its own block is cheaper (a heat-up's handful of steps), above it the
carry's few passes are (a furnace in closed loop moves its inputs every minute)."""


def _impulse_response(lam, z, w, s, dw, t_start, t, dtype):
    """Modal states (P, n, N) as a sum of impulses: impulse k at sample i_k adds
    alpha_k exp(lam (t_i - t_ik)) + beta_k to every sample i >= i_k: the start state's,
    then one per step at the first sample on or after it."""
    P, n = lam.shape
    N = t.size
    steady = -w / lam
    first = np.searchsorted(t, s, side="left")
    a = dw / lam[:, None, :]
    late = np.maximum(t[np.minimum(first, N - 1)] - s, 0.0)
    alpha = np.concatenate([((z - steady) * np.exp(lam * (t[0] - t_start)))[:, None],
                            a * np.exp(lam[:, None, :] * late[:, :, None])], axis=1)
    beta = np.concatenate([steady[:, None], -a], axis=1)
    at = np.concatenate([np.zeros((P, 1), dtype=int), first], axis=1)
    p, k = np.nonzero(at < N)  # p-major, k ascending: each sum in the order of the steps
    if at.shape[1] > PER_SAMPLE_RATIO * np.sqrt(N):
        return _summed_per_sample(lam, t, p, at[p, k], alpha[p, k], beta[p, k], dtype)
    return _in_sample_blocks(lam, t, p, at[p, k], alpha[p, k], beta[p, k], dtype)


def _summed_per_sample(lam, t, p, i, alpha, beta, dtype):
    """`_impulse_response` with the impulses of each sample added up first (a weighted count
    per mode): the exponential parts are then the first-order recursion
    y_i = exp(lam (t_i - t_(i-1))) y_(i-1) + impulse_i, which `carried` runs in blocks, and
    the constant parts a cumulative sum."""
    P, n = lam.shape
    N = t.size
    cell = p * N + i

    def per_sample(x: np.ndarray) -> np.ndarray:
        out = np.empty((P * N, n), dtype)
        for j in range(n):
            out[:, j] = np.bincount(cell, np.real(x[:, j]), P * N)
            if np.iscomplexobj(out):
                out[:, j] += 1j * np.bincount(cell, np.imag(x[:, j]), P * N)
        return out.reshape(P, N, n)

    # carried adds c[j] at T[j + 1]: the record's times behind a repeat of the first
    y = carried(lam, np.concatenate([t[:1], t, t[-1:]]),
                np.concatenate([per_sample(alpha), np.zeros((P, 1, n), dtype)], axis=1))
    return (y[:, 1:] + np.cumsum(per_sample(beta), axis=1)).transpose(0, 2, 1)


def _in_sample_blocks(lam, t, p, i, alpha, beta, dtype):
    """`_impulse_response` in blocks of samples. Samples are cut into M blocks of L (both
    about sqrt(N)). With S_m the exponential part and B_m the constant part of the impulses
    before block m, sample l of block m is S_m G[m, l] + B_m
    (G = exp(lam (t_l - t_block_start))), plus the impulses that fall inside the block
    itself. S_m follows block to block in M small steps; the dense part is one broadcast
    product, and each impulse touches only its own block."""
    P, n = lam.shape
    N = t.size
    L = max(1, int(np.ceil(np.sqrt(N))))
    M = -(-N // L)
    tt = np.concatenate([t, np.full(M * L - N, t[-1])]).reshape(M, L)
    m, l0 = i // L, i % L
    lam_p = lam[p]
    start = tt[:, 0]
    nxt = np.append(start[1:], start[-1])
    into = np.zeros((P, M + 1, n), dtype)  # exponential part carried to each block's start
    level = np.zeros((P, M + 1, n), dtype)  # constant part added inside each block
    np.add.at(into, (p, m + 1), alpha * np.exp(lam_p * (nxt[m] - t[i])[:, None]))
    np.add.at(level, (p, m + 1), beta)
    into, level = into.transpose(0, 2, 1), level.transpose(0, 2, 1)
    SB = np.empty((P, n, M, 2), dtype)  # exponential and constant part at each block's start
    SB[:, :, 0, 0] = 0.0
    hop = np.exp(lam[:, :, None] * (nxt - start)[None, None, :])  # block start to the next
    for b in range(1, M):
        SB[:, :, b, 0] = hop[:, :, b - 1] * SB[:, :, b - 1, 0] + into[:, :, b]
    SB[:, :, :, 1] = np.cumsum(level[:, :, :M], axis=2)
    d = np.diff(t)
    G1 = np.ones((P, n, 2, L), dtype)  # [exp(lam (t_l - t_block_start)); 1]
    if N > 2 and d[0] > 0 and np.ptp(d) <= 1e-12 * d[0] * N:
        G1[:, :, 0, :] = np.exp(lam[:, :, None] * (tt[0] - tt[0, 0]))  # the same in every block
        y = SB @ G1
    else:
        G1 = np.broadcast_to(G1[:, :, None], (P, n, M, 2, L)).copy()
        G1[:, :, :, 0, :] = np.exp(lam[:, :, None, None] * (tt - start[:, None]))
        y = (SB[:, :, :, None, :] @ G1)[:, :, :, 0, :]
    # each impulse inside its own block, from its sample on; in chunks that bound the memory
    blocks = y.transpose(0, 2, 1, 3)  # (P, M, n, L), a view
    chunk = max(1, _LOCAL_ELEMENTS // (n * L))
    for c in range(0, i.size, chunk):
        q = slice(c, c + chunk)
        after = np.arange(L)[None, :] >= l0[q, None]  # (Q, L)
        grow = np.exp(lam_p[q][:, :, None]
                      * np.where(after, tt[m[q]] - t[i[q]][:, None], 0.0)[:, None])
        np.add.at(blocks, (p[q], m[q]), np.where(after[:, None, :], alpha[q][:, :, None] * grow
                                                 + beta[q][:, :, None], 0.0))
    return y.reshape(P, n, M * L)[:, :, :N]


def _walked(lam, z, w, s, dw, t_start, t):
    """Modal states (P, n, N) under steps at times s (K,) shared by the P sets, s >= t_start,
    walked from segment to segment as z(tau) = e^(lam tau) z0 + phi(tau) w with
    phi = (e^(lam tau) - 1) / lam, which is tau where lam is zero: exact at any eigenvalue,
    where the steady states -w/lam of the other paths do not exist (a furnace that keeps
    all its heat, which a search over a wide box proposes). The segments' starts are carried
    in blocks (`carried`), so that a record whose input moves every sample costs a few
    passes over it, not one exponential per sample and step."""
    order, bounds, last_idx = segment_bounds(s, t_start)
    dw = dw[:, order]
    held = np.concatenate([w[:, None], w[:, None, :] + np.cumsum(dw, axis=1)],
                          axis=1)[:, last_idx + 1]  # (P, segments, n): the input on each
    ends = np.append(bounds, bounds[-1])
    _, phi = _propagators(lam[:, None, :], np.diff(ends)[None, :, None])
    starts = (carried(lam, ends, phi * held)
              + np.exp(lam[:, None, :] * (bounds - bounds[0])[None, :, None]) * z[:, None])
    seg = np.searchsorted(bounds, t, side="right") - 1
    e, phi = _propagators(lam[:, None, :], (t - bounds[seg])[None, :, None])
    return np.swapaxes(e * starts[:, seg] + phi * held[:, seg], 1, 2)
