"""Starting values by linear least squares on the zone equations: where a fit of a many-zone
network, with or without an effect, starts.

Every zone is measured, so each zone's equation is linear in the parameters that enter it
affinely: the network's exchanges, losses and heats per burner, and an effect's own where
it only changes those (`Tried.zone_affine`: a loss to ambient from another zone, burners
heating their own zone). Integrated from a record's start,
T_i(t) = T_i(t0) + sum_p theta_p int (dA_p[i] T + dB_p[i] u),
where dA_p, dB_p are how the parameter moves zone i's row of the system. The integrals of
the measured temperatures average their noise away, and a term in t per record and zone
takes up the thermocouples' constant offsets (which enter the integrals as offset x time).
A genetic search in twenty-odd dimensions finds the basin far less surely, and far more
slowly, than this one solve; a polish from a baseline bent to absorb an effect may not
leave the side valley it is in at all (seen: a loss from one zone of six, the baseline's
exchange rates at hundreds of times the truth).

A furnace held at its setpoints breaks the offsets' term: a zone whose temperature barely
moves has an integral that is nearly a multiple of t, so the term in t takes up the zone's
whole exchange, and a zone that settles within a sample (a preheating zone under a minute)
comes out with no exchange, loss or heat at all, a start the polish cannot leave. Without
that term the solve keeps each zone's balance, at the price of the offsets' small share of
the level; but a zone that settles within a sample has its rates' scale nowhere in the
integrated equations, and the noise in the integrals shrinks it to nothing either way.
`sampled_start` keeps it: each zone's equation over one sample, where such a zone's balance
is what the regression sees. `equation_error_starts` gives the distinct ones; which is the
better start is for the records to say (`fit` polishes each a little and goes on from the
best)."""

from __future__ import annotations

import numpy as np

from ..experiment import Experiment
from ..simulation.network import parameter_names
from ..simulation.structure import ModelStructure


def equation_error(structure: ModelStructure, records: list[Experiment], offsets: bool = True
                   ) -> dict[str, float]:
    """Values of the structure's affine parameters (the rest keep their defaults) from
    `records`, Experiments of its furnace; values outside a parameter's box come back
    clipped to it. `offsets`: a term in t per record and zone for the thermocouples'
    offsets."""
    nz = structure.furnace.n_zones
    names = _affine_names(structure)
    rows = _rows(structure, names)
    blocks = []  # per record: (regressors (zones, N, names), t - t0, readings (N, zones))
    for r in records:
        t = np.asarray(r.t_min, dtype=float)
        y = _filled(r.zone_temp, t)
        dt = np.diff(t)
        state = _integral(y, dt)  # (N, zones)
        held = np.concatenate([r.burners, r.disturbances], axis=1).astype(float)
        heat = np.concatenate([np.zeros((1, held.shape[1])),
                               np.cumsum(held[:-1] * dt[:, None], axis=0)])
        air = _integral(np.asarray(r.t_air, dtype=float)[:, None], dt)
        # Heat inputs and disturbances hold between samples; ambient moves.
        u = np.concatenate([heat[:, :nz], air, heat[:, nz:]], axis=1)
        X = np.einsum("pij,nj->inp", rows[0], state) + np.einsum("pij,nj->inp", rows[1], u)
        blocks.append((X, t - t[0], y))
    k, R = len(names), len(blocks)
    m = sum(nz * tt.size for _, tt, _ in blocks)
    X = np.zeros((m, k + 2 * nz * R))
    b = np.zeros(m)
    at = 0
    for j, (Xj, tt, yy) in enumerate(blocks):
        n = tt.size
        for i in range(nz):
            X[at:at + n, :k] = Xj[i]
            col = k + 2 * (nz * j + i)
            X[at:at + n, col] = 1.0
            if offsets:
                X[at:at + n, col + 1] = tt
            b[at:at + n] = yy[:, i]
            at += n
    used = np.abs(X).max(axis=0) > 0  # a parameter no zone row holds stays at its default
    scale = np.where(used, np.abs(X).max(axis=0), 1.0)
    coef = np.zeros(X.shape[1])
    coef[used] = np.linalg.lstsq(X[:, used] / scale[used], b, rcond=None)[0] / scale[used]
    return _boxed(structure, names, coef[:k], used[:k])


def sampled_start(structure: ModelStructure, records: list[Experiment],
                  settled: float = 0.02) -> dict[str, float]:
    """Values of the affine parameters from each zone's reading one sample on: a zone's
    equation with its neighbours and inputs held over the sample is
    T_i(k+1) = alpha T_i(k) + beta . x(k), linear in (alpha, beta), and its exact hold maps
    them back to the zone's row, rate ln(alpha)/h and coefficients beta ln(alpha)/(h (alpha-1)).
    A zone that settles within a sample still has its balance in beta where the integrated
    equations lose it in the noise; its rate is then only bounded below, and is put where
    alpha is `settled`. The rows are matched by the parameters in least squares, each zone's
    row scaled by its rate. Only steps of the records' usual sample interval are used."""
    nz = structure.furnace.n_zones
    names = _affine_names(structure)
    dA, dB = _rows(structure, names)
    lhs, rhs = [], []
    samples: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in range(nz)]
    h = float(np.median(np.concatenate([np.diff(np.asarray(r.t_min, dtype=float))
                                        for r in records])))
    for r in records:
        t = np.asarray(r.t_min, dtype=float)
        y = _filled(r.zone_temp, t)
        u = r.inputs_over_steps()
        step = np.abs(np.diff(t) - h) <= 1e-6 * h
        mid = 0.5 * (y[:-1] + y[1:])
        for i in range(nz):
            others = np.delete(mid, i, axis=1)
            X = np.concatenate([y[:-1, [i]], others, u], axis=1)
            samples[i].append((X[step], y[1:, i][step]))
    for i in range(nz):
        X = np.concatenate([x for x, _ in samples[i]])
        b = np.concatenate([v for _, v in samples[i]])
        whole = np.isfinite(X).all(axis=1) & np.isfinite(b)
        X, b = X[whole], b[whole]
        if b.size <= X.shape[1]:  # too few steps of the usual interval: nothing to say
            return _boxed(structure, names, np.zeros(len(names)), np.zeros(len(names), bool))
        scale = np.abs(X).max(axis=0)
        scale[scale == 0] = 1.0
        c = np.linalg.lstsq(X / scale, b, rcond=None)[0] / scale
        alpha = float(np.clip(c[0], settled, 1.0 - 1e-9))
        rate = np.log(alpha) / h
        gain = rate / (alpha - 1.0)
        row = np.concatenate([np.insert(c[1:nz] * gain, i, rate), c[nz:] * gain])
        lhs.append(np.concatenate([dA[:, i, :], dB[:, i, :]], axis=1).T / abs(rate))
        rhs.append(row / abs(rate))
    theta = np.linalg.lstsq(np.concatenate(lhs), np.concatenate(rhs), rcond=None)[0]
    return _boxed(structure, names, theta, np.ones(len(names), dtype=bool))


def equation_error_starts(structure: ModelStructure, records: list[Experiment]
                          ) -> list[dict[str, float]]:
    """The candidate starts, each a different one: `equation_error` with the offsets' terms,
    without them, and `sampled_start` (starts closer than 30% in every value count once)."""
    out: list[dict[str, float]] = []
    for start in (equation_error(structure, records),
                  equation_error(structure, records, offsets=False),
                  sampled_start(structure, records)):
        if not any(_near(start, other) for other in out):
            out.append(start)
    return out


def _near(a: dict[str, float], b: dict[str, float]) -> bool:
    return all(abs(np.log(max(abs(a[n]), 1e-12) / max(abs(b[n]), 1e-12))) <= np.log(1.3)
               for n in a)


def _affine_names(structure: ModelStructure) -> list[str]:
    affine = set(parameter_names(structure.furnace)) | {
        p.name for e in structure.effects if e.tried.zone_affine for p in e.params}
    return [n for n in structure.names if n in affine]


def _boxed(structure: ModelStructure, names: list[str], values: np.ndarray,
           used: np.ndarray) -> dict[str, float]:
    """Values clipped to their parameters' boxes; a value not determined (not `used`, not
    finite) is the parameter's default."""
    box = {p.name: p for p in structure.params}
    return {n: float(np.clip(v, box[n].lo, box[n].hi)) if ok and np.isfinite(v)
            else box[n].default for n, v, ok in zip(names, values, used, strict=True)}


def _rows(structure: ModelStructure, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """How a unit of each parameter moves the zone rows of the system: (names, zones, zones)
    for the zone temperatures and (names, zones, inputs) for the inputs. Exact for affine
    parameters: a difference of two systems, at the defaults and one higher."""
    nz = structure.furnace.n_zones
    base = structure.defaults()
    ref = structure.system(structure.theta(base))
    dA, dB = [], []
    for n in names:
        moved = structure.system(structure.theta({**base, n: base[n] + 1.0}))
        dA.append(moved.A[0, :nz, :nz] - ref.A[0, :nz, :nz])
        dB.append(moved.B[0, :nz] - ref.B[0, :nz])
    return np.array(dA).reshape(len(names), nz, nz), np.array(dB).reshape(len(names), nz, -1)


def _filled(y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Zone temperatures with missing readings interpolated in time (held at the ends)."""
    y = np.array(y, dtype=float)
    for i in range(y.shape[1]):
        ok = np.isfinite(y[:, i])
        if ok.any() and not ok.all():
            y[:, i] = np.interp(t, t[ok], y[ok, i])
    return y


def _integral(y: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """The trapezoidal integral of y (N, k) from its first sample to each, steps dt (N - 1,)."""
    steps = 0.5 * (y[1:] + y[:-1]) * dt[:, None]
    return np.concatenate([np.zeros((1, y.shape[1])), np.cumsum(steps, axis=0)])
