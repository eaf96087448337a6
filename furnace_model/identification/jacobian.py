"""The Jacobian of a fit's residuals: exact where the model is linear in its state, by
forward differences where it is not.

Exact (`furnace_model.simulation.sensitivity`): every parameter that moves the system's
matrices, its input levels or a thermocouple's own error, and every initial state, in one
pass over each record. The derivatives of the matrices and levels themselves are central
differences of how the structure builds them (no simulation, and exact to about 1e-10 for
the rational expressions they are); those of the response are closed-form, and so are
those of a parameter that moves the instants at which the input steps (a dead time, the
instant of a fuel change): moving a step puts an impulse into the input. Some
parameters stay with forward differences, one simulation per column: one that moves a
step's instant and its level at once (an instant within a difference step of another
step), one that moves what the sensors read (C), and every parameter of a structure with a
nonlinear term (radiation).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..effects import Effect
from ..simulation.lti import Drive, Modes
from ..simulation.sensitivity import NoClosedForm, response_sensitivity

if TYPE_CHECKING:
    from .problem import Problem

FD_STEP = 1e-6
"""Forward-difference step of a parameter on the search scale (times max(1, |z|))."""
X0_STEP = 1e-3
"""Forward-difference step of an initial zone temperature, °C (the response is linear in it)."""
CENTRAL_STEP = 1e-4
"""Central-difference step of the matrices and levels on the search scale."""


def jacobian(prob: Problem, z: np.ndarray) -> np.ndarray:
    """d residuals / d unknowns (m, n) at z."""
    if prob.structure.linear:
        try:
            return _exact(prob, z)
        except NoClosedForm:
            pass
    return forward_differences(prob, z)


def forward_differences(prob: Problem, z: np.ndarray,
                        columns: np.ndarray | None = None, x0: bool = True) -> np.ndarray:
    """Forward differences, all perturbed sets of a record in one batched call: of the free
    parameters in `columns` (all if None) and, with `x0`, of the initial states; the other
    columns are zero. A nonlinear structure integrates them as small moves of the point
    (`Batch` "differences": from the point's own trajectory, a few sweeps each).

    Where the nonlinear terms vanish at z (radiation's share at zero: a fit that drives
    the effect to its null), every set but the one that switches them on is linear and
    simulated in closed form; that one is taken to first order in its nonlinear terms
    (`ModelStructure.simulate_first_order`). That differs from the integrated set by
    the square of the step, and by the two schemes' discretisations (a few millionths
    of the derivative on a heat-up): the same derivative, without a nonlinear
    integration per Jacobian."""
    k, nz = prob.k, prob.nz
    cols = np.arange(k) if columns is None else np.asarray(columns, dtype=int)
    nx = nz if x0 else 0
    h = np.concatenate([FD_STEP * np.maximum(1.0, np.abs(z[cols])), np.full(nx, X0_STEP)])
    zp = np.repeat(z[None, :k], cols.size + 1 + nx, axis=0)
    zp[1 + np.arange(cols.size), cols] += h[:cols.size]
    vals = prob.values(zp)
    first = None
    if not prob.structure.linear:
        off = prob.structure.nonlinear_off(vals)
        if off[0] and not off.all():
            first = ~off
    blocks = []
    for j, r in enumerate(prob.records):
        x0s = np.repeat(prob.x0_of(z, j)[None], zp.shape[0], axis=0)
        x0s[1 + cols.size + np.arange(nx), np.arange(nx)] += h[cols.size:]
        res = prob.residuals(j, vals, x0s, first, batch="differences")
        d = (res[1:] - res[0]) / h[:, None]  # (columns + zones, m_j)
        block = np.zeros((res.shape[1], prob.n))
        block[:, cols] = d[:cols.size].T
        i = prob.k + prob.block * j
        if x0:
            block[:, i:i + nz] = d[cols.size:].T
        if prob.offsets_fitted:  # a zone's offset moves its own residuals one for one
            block[np.arange(res.shape[1]), i + nz + r.zone_of] = 1.0
        blocks.append(block)
    return np.concatenate(blocks)


def _exact(prob: Problem, z: np.ndarray) -> np.ndarray:
    structure, k, nz = prob.structure, prob.k, prob.nz
    h = CENTRAL_STEP * np.maximum(1.0, np.abs(z[:k]))
    zs = np.repeat(z[None, :k], 1 + 2 * k, axis=0)
    zs[1 + np.arange(k), np.arange(k)] += h
    zs[1 + k + np.arange(k), np.arange(k)] -= h
    vals = prob.values(zs)
    theta = structure.theta(vals)
    sys = structure.system(theta)
    up, down = slice(1, 1 + k), slice(1 + k, 1 + 2 * k)
    dA = (sys.A[up] - sys.A[down]) / (2.0 * h)[:, None, None]
    dB = (sys.B[up] - sys.B[down]) / (2.0 * h)[:, None, None]
    timed = np.any(sys.C[1:] != sys.C[0], axis=(1, 2))
    timed = timed[:k] | timed[k:]
    directions = structure.full_state(np.eye(nz))
    modes = Modes.of(sys.A[:1])
    # the parameters a thermocouple's own error depends on, and their sets (point, up, down)
    own = {p.name for e in structure.effects if type(e).sensor_offsets is not Effect.sensor_offsets
           for p in e.params}
    sensed = np.array([i for i, name in enumerate(prob.names) if name in own], dtype=int)
    rows = np.concatenate([[0], np.ravel(np.column_stack([1 + sensed, 1 + k + sensed]))]
                          ).astype(int)
    furnace = structure.furnace
    per_record = []
    for j, r in enumerate(prob.records):
        drive = structure.drive(theta, r.inputs)
        base, d_u0, d_du, d_s, moved = _drive_derivatives(drive, h)
        timed |= moved
        x0 = structure.full_state(prob.x0_of(z, j)[None])[0]
        dy, dy0 = response_sensitivity(sys.A[0], sys.B[0], sys.C[0], dA, dB, base, d_u0,
                                          d_du, x0, directions, float(r.inputs.t[0]), r.t, modes,
                                          d_s)
        if sensed.size:
            off = structure.sensor_offsets({n: v[rows] for n, v in vals.items()}, r.t)
            d_off = (off[1::2] - off[2::2]) / (2.0 * h[sensed])[:, None, None]
            weight = r.tc_weight if r.tc_weight is not None else furnace.weights(
                np.ones((r.t.size, len(furnace.sensors)), dtype=bool))
            dy[sensed] += furnace.zone_sums(d_off * weight)
        per_record.append((dy, dy0))
    J = _assemble(prob, per_record)
    if timed.any():
        cols = np.nonzero(timed)[0]
        J[:, cols] = forward_differences(prob, z, cols, x0=False)[:, cols]
    return J


def _drive_derivatives(drive: Drive, h: np.ndarray
                       ) -> tuple[Drive, np.ndarray | None, np.ndarray | None,
                                  np.ndarray | None, np.ndarray]:
    """The drive of the central set (set 0 of 1 + 2k: the point, then each parameter up,
    then down), the derivatives of its levels (k, m) and (k, K, m) and of its step times
    (k, K), None where the drive is one for all sets (no effect moves the inputs), and
    which parameters move both a step's time and the levels: across the difference's span
    an instant then passes another step, so neither derivative holds."""
    k = h.size
    if np.ndim(drive.s) == 1 and drive.u0.shape[0] == 1 and drive.du.shape[0] == 1:
        return drive, None, None, None, np.zeros(k, dtype=bool)  # no parameter moves it
    P = 1 + 2 * k
    s = np.broadcast_to(drive.s, (P,) + np.shape(drive.s)[-1:])
    u0 = np.broadcast_to(drive.u0, (P,) + drive.u0.shape[1:])
    du = np.broadcast_to(drive.du, (P,) + drive.du.shape[1:])
    d_s = (s[1:1 + k] - s[1 + k:]) / (2.0 * h)[:, None]
    d_u0 = (u0[1:1 + k] - u0[1 + k:]) / (2.0 * h)[:, None]
    d_du = (du[1:1 + k] - du[1 + k:]) / (2.0 * h)[:, None, None]
    timed = np.any(s[1:] != s[0], axis=1)
    levels = np.any(u0[1:] != u0[0], axis=1) | np.any(du[1:] != du[0], axis=(1, 2))
    moved = (timed[:k] | timed[k:]) & (levels[:k] | levels[k:])
    d_s[moved], d_u0[moved], d_du[moved] = 0.0, 0.0, 0.0
    base = Drive(drive.t0, u0[:1], s[0], du[:1])
    return base, d_u0, d_du, d_s, moved


def _assemble(prob: Problem, per_record: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The records' output derivatives (k, N, zones) and (zones, N, zones) as residual rows,
    each record's initial states and offsets in its own columns. Filled as its transpose,
    whose rows are the derivatives as they come, and returned as a view of it (column
    major): writing the columns of a row-major array strides through all of it."""
    k, nz = prob.k, prob.nz
    rows = [r.zone_of.size for r in prob.records]
    Jt = np.zeros((prob.n, sum(rows)))
    at = 0
    for j, (r, (dy, dy0)) in enumerate(zip(prob.records, per_record, strict=True)):
        block = Jt[:, at:at + rows[j]]
        for cols, d in ((slice(0, k), dy), (slice(k + prob.block * j, k + prob.block * j + nz),
                                             dy0)):
            flat = d.reshape(d.shape[0], d.shape[1] * d.shape[2])  # a row's zones together
            block[cols] = flat if r.complete else flat[:, r.mask.ravel()]
        if prob.offsets_fitted:
            block[k + prob.block * j + nz + r.zone_of, np.arange(rows[j])] = 1.0
        at += rows[j]
    return Jt.T
