"""Starting values by linear least squares on the integrated zone equations: where a fit of
a many-zone network, with or without an effect, starts.

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
the level. `equation_error_starts` gives both; which is the better start is for the records
to say (`fit` takes the one whose simulation misses them less)."""

from __future__ import annotations

import numpy as np
from scipy.integrate import cumulative_trapezoid

from ..experiment import Experiment
from ..simulation.network import parameter_names
from ..simulation.structure import ModelStructure


def equation_error(structure: ModelStructure, records: list[Experiment], offsets: bool = True
                   ) -> dict[str, float]:
    """Values of the structure's affine parameters (the rest keep their defaults) from
    `records`, Experiments of its furnace; values outside a parameter's box come back
    clipped to it. `offsets`: a term in t per record and zone for the thermocouples'
    offsets."""
    furnace = structure.furnace
    nz = furnace.n_zones
    affine = set(parameter_names(furnace)) | {
        p.name for e in structure.effects if e.tried.zone_affine for p in e.params}
    box = {p.name: p for p in structure.params}
    names = [n for n in structure.names if n in affine]
    rows = _rows(structure, names)
    blocks = []  # per record: (regressors (zones, N, names), t - t0, readings (N, zones))
    for r in records:
        t = np.asarray(r.t_min, dtype=float)
        y = _filled(r.zone_temp, t)
        dt = np.diff(t)
        state = cumulative_trapezoid(y, t, axis=0, initial=0.0)  # (N, zones)
        held = np.concatenate([r.burners, r.disturbances], axis=1).astype(float)
        heat = np.concatenate([np.zeros((1, held.shape[1])),
                               np.cumsum(held[:-1] * dt[:, None], axis=0)])
        air = cumulative_trapezoid(np.asarray(r.t_air, dtype=float)[:, None], t, axis=0,
                                   initial=0.0)
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
    out = {}
    for i, name in enumerate(names):
        p = box[name]
        v = coef[i]
        out[name] = float(np.clip(v, p.lo, p.hi)) if used[i] and np.isfinite(v) else p.default
    return out


def equation_error_starts(structure: ModelStructure, records: list[Experiment]
                          ) -> list[dict[str, float]]:
    """`equation_error` with the offsets' terms, and without them where that gives another
    start (any value more than 30% apart): one or two candidate starts."""
    with_offsets = equation_error(structure, records)
    without = equation_error(structure, records, offsets=False)
    far = any(abs(np.log(max(abs(a), 1e-12) / max(abs(b), 1e-12))) > np.log(1.3)
              for a, b in ((with_offsets[n], without[n]) for n in with_offsets))
    return [with_offsets, without] if far else [with_offsets]


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
