"""Offline identification of the model's parameters from heat-up records (paper section III).

The criterion is the paper's eq. 12: the sum over zones of the squared difference between
the measured zone temperature and the model's, over every sample with a reading (missing
readings are masked out, not filled). Unknowns are the structure's parameters plus each
experiment's initial zone temperatures: a cold start sits at ambient, a window cut from a
running furnace does not.

Two methods:
- `ga`: the paper's real-coded genetic algorithm, population and generations as its knobs.
- `fast` (default): a short evolutionary search to find the basin, then a Gauss-Newton polish
  (scipy's trust-region least squares) on the exact simulator, with the finite-difference
  Jacobian evaluated as one batched simulation of all perturbed parameter sets.
Both search positive parameters on the log scale. The Jacobian at the optimum gives the
intervals and the determined combinations (furnace_model.uncertainty).
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
from scipy.stats import chi2

from .criteria import Criteria, criteria
from .errors import FurnaceError
from .experiment import Experiment
from .ga import genetic_search
from .plausible import FLAG_LEVEL, Flag, start_band, zone_bias_bounds
from .profile import profile_interval
from .response import Response
from .scores import zone_metrics
from .structure import Inputs, ModelStructure
from .uncertainty import WIDE, Z95, Uncertainty, from_jacobian, gram

METHODS = ("fast", "ga")
GA_DEFAULTS = {"fast": (32, 30), "ga": (20, 2000)}
"""(population, generations) per method: the paper ran population 20 for 25 000-100 000
cycles; 2000 generations already take seconds per run here."""
PROFILE_WIDE = 0.25
"""A linearised 95% half-width (search scale: about +-25% for a rate) beyond which the
interval is profiled instead: nearer, the criterion is close enough to quadratic (b and c of
a 1-minute heat-up, +-8%, held the truth in 57-59 of 60 draws linearised)."""
PROFILE_GAIN_TOL = 1e-7
"""A profile's refit is converged to this share of the criterion: its rise is wanted to a
few percent, and it is thousands of times smaller than the criterion."""
WARM_DAMPING = 1e-7
"""The first Levenberg-Marquardt damping of a sliding window's refit (`WarmStart`): the
previous window's optimum is next to this one's, where Gauss-Newton steps converge in two or
three; the general warm start's 1e-3 took eight or nine to walk the last millionths of the
criterion down the d/e valley (the same optimum, to a few millionths of d and e)."""
_T = TypeVar("_T")
_FD_STEP = 1e-6
_CELLS = 4_000_000
"""Model values (sets x samples x zones) per simulator call in the GA: about 32 MB each."""
POLISH_MAX_ITER = 60
STOP_REASONS = {
    "converged": "the polish converged: its last step changed the cost by less than 1e-10 "
                 "relative or the unknowns by less than 1e-9, or no step lowered the cost",
    "iteration_limit": f"the polish reached its limit of {POLISH_MAX_ITER} iterations before "
                       "converging",
    "time_budget": "the time budget ran out before the search finished",
    "ga_generations": "the genetic algorithm ran all its generations; method ga has no polish",
    "not_finite": "the model cannot be simulated at the point the polish started from",
}
"""Why a run's search stopped (FitResult.stop_reason, the runs' stop_reason)."""


@dataclass
class _Record:
    """One experiment made ready for repeated simulation: inputs built once."""

    t: np.ndarray
    y: np.ndarray  # (N, zones) measured zone temperatures
    mask: np.ndarray  # (N, zones) readings present
    inputs: Inputs
    x0_guess: np.ndarray  # (zones,)
    tc_weight: np.ndarray | None  # (N, thermocouples): how each enters its zone's mean
    complete: bool = False  # no reading missing: the mask can be skipped
    zone_of: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))  # per residual
    name: str = ""
    bias: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (zones,) offset bound
    x0_lo: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (zones,) plausible start
    x0_hi: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @classmethod
    def of(cls, exp: Experiment, with_sensor_offsets: bool,
           structure: ModelStructure | None = None) -> _Record:
        if len(exp) < 2:
            raise FurnaceError(f"{exp.source or exp.name}: needs at least two samples to fit")
        furnace = exp.furnace
        if structure is not None and structure.furnace != furnace:
            raise FurnaceError(f"{exp.source or exp.name}: a record of furnace "
                               f"'{furnace.name}', the model is of furnace "
                               f"'{structure.furnace.name}'")
        nz = furnace.n_zones
        y = exp.zone_temp
        mask = np.isfinite(y)
        guess = np.empty(nz)
        for w, zone in enumerate(furnace.zones):
            if not mask[:, w].any():
                raise FurnaceError(f"{exp.source or exp.name}: zone '{zone}' has no readings")
            guess[w] = y[np.argmax(mask[:, w]), w]
        weight = furnace.weights(np.isfinite(exp.tc)) if with_sensor_offsets else None
        zone_of = np.broadcast_to(np.arange(nz), mask.shape)[mask]
        bias = zone_bias_bounds(furnace, exp.tc)
        lo, hi = start_band(y, exp.t_air, bias)
        return cls(exp.t_min, np.where(mask, y, 0.0), mask, exp.inputs(), np.clip(guess, lo, hi),
                   weight, bool(mask.all()), zone_of, exp.name, bias, lo, hi)


class _Problem:
    """The least-squares problem: unknown vector = free parameters (log scale where the
    parameter is positive) followed by the initial zone temperatures of each experiment
    (and its zone offsets when fitted), one per zone. The records' own unknowns are held to
    what they can physically be (`furnace_model.plausible`): the box `nuisance_lo`,
    `nuisance_hi`."""

    def __init__(self, experiments: list[Experiment], structure: ModelStructure,
                 fixed: dict[str, float], bounds: dict[str, tuple[float, float]],
                 zone_offsets: bool = False, held_offsets: Sequence[np.ndarray] | None = None):
        unknown = sorted(set(fixed) - set(structure.names)) + sorted(set(bounds) - set(structure.names))
        if unknown:
            raise FurnaceError(f"unknown parameter(s) {unknown}; the model has {structure.names}")
        self.structure = structure
        self.fixed = dict(fixed)
        self.free = [p for p in structure.params if p.name not in fixed]
        self.names = [p.name for p in self.free]
        self.log = np.array([p.log for p in self.free], dtype=bool)
        lo = np.array([bounds.get(p.name, (p.lo, p.hi))[0] for p in self.free], dtype=float)
        hi = np.array([bounds.get(p.name, (p.lo, p.hi))[1] for p in self.free], dtype=float)
        if np.any(lo >= hi) or np.any(self.log & (lo <= 0)):
            raise FurnaceError("parameter bounds must have lo < hi (and lo > 0 for rates)")
        self.lo_val, self.hi_val = lo, hi
        self.lo, self.hi = self.to_z(lo), self.to_z(hi)
        self.nz = nz = structure.n_zones
        self.records = [_Record.of(e, structure.has_sensor_offsets, structure)
                        for e in experiments]
        # Known thermocouple offsets per record (zones,), added to the model: a span of a record
        # whose offsets were estimated on more data than it holds.
        self.held = None if held_offsets is None else [np.asarray(o, float) for o in held_offsets]
        self.k = len(self.free)
        self.offsets_fitted = zone_offsets
        self.blocked = not structure.furnace.paper_structure  # Jacobians with many columns
        self.block = 2 * nz if zone_offsets else nz  # per experiment: x0, then offsets
        self.n = self.k + self.block * len(self.records)
        self.n_obs = int(sum(r.mask.sum() for r in self.records))
        # A held offset is in the readings: the start they allow is theirs less it.
        shift = [np.zeros(nz) if self.held is None else self.held[j]
                 for j in range(len(self.records))]
        self.nuisance_lo = np.concatenate(
            [np.concatenate([r.x0_lo - s, -r.bias] if zone_offsets else [r.x0_lo - s])
             for r, s in zip(self.records, shift, strict=True)]) if self.records else np.zeros(0)
        self.nuisance_hi = np.concatenate(
            [np.concatenate([r.x0_hi - s, r.bias] if zone_offsets else [r.x0_hi - s])
             for r, s in zip(self.records, shift, strict=True)]) if self.records else np.zeros(0)
        self._memo: dict[str, tuple[bytes, Any]] = {}

    def holding(self, i: int, z_i: float) -> _Problem:
        """The same problem with free parameter i held at z_i (search scale): what a
        profile of the criterion refits at each trial value."""
        sub = copy.copy(self)
        keep = [j for j in range(self.k) if j != i]
        value = float(np.exp(z_i)) if self.log[i] else float(z_i)
        sub.fixed = {**self.fixed, self.names[i]: value}
        sub.free = [self.free[j] for j in keep]
        sub.names = [self.names[j] for j in keep]
        sub.log, sub.lo, sub.hi = self.log[keep], self.lo[keep], self.hi[keep]
        sub.lo_val, sub.hi_val = self.lo_val[keep], self.hi_val[keep]
        sub.k, sub.n = self.k - 1, self.n - 1
        sub._memo = {}
        return sub

    def series(self) -> list[np.ndarray]:
        """Positions in the residual vector of each record's zone series, in time order:
        the unit whose noise has one variance and one colour."""
        out, at = [], 0
        for r in self.records:
            for w in range(self.nz):
                out.append(at + np.nonzero(r.zone_of == w)[0])
            at += r.zone_of.size
        return out

    def to_z(self, v: np.ndarray) -> np.ndarray:
        v = np.asarray(v, dtype=float)
        return np.where(self.log, np.log(np.where(self.log, np.maximum(v, 1e-300), 1.0)), v)

    def from_z(self, z: np.ndarray) -> np.ndarray:
        return np.where(self.log, np.exp(np.where(self.log, z, 0.0)), z)

    def values(self, zp: np.ndarray) -> dict[str, np.ndarray]:
        """Parameter sets (P, k) on the search scale -> {name: (P,)} for the simulator."""
        v = self.from_z(np.atleast_2d(zp))
        out = {n: v[:, i] for i, n in enumerate(self.names)}
        for name, val in self.fixed.items():
            out[name] = np.full(v.shape[0], float(val))
        return out

    def predict(self, j: int, values: dict[str, np.ndarray], x0: np.ndarray,
                first_order: np.ndarray | None = None) -> np.ndarray:
        """Model zone temperatures (P, N, zones) for experiment j; the sets marked in
        `first_order` (P,) to first order in the nonlinear terms (`jac`)."""
        r = self.records[j]
        with np.errstate(all="ignore"):
            if first_order is None:
                response = self._simulate(values, r, x0)
            else:
                response = self._simulate_split(values, r, x0, first_order)
            y = response.readings(weight=r.tc_weight)
        return y if self.held is None else y + self.held[j]

    def _simulate(self, values: dict[str, np.ndarray], r: _Record, x0: np.ndarray) -> Response:
        try:
            return self.structure.simulate(values, r.inputs, r.t, x0)
        except IndexError:
            # The simulator cannot yet take a mode slower than ~1e9 min (an eigenvalue that
            # is numerically zero) in a batch with shared steps: such a set is a furnace that
            # never cools, far from any data. Score the others; those get NaN.
            theta = self.structure.theta(values)
            lam = np.linalg.eigvals(self.structure.system(theta).A)
            span = max(float(r.t[-1] - r.t[0]), 1.0)
            bad = np.any(np.abs(lam) * span <= 1e-6, axis=1)
            if not bad.any():
                raise
            good = np.nonzero(~bad)[0]
            x0 = np.broadcast_to(x0, (bad.size, x0.shape[-1]))
            out = np.full((bad.size, r.t.size, self.nz), np.nan)
            if good.size:
                out[good] = self.structure.simulate({k: v[good] for k, v in theta.items()},
                                                    r.inputs, r.t, x0[good]).zones
            return Response(r.t, out, self.structure, theta)

    def _simulate_split(self, values: dict[str, np.ndarray], r: _Record, x0: np.ndarray,
                        first_order: np.ndarray) -> Response:
        x0 = np.broadcast_to(x0, (first_order.size, x0.shape[-1]))
        fo, full = np.nonzero(first_order)[0], np.nonzero(~first_order)[0]
        out = np.empty((first_order.size, r.t.size, self.nz))
        out[full] = self._simulate({k: v[full] for k, v in values.items()}, r, x0[full]).zones
        try:
            out[fo] = self.structure.simulate_first_order({k: v[fo] for k, v in values.items()},
                                                          r.inputs, r.t, x0[fo])
        except IndexError:  # a mode too slow for the closed form: as _simulate does
            out[fo] = self._simulate({k: v[fo] for k, v in values.items()}, r, x0[fo]).zones
        return Response(r.t, out, self.structure, values)

    def residuals(self, j: int, values: dict[str, np.ndarray], x0: np.ndarray,
                  first_order: np.ndarray | None = None) -> np.ndarray:
        r = self.records[j]
        diff = self.predict(j, values, x0, first_order) - r.y
        return diff.reshape(diff.shape[0], -1) if r.complete else diff[:, r.mask]

    def sse_params(self, zp: np.ndarray) -> np.ndarray:
        """SSE (P,) for parameter sets (P, k), initial states at the first readings: the
        GA's objective, one simulation call per experiment for the whole population (in
        slices of about _CELLS values, so a long 1-second window stays within memory)."""
        total = np.zeros(zp.shape[0])
        for j, r in enumerate(self.records):
            step = max(1, _CELLS // (self.nz * r.t.size))
            for p0 in range(0, zp.shape[0], step):
                sl = slice(p0, p0 + step)
                res = self.residuals(j, self.values(zp[sl]), r.x0_guess[None])
                total[sl] += np.einsum("pm,pm->p", res, res)
        return np.where(np.isfinite(total), total, np.inf)

    def x0_of(self, z: np.ndarray, j: int) -> np.ndarray:
        i = self.k + self.block * j
        return z[i:i + self.nz]

    def offsets_of(self, z: np.ndarray, j: int) -> np.ndarray:
        i = self.k + self.block * j + self.nz
        return z[i:i + self.nz] if self.offsets_fitted else np.zeros(self.nz)

    def at_bound(self, z: np.ndarray) -> dict[str, str]:
        """Free parameters that ended on an edge of their search box: {name: side}. The
        polish clips onto the edge exactly; the tolerance is for the GA alone."""
        tol = 1e-6 * (self.hi - self.lo)
        out = {}
        for i, name in enumerate(self.names):
            if z[i] <= self.lo[i] + tol[i]:
                out[name] = "lower"
            elif z[i] >= self.hi[i] - tol[i]:
                out[name] = "upper"
        return out

    def start(self, zp: np.ndarray, offsets: Sequence[np.ndarray] | None = None) -> np.ndarray:
        """The unknown vector from parameters zp: each record's initial state at its first
        readings, its zone offsets at zero, or at `offsets` (per record) when fitted and given,
        and then the first readings less them (a thermocouple's bias is in its reading);
        inside the records' physical box."""
        per = []
        for j, r in enumerate(self.records):
            if offsets is None or not self.offsets_fitted:
                per.append(np.concatenate([r.x0_guess, np.zeros(self.block - self.nz)]))
            else:
                off = np.asarray(offsets[j], dtype=float)
                per.append(np.concatenate([r.x0_guess - off, off]))
        own = np.clip(np.concatenate(per), self.nuisance_lo, self.nuisance_hi) if per else []
        return np.concatenate([zp, own])

    def held_by_bounds(self, polished: _Polished) -> np.ndarray:
        """Which of the records' own unknowns (n - k,) the data push against their physical
        bounds: those on a bound, where the bounds cost the fit more than noise could
        (a likelihood-ratio test at `FLAG_LEVEL` against the free optimum, its residual's
        correlation time allowed for). A short window of a furnace at rest cannot tell an
        offset from the start, and the free optimum wanders out of the box at no cost: its
        bound is no evidence of a missing effect, and nothing is flagged."""
        on = self._on_bound(polished.z)
        if polished.free_cost is None or not on.any():
            return np.zeros(on.size, dtype=bool)
        r = polished.r
        sigma2 = polished.free_cost / max(r.size - self.n, 1)
        tau = max([_correlation_time(r[idx]) for idx in self.series()], default=1.0)
        rise = (float(r @ r) - polished.free_cost) / (sigma2 * tau)
        return on if rise > chi2.ppf(FLAG_LEVEL, int(on.sum())) else np.zeros(on.size, dtype=bool)

    def flags(self, z: np.ndarray, held: np.ndarray) -> list[Flag]:
        """The records' own unknowns marked in `held` (`held_by_bounds`), as flags."""
        out = []
        zones = self.structure.furnace.zones
        at = z[self.k:]
        for i in np.nonzero(held)[0]:
            j, q = divmod(int(i), self.block)
            kind = "offset" if q >= self.nz else "initial_state"
            out.append(Flag(kind, self.records[j].name, zones[q % self.nz], float(at[i]),
                            float(self.nuisance_lo[i]), float(self.nuisance_hi[i])))
        return out

    def _on_bound(self, z: np.ndarray) -> np.ndarray:
        at = z[self.k:]
        tol = 1e-6 * np.maximum(1.0, np.abs(at))
        return (at <= self.nuisance_lo + tol) | (at >= self.nuisance_hi - tol)

    def unflagged(self, J: np.ndarray, held: np.ndarray) -> np.ndarray:
        """J with the columns of the records' unknowns held on a bound (`held_by_bounds`)
        zeroed: held, they take nothing from the parameters' uncertainty (a zero column is a
        direction the covariance leaves apart)."""
        if not held.any():
            return J
        J = J.copy()
        J[:, self.k + np.nonzero(held)[0]] = 0.0
        return J

    def remembered(self, what: str, z: np.ndarray, compute: Callable[[], _T]) -> _T:
        """compute() for unknowns z, or what it gave last time for the same z: a fit asks
        for the residuals, Jacobian and zone series at its optimum several times over (the
        scores of each run, the intervals, the criteria), and each is a simulation."""
        key = np.asarray(z, dtype=float).tobytes()
        hit = self._memo.get(what)
        if hit is not None and hit[0] == key:
            return hit[1]
        value = compute()
        self._memo[what] = (key, value)
        return value

    def fun(self, z: np.ndarray) -> np.ndarray:
        return self.remembered("fun", z, lambda: self.fun_many(z[None])[0])

    def fun_many(self, Z: np.ndarray) -> np.ndarray:
        """Residuals (P, m) of unknown vectors (P, n), each experiment in one batched call."""
        vals = self.values(Z[:, :self.k])
        out, nz = [], self.nz
        for j, r in enumerate(self.records):
            i = self.k + self.block * j
            res = self.residuals(j, vals, Z[:, i:i + nz])
            out.append(res + Z[:, i + nz:i + 2 * nz][:, r.zone_of] if self.offsets_fitted
                       else res)
        return np.concatenate(out, axis=1)

    def jac(self, z: np.ndarray) -> np.ndarray:
        return self.remembered("jac", z, lambda: self._jac(z))

    def _jac(self, z: np.ndarray) -> np.ndarray:
        """Forward differences, all perturbed sets of an experiment in one batched call.

        Where the nonlinear terms vanish at z (radiation's share at zero: a fit that drives
        the effect to its null), every set but the one that switches them on is linear and
        simulated in closed form; that one is taken to first order in its nonlinear terms
        (`ModelStructure.simulate_first_order`). That differs from the integrated set by
        the square of the step, and by the two schemes' discretisations (a few millionths
        of the derivative on a heat-up): the same derivative, without a nonlinear
        integration per Jacobian."""
        k = self.k
        blocks = []
        zp, h = self._perturbed(z)
        vals = self.values(zp)
        first = None
        if not self.structure.linear:
            off = self.structure.nonlinear_off(vals)
            if off[0] and not off.all():
                first = ~off
        nz = self.nz
        for j in range(len(self.records)):
            P = k + 1 + nz
            x0 = np.repeat(self.x0_of(z, j)[None], P, axis=0)
            x0[1 + k + np.arange(nz), np.arange(nz)] += h[k:]
            res = self.residuals(j, vals, x0, first)
            d = (res[1:] - res[0]) / h[:, None]  # (k+zones, m_j)
            block = np.zeros((res.shape[1], self.n))
            block[:, :k] = d[:k].T
            i = k + self.block * j
            block[:, i:i + nz] = d[k:].T
            if self.offsets_fitted:  # a zone's offset moves its own residuals one for one
                block[np.arange(res.shape[1]), i + nz + self.records[j].zone_of] = 1.0
            blocks.append(block)
        return np.concatenate(blocks)

    def _perturbed(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The Jacobian's parameter sets (k + 1 + zones, k): z, then each free parameter
        stepped, then z again for each initial zone temperature; and the steps (k + zones,)."""
        k, nz = self.k, self.nz
        h = np.concatenate([_FD_STEP * np.maximum(1.0, np.abs(z[:k])), np.full(nz, 1e-3)])
        zp = np.repeat(z[None, :k], k + 1 + nz, axis=0)
        zp[1 + np.arange(k), np.arange(k)] += h[:k]
        return zp, h

    def polish(self, z0: np.ndarray, deadline: float | None, max_iter: int = POLISH_MAX_ITER,
               gain_tol: float = 1e-10, damping: float = 1e-3) -> _Polished:
        """Levenberg-Marquardt from z0, parameters kept in their box and the records' own
        unknowns in theirs; converged when a step lowers the cost by less than `gain_tol`
        of it. `damping`: the first step's, small for a start already near the minimum
        (Gauss-Newton converges there in a few steps).

        The records' own unknowns are first left free: where that optimum is physical it is
        the answer, reached by the path the parameters would take anyway; where it is not,
        the polish goes on from it inside their box. Boxed from the start, a bound that the
        optimum does not touch can still block the path to it and leave the fit in a side
        valley (docs/identification.md)."""
        free = self._polish(z0, deadline, max_iter, gain_tol, damping, boxed=False)
        own = free.z[self.k:]
        if free.reason == "not_finite" or np.all(
                (own >= self.nuisance_lo) & (own <= self.nuisance_hi)):
            return free
        boxed = self._polish(free.z, deadline, max_iter, gain_tol, damping, boxed=True)
        boxed.free_cost = float(free.r @ free.r)
        return boxed

    def _polish(self, z0: np.ndarray, deadline: float | None, max_iter: int,
                gain_tol: float, damping: float, boxed: bool) -> _Polished:
        """One Levenberg-Marquardt run; `boxed`: the records' own unknowns in their box.

        The steps are those of scipy's least_squares, solved on the n x n normal equations
        instead of a QR or SVD of the tall Jacobian: with tens of thousands of residuals and
        a dozen unknowns, that factorisation is what would cost, not the simulation.
        """
        # A nonlinear simulation costs about the same for a few parameter sets as for one
        # (its time goes to stepping, not arithmetic): try several dampings in one call.
        trials = 1 if self.structure.linear else 4
        wide = np.full(self.n - self.k, np.inf)
        lo = np.concatenate([self.lo, self.nuisance_lo if boxed else -wide])
        hi = np.concatenate([self.hi, self.nuisance_hi if boxed else wide])
        z = np.clip(z0, lo, hi)
        r = self.fun(z)
        cost = float(r @ r)
        if not np.isfinite(cost):
            return _Polished(z, r, np.zeros((r.size, self.n)), "not_finite", 0)
        if self.n == 0:
            return _Polished(z, r, np.zeros((r.size, 0)), "converged", 0)
        J = self.jac(z)
        mu, reason, done = damping, "iteration_limit", 0
        for _ in range(max_iter):
            if deadline is not None and time.perf_counter() > deadline:
                reason = "time_budget"
                break
            if self.blocked:  # many columns: see `gram`
                H, g = gram(J, True), np.einsum("mi,m->i", J, r)
            else:
                H, g = J.T @ J, J.T @ r
            d = np.maximum(np.diag(H), 1e-12 * max(np.diag(H).max(), 1e-300))
            # The step is clipped to the box: where the diagnosis's bent baselines end, and so
            # where its candidates start, depends on it (docs/identification.md). A record's
            # own unknown held on its bound by the gradient is left out of the step (an
            # active set), so that the others take Gauss-Newton steps, not clipped ones.
            move = np.ones(self.n, dtype=bool)
            move[self.k:] = ~(((z <= lo) & (g > 0)) | ((z >= hi) & (g < 0)))[self.k:]
            accepted = False
            while mu < 1e12 and not accepted:
                mus = mu * 4.0 ** np.arange(trials)
                Z = np.array([np.clip(z - _step(H, g, m * d, move), lo, hi) for m in mus])
                R = self.fun_many(Z)
                costs = np.einsum("pm,pm->p", R, R)
                for i in range(trials):  # the first damping that lowers the cost, as in turn
                    if np.isfinite(costs[i]) and costs[i] < cost:
                        z_new, r_new, c_new, mu = Z[i], R[i], float(costs[i]), mus[i]
                        accepted = True
                        break
                else:
                    mu = mus[-1] * 4.0
            if not accepted:
                reason = "converged"  # no step lowers the cost: a minimum to working precision
                break
            gain = (cost - c_new) / cost
            moved = np.max(np.abs(z_new - z) / (1.0 + np.abs(z)))
            z, r, cost = z_new, r_new, c_new
            done += 1
            mu = max(mu / 5.0, 1e-9)
            J = self.jac(z)
            if gain < gain_tol or moved < 1e-9:
                reason = "converged"
                break
        if trials == 1:  # r came from a call of z alone: what fun(z) would compute
            self._memo["fun"] = (np.asarray(z, dtype=float).tobytes(), r)
        return _Polished(z, r, J, reason, done)


@dataclass
class _Polished:
    """Where a polish ended and why (a key of STOP_REASONS), after how many accepted steps."""

    z: np.ndarray
    r: np.ndarray
    J: np.ndarray
    reason: str
    iterations: int
    free_cost: float | None = None
    """The cost at the optimum with the records' own unknowns free, where that optimum was
    not physical and the polish went on inside their box."""


def _correlation_time(e: np.ndarray) -> float:
    """Samples per independent one of a residual series, by its lag-1 autocorrelation."""
    if e.size < 10:
        return 1.0
    e = e - e.mean()
    den = float(e @ e)
    rho = float(np.clip(e[1:] @ e[:-1] / den, 0.0, 0.999)) if den > 0 else 0.0
    return (1.0 + rho) / (1.0 - rho)


def _step(H: np.ndarray, g: np.ndarray, damping: np.ndarray, move: np.ndarray) -> np.ndarray:
    """The damped Gauss-Newton step of the unknowns in `move`, zero for the others."""
    if move.all():
        return _solve(H + np.diag(damping), g)
    out = np.zeros(g.size)
    out[move] = _solve(H[np.ix_(move, move)] + np.diag(damping[move]), g[move])
    return out


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(A, b, rcond=None)[0]


class _Predicts:
    """Prediction from parameter values and, for the records a result was estimated on, its
    initial states and thermocouple offsets. Needs `structure`, `params`, `data`, `x0` and
    `zone_offsets_c` (None: no offsets), and `zone_offsets` (bool: a new record's offsets
    are estimated with its initial state)."""

    structure: ModelStructure
    params: dict[str, float]
    data: list[Experiment]
    x0: list[np.ndarray]
    zone_offsets_c: list[dict[str, float]] | None
    zone_offsets: bool

    @property
    def model(self) -> Model:
        """The structure with these parameter values and the offsets they carry, without
        records."""
        return Model(self.structure, dict(self.params), self.zone_offsets,
                     self.carried_offsets())

    def carried_offsets(self) -> np.ndarray | None:
        """The thermocouple offsets (zones,) carried to other records of the furnace: each
        zone's offsets over the records, weighted by their readings. None without offsets.
        Offsets belong to the sensors: a record of the same thermocouples starts from them."""
        if self.zone_offsets_c is None or not self.data:
            return None
        w = np.array([np.isfinite(e.zone_temp).sum(axis=0) for e in self.data], dtype=float)
        off = np.array([self.offsets(j) for j in range(len(self.data))])
        return (w * off).sum(axis=0) / np.maximum(w.sum(axis=0), 1.0)

    def offsets(self, j: int) -> np.ndarray:
        """Record j's zone offsets (zones,), zeros where none were estimated or held."""
        zones = self.structure.furnace.zones
        if self.zone_offsets_c is None:
            return np.zeros(len(zones))
        return np.array([self.zone_offsets_c[j][z] for z in zones], dtype=float)

    def _record(self, j: int) -> Experiment:
        if not 0 <= j < len(self.data):
            raise IndexError(f"record {j}: this result holds {len(self.data)} record(s)")
        return self.data[j]

    def response(self, record: int | Experiment, x0: np.ndarray | None = None,
                 states: bool = True) -> Response:
        """The simulated run on a record: an own record (index) from its fitted initial
        state, a new one from x0 (estimated from its data if None)."""
        if isinstance(record, int | np.integer):
            return self.model.response(self._record(int(record)), self.x0[int(record)], states)
        return self.model.response(record, x0, states)

    def predict(self, record: int | Experiment, x0: np.ndarray | None = None,
                offsets: np.ndarray | None = None) -> np.ndarray:
        """What the thermocouples read (N, 3) on a record, as its zone means.

        An own record (an index into `data`) starts from its fitted initial state and gets
        its fitted zone offsets. A new record (an Experiment): with x0 None its initial
        state, and its offsets where this result estimated offsets, are estimated from its
        data under these parameters (a new campaign's start and thermocouple biases are not
        the model's to predict); with x0 given the run starts there and `offsets` (3,; none
        if None) are added."""
        if isinstance(record, int | np.integer):
            j = int(record)
            return self.model.predict(self._record(j), self.x0[j], self.offsets(j))
        return self.model.predict(record, x0, offsets)

    def refine(self, data: Sequence[Experiment], free: Sequence[str] = (), *,
               x0: Sequence[np.ndarray] | None = None,
               offsets: Sequence[np.ndarray] | None = None,
               sigma: float | None = None) -> Refinement:
        """Re-estimate the parameters in `free` on other data, the others held at these
        values; see `Model.refine`."""
        return self.model.refine(data, free, x0=x0, offsets=offsets, sigma=sigma)


@dataclass
class FitResult(_Predicts):
    structure: ModelStructure
    params: dict[str, float]
    x0: list[np.ndarray]
    ci95: dict[str, tuple[float, float]]
    corr: np.ndarray
    undetermined: list[str]
    determined_combinations: list[str]
    warnings: list[str]
    per_zone: dict[str, dict[str, float]]
    sse: float
    n_obs: int
    elapsed_s: float
    runs: list[dict]
    method: str = "fast"
    status: str = "ok"  # ok | insufficient_excitation
    genetic_mean: dict[str, float] = field(default_factory=dict)
    sigma_c: float = float("nan")  # residual standard deviation
    combinations: dict[str, dict] = field(default_factory=dict)  # name -> {value, ci95}
    zone_offsets_c: list[dict[str, float]] | None = None  # per experiment: offset per zone
    uncertainty: Uncertainty | None = None
    std: dict[str, float] = field(default_factory=dict)  # own units; 0 fixed, NaN at a bound
    cov: np.ndarray | None = None  # own units, names order; fixed 0, at a bound NaN
    fixed: list[str] = field(default_factory=list)
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)  # searched box
    at_bound: dict[str, str] = field(default_factory=dict)  # name -> "lower" | "upper"
    stop_reason: str = ""  # a key of STOP_REASONS, for the best run
    iterations: int = 0  # accepted polish steps of the best run's result
    generations: int = 0  # GA generations of the best run
    criteria: Criteria | None = None
    ci95_white: dict[str, tuple[float, float]] = field(default_factory=dict)
    """The intervals were the residuals white (ci95 allows for their autocorrelation)."""
    profiled: list[str] = field(default_factory=list)
    """Parameters whose interval follows the criterion (profile likelihood)."""
    data: list[Experiment] = field(default_factory=list)
    """The fitted records, in order: `predict(j)` is record j as the fit models it."""
    zone_offsets_ci95_c: list[dict[str, list[float] | None]] | None = None
    """Per record, each zone offset's 95% interval; None on its bound."""
    bounds_c: list[dict] = field(default_factory=list)
    """Per record, the physical box of its offsets and initial temperatures (`_bounds_c`)."""
    flags: list[Flag] = field(default_factory=list)
    """The records' offsets and initial temperatures that ended on their physical bound."""

    @property
    def zone_offsets(self) -> bool:
        """Whether the fit estimated thermocouple offsets: a new record gets them too."""
        return self.zone_offsets_c is not None

    @property
    def stop_description(self) -> str:
        return STOP_REASONS.get(self.stop_reason, "")

    def to_json(self, data: list[str]) -> dict:
        """CONTRACTS.md section 5, plus the diagnostics of this fit."""
        return {
            "model": self.structure.furnace.model_label + ("" if not self.structure.effects
                                                           else "+" + self.structure.label),
            "furnace": self.structure.furnace.name,
            "effects": [{"name": e.name, "options": _plain(e.options)}
                        for e in self.structure.effects],
            "params": dict(self.params),
            "ci95": {k: [v[0], v[1]] for k, v in self.ci95.items()},
            "per_zone": self.per_zone,
            "runs": self.runs,
            "data": list(data),
            "elapsed_s": self.elapsed_s,
            "method": self.method,
            "status": self.status,
            "genetic_mean": self.genetic_mean,
            "undetermined": self.undetermined,
            "determined_combinations": self.determined_combinations,
            "combinations": self.combinations,
            "corr": {"names": list(self.ci95), "matrix": np.round(self.corr, 6).tolist()},
            "warnings": self.warnings,
            "x0": [np.round(x, 4).tolist() for x in self.x0],
            "sse": self.sse,
            "n_obs": self.n_obs,
            "sigma_c": self.sigma_c,
            "zone_offsets_c": self.zone_offsets_c,
            "zone_offsets_ci95_c": self.zone_offsets_ci95_c,
            "offsets_c": _zone_dict(self.structure, self.carried_offsets()),
            "bounds_c": self.bounds_c,
            "flags": [f.to_json() for f in self.flags],
            **self._report_json(),
        }

    def _report_json(self) -> dict:
        """What System Identification Toolbox's present, getcov, aic and fpe give."""
        names = self.structure.names
        cov = self.cov if self.cov is not None else np.zeros((len(names),) * 2)
        unc, ic = self.uncertainty, self.criteria
        return {
            "std": {k: _finite(v) for k, v in self.std.items()},
            "cov": {"names": list(names), "matrix": _finite(cov)},
            "cov_search": None if unc is None else {
                "names": list(unc.names), "scale": ["log" if g else "linear" for g in unc.log],
                "matrix": _finite(unc.cov)},
            "fixed": {k: self.params[k] for k in self.fixed},
            "bounds": {k: [lo, hi] for k, (lo, hi) in self.bounds.items()},
            "at_bound": dict(self.at_bound),
            "ci95_white": {k: [v[0], v[1]] for k, v in self.ci95_white.items()},
            "profiled": list(self.profiled),
            "residual_correlation_time": (self.uncertainty.correlation_time
                                          if self.uncertainty is not None else None),
            "stop_reason": self.stop_reason,
            "iterations": self.iterations,
            "generations": self.generations,
            **{k: None if ic is None else _finite(getattr(ic, k))
               for k in ("aic", "aicc", "bic", "naic", "fpe")},
            "n_estimated": None if ic is None else ic.n_params,
            "n_samples": None if ic is None else ic.n_samples,
        }


def _zone_dict(structure: ModelStructure, v: np.ndarray | None) -> dict[str, float] | None:
    return None if v is None else dict(zip(structure.furnace.zones, map(float, v), strict=True))


def _finite(v):
    """A number or array for JSON, which has no NaN or infinity: those become null."""
    if np.ndim(v):
        return [_finite(x) for x in v]
    return float(v) if np.isfinite(v) else None


def _plain(options: dict) -> dict:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in options.items()}


def fit(experiments: list[Experiment], structure: ModelStructure | None = None, *,
        method: str = "fast", runs: int = 1, population: int | None = None,
        generations: int | None = None, seed: int = 0,
        init: dict[str, float] | None = None,
        fixed: dict[str, float] | None = None,
        bounds: dict[str, tuple[float, float]] | None = None,
        progress: Callable[[float], None] | None = None,
        time_budget_s: float | None = None, zone_offsets: bool = False,
        profile: bool = True, warm: WarmStart | None = None) -> FitResult:
    """Fit the structure's parameters to the experiments (jointly; own initial state each).

    Run r uses seed + r. With `init` the global search is skipped: a warm-started polish,
    which is what a sliding-window refit wants. The best run (lowest SSE) is the result; the
    arithmetic mean of the runs is kept as the paper's 'genetic mean parameter'.
    `zone_offsets` adds a constant offset per zone and experiment: thermocouple biases the
    model cannot otherwise absorb, except by bending its parameters (per experiment, since
    thermocouples are replaced and recalibrated between campaigns). `profile`: the
    intervals of parameters the data leave wide follow the criterion (furnace_model.profile)
    instead of its quadratic approximation; a refit per trial value, so callers that only
    rank fits may leave it off.

    `warm` (with `init`): a sliding window's refit, which starts from the window before
    (see `WarmStart`); the same optimum and intervals, to the optimiser's and the profile's
    tolerances, for less work.
    """
    t_start = time.perf_counter()
    if method not in METHODS:
        raise FurnaceError(f"unknown method '{method}': use one of {', '.join(METHODS)}")
    if not experiments:
        raise FurnaceError("no data to fit")
    if runs < 1:
        raise FurnaceError("runs must be at least 1")
    structure = structure or ModelStructure()
    prob = _Problem(experiments, structure, fixed or {}, bounds or {}, zone_offsets)
    pop_default, gen_default = GA_DEFAULTS[method]
    population = int(population or pop_default)
    generations = int(generations if generations is not None else gen_default)
    deadline = None if time_budget_s is None else t_start + float(time_budget_s)
    start, spread = None, None
    if not init and method == "fast" and not structure.furnace.paper_structure:
        # a network of many zones: the search starts where the equations' least squares put
        # it, and a warm-started polish takes it from there (the parameters of an effect
        # that is not zone-affine from their defaults, searched over half their box)
        from .equationerror import equation_error

        init = {n: v for n, v in equation_error(structure, experiments).items()
                if n not in (fixed or {})}
    if init:
        start_vals = {**structure.defaults(), **init}
        start = prob.to_z(np.array([start_vals[n] for n in prob.names]))
        # Given values are searched near where they are; the others (an effect's parameters
        # on top of a baseline fit) over half their box around their defaults.
        spread = np.array([0.02 if n in init else 0.5 for n in prob.names])

    offsets = None
    if warm is not None and zone_offsets and warm.offsets is not None:
        if len(warm.offsets) != len(experiments):
            raise FurnaceError(f"warm start: offsets of {len(warm.offsets)} experiment(s) "
                               f"given for {len(experiments)}")
        offsets = [np.nan_to_num([float((o or {}).get(zone, 0.0))
                                  for zone in structure.furnace.zones])
                   for o in warm.offsets]
    results = []
    for r in range(runs):
        t_run = time.perf_counter()
        rng = np.random.default_rng(seed + r)

        def report(frac, r=r):
            if progress is not None:
                progress(min((r + frac) / runs, 1.0))

        run = _one_run(prob, method, population, generations, rng, start, spread, deadline,
                       report, offsets, 1e-3 if warm is None else WARM_DAMPING)
        results.append((run, seed + r, time.perf_counter() - t_run))
    report_done = progress or (lambda _f: None)
    report_done(1.0)

    run_dicts = []
    for run, s, dt in results:
        run_dicts.append({"seed": s, "method": method, "population": population,
                          "generations": run.generations, "params": _param_dict(prob, run.z),
                          "per_zone": _per_zone(prob, run.z), "sse": _sse(prob, run.z),
                          "elapsed_s": round(dt, 4), "stop_reason": run.stop_reason,
                          "iterations": run.iterations})
    best_run = results[int(np.argmin([d["sse"] for d in run_dicts]))][0]
    z = best_run.z
    res = prob.fun(z)
    J = prob.jac(z)
    held = prob.held_by_bounds(_Polished(z, res, J, best_run.stop_reason, 0, best_run.free_cost))
    unc = from_jacobian(prob.unflagged(J, held), res, prob.names, prob.log, z[:prob.k],
                        prob.series(), prob.blocked)
    flags = prob.flags(z, held)
    params = _param_dict(prob, z)
    ci = dict(zip(prob.names, unc.ci95(prob.lo_val, prob.hi_val), strict=True))
    ci_white = dict(zip(prob.names, unc.ci95(prob.lo_val, prob.hi_val, white=True), strict=True))
    for name, v in prob.fixed.items():
        ci[name] = ci_white[name] = (float(v), float(v))
    undetermined = unc.undetermined(prob.from_z(z[:prob.k]), prob.lo_val, prob.hi_val)
    profiled = {}
    if profile:
        wide = [n for i, n in enumerate(prob.names)
                if Z95 * np.sqrt(max(unc.cov[i, i], 0.0)) > PROFILE_WIDE]
        profiled = _profiled(prob, z, float(res @ res), unc, wide, deadline,
                             None if warm is None else warm.intervals)
        ci.update(profiled)
    named = unc.determined_combinations(undetermined)
    combos = [name for name, _ in named]
    combo_values = {}
    for name, coef in named:
        value, (lo, hi) = unc.combination_value(coef)
        combo_values[name] = {"value": value, "ci95": [lo, hi]}
    at_bound = prob.at_bound(z)
    warnings = _warnings(experiments, unc, undetermined, combos, best_run, time_budget_s,
                         at_bound, params) + [f.words() for f in flags]
    static = all(e.burner_steps == 0 for e in experiments)
    corr = np.eye(len(structure.names))
    cov = np.zeros((len(structure.names),) * 2)
    idx = [structure.names.index(n) for n in prob.names]
    corr[np.ix_(idx, idx)] = unc.corr
    cov[np.ix_(idx, idx)] = unc.cov_own_units
    for name in at_bound:  # a linearisation on the edge of the box says nothing about it
        cov[structure.names.index(name), :] = cov[:, structure.names.index(name)] = np.nan
    mean = {n: float(np.mean([d["params"][n] for d in run_dicts])) for n in structure.names}
    # The GA alone keeps each record's initial state at its first readings: not estimated.
    n_estimated = prob.k if method == "ga" else prob.n
    return FitResult(
        structure=structure, params=params,
        x0=[prob.x0_of(z, j).copy() for j in range(len(prob.records))],
        ci95={n: ci[n] for n in structure.names}, corr=corr, undetermined=undetermined,
        determined_combinations=combos, warnings=warnings, per_zone=_per_zone(prob, z),
        sse=float(res @ res), n_obs=prob.n_obs, elapsed_s=time.perf_counter() - t_start,
        runs=run_dicts, method=method,
        status="insufficient_excitation" if static else "ok", genetic_mean=mean,
        sigma_c=unc.sigma, combinations=combo_values,
        zone_offsets_c=([dict(zip(structure.furnace.zones, map(float, prob.offsets_of(z, j)),
                                  strict=True))
                         for j in range(len(experiments))] if zone_offsets else None),
        zone_offsets_ci95_c=_offset_intervals(prob, z, unc, flags) if zone_offsets else None,
        bounds_c=_bounds_c(prob), flags=flags,
        uncertainty=unc, ci95_white={n: ci_white[n] for n in structure.names},
        profiled=list(profiled),
        std={n: float(np.sqrt(max(cov[i, i], 0.0))) if np.isfinite(cov[i, i]) else float("nan")
             for i, n in enumerate(structure.names)},
        cov=cov, fixed=sorted(prob.fixed, key=structure.names.index),
        bounds={n: (float(lo), float(hi))
                for n, lo, hi in zip(prob.names, prob.lo_val, prob.hi_val, strict=True)},
        at_bound=at_bound, stop_reason=best_run.stop_reason, iterations=best_run.iterations,
        generations=best_run.generations,
        criteria=criteria(_residual_matrix(prob, z), n_estimated), data=list(experiments))


def _offset_intervals(prob: _Problem, z: np.ndarray, unc: Uncertainty,
                      flags: list[Flag]) -> list[dict[str, list[float] | None]]:
    """Per record, each zone offset's 95% interval (None where it sits on its bound: a
    bound is not an estimate)."""
    zones = prob.structure.furnace.zones
    held = {(f.record, f.zone) for f in flags if f.kind == "offset"}
    out = []
    for j, r in enumerate(prob.records):
        at = prob.block * j + prob.nz
        sd = unc.nuisance_sd[at:at + prob.nz] if unc.nuisance_sd.size else np.full(prob.nz, np.nan)
        off = prob.offsets_of(z, j)
        out.append({zone: None if (r.name, zone) in held or not np.isfinite(sd[w]) else
                    [float(off[w] - Z95 * sd[w]), float(off[w] + Z95 * sd[w])]
                    for w, zone in enumerate(zones)})
    return out


def _bounds_c(prob: _Problem) -> list[dict[str, dict[str, list[float | None]]]]:
    """Per record, what its own unknowns may physically be: {"offset": {zone: [lo, hi]},
    "initial": {zone: [lo, hi]}} (None: unbounded on that side)."""
    zones = prob.structure.furnace.zones

    def edge(v: float) -> float | None:
        return float(v) if np.isfinite(v) else None

    return [{"offset": {zone: [-float(r.bias[w]), float(r.bias[w])]
                        for w, zone in enumerate(zones)},
             "initial": {zone: [edge(r.x0_lo[w]), edge(r.x0_hi[w])]
                         for w, zone in enumerate(zones)}}
            for r in prob.records]


@dataclass(frozen=True)
class WarmStart:
    """What a sliding window's refit takes from the window before it, besides its parameter
    values (`fit`'s init): windows that overlap nearly wholly have their optimum, and their
    intervals' ends, next to each other's."""

    offsets: Sequence[Mapping[str, float] | None] | None = None
    """Per experiment, {zone: offset in °C}: where the zone offsets start, and the initial
    states at the first readings less them (a thermocouple's bias is in its reading). From
    zero and the readings the polish took eight or nine steps instead of two or three."""
    intervals: Mapping[str, tuple[float, float]] | None = None
    """{name: (low, high)}, own units: where each profile's search starts
    (`furnace_model.profile.profile_interval`'s `start`)."""


@dataclass
class _Run:
    """One run's end point, why its search stopped, and how far it went."""

    z: np.ndarray
    stop_reason: str
    iterations: int  # accepted polish steps of the result's polish
    generations: int  # GA generations run
    truncated: bool  # some stage (GA or polish) stopped on the time budget
    free_cost: float | None = None  # the polish's: see _Polished


def _profiled(prob: _Problem, z: np.ndarray, sse: float, unc: Uncertainty,
              names: list[str], deadline: float | None,
              starts: Mapping[str, tuple[float, float]] | None = None
              ) -> dict[str, tuple[float, float]]:
    """Profile-likelihood intervals of the named (wide) parameters, in their own units; the
    criterion's rise at the ends is the linearised interval's, with the residual's colour.
    `starts` (own units): where each search starts (a neighbouring window's ends)."""
    out = {}
    white = unc.cov_white if unc.cov_white is not None else unc.cov
    for name in names:
        i = prob.names.index(name)
        if deadline is not None and time.perf_counter() > deadline:
            break
        colour = unc.cov[i, i] / white[i, i] if white[i, i] > 0 else 1.0
        rise = Z95 ** 2 * unc.sigma ** 2 * colour
        # Start each refit where the linearisation puts the others for that value (along
        # the valley: d follows e at fixed d/e), not where they were; from there Gauss-Newton
        # steps (little damping) reach the minimum in two or three.
        along = np.delete(unc.cov[:, i] / unc.cov[i, i], i)
        rest = np.delete(z, i)

        def sse_at(z_i: float, i=i, rest=rest, along=along) -> float:
            start = rest.copy()
            start[:along.size] += along * (z_i - z[i])
            r = prob.holding(i, z_i).polish(start, deadline, 30, PROFILE_GAIN_TOL, 1e-7).r
            return float(r @ r)

        start = None
        if starts is not None and name in starts:  # on the search scale; NaN: no guide
            ends = np.asarray(starts[name], dtype=float)
            if prob.log[i]:
                ends = np.log(np.where(ends > 0, ends, np.nan))
            start = (float(ends[0]), float(ends[1]))
        lo, hi = profile_interval(sse_at, float(z[i]), Z95 * float(np.sqrt(unc.cov[i, i])),
                                  sse, rise, float(prob.lo[i]), float(prob.hi[i]), start)
        if prob.log[i]:
            out[name] = (float(np.exp(lo)), float(np.exp(hi)))
        else:
            out[name] = (float(lo), float(hi))
    return out


def _one_run(prob: _Problem, method: str, population: int, generations: int,
             rng: np.random.Generator, start: np.ndarray | None, spread: np.ndarray | None,
             deadline: float | None, report: Callable[[float], None],
             offsets: list[np.ndarray] | None = None, damping: float = 1e-3) -> _Run:
    if prob.k == 0:
        p = prob.polish(prob.start(np.zeros(0)), deadline)
        return _Run(p.z, p.reason, p.iterations, 0, p.reason == "time_budget", p.free_cost)
    if method == "fast" and start is not None and np.all(spread < 0.1):
        # every value given: polish
        p = prob.polish(prob.start(start, offsets), deadline, damping=damping)
        report(1.0)
        return _Run(p.z, p.reason, p.iterations, 0, p.reason == "time_budget", p.free_cost)
    ga_deadline = deadline
    if deadline is not None and method == "fast":
        ga_deadline = time.perf_counter() + 0.5 * (deadline - time.perf_counter())
    share = 0.8 if method == "fast" else 1.0
    found = genetic_search(prob.sse_params, prob.lo, prob.hi, population=population,
                           generations=generations, rng=rng, start=start,
                           spread=spread if start is not None else 1.0,
                           progress=lambda f: report(share * f), deadline=ga_deadline)
    ga_cut = found.generations < generations  # only the deadline ends it early
    if method == "ga":
        return _Run(prob.start(found.best), "time_budget" if ga_cut else "ga_generations", 0,
                    found.generations, ga_cut)
    # Polish the best few distinct members: the GA's best may sit in a side valley. A warm
    # start is always among them: the extended model may be the baseline with its effect off.
    polished: list[_Polished] = []
    picked: list[np.ndarray] = []
    first = [] if start is None else [np.clip(start, prob.lo, prob.hi)]
    for cand in [*first, *found.population]:
        if len(picked) == 3 + len(first):
            break
        if any(np.max(np.abs(cand - p)) < 0.3 for p in picked):
            continue
        picked.append(cand)
        polished.append(prob.polish(prob.start(cand, offsets), deadline))
    report(1.0)
    best = min(polished, key=lambda p: np.nan_to_num(float(p.r @ p.r), nan=np.inf))
    cut = ga_cut or any(p.reason == "time_budget" for p in polished)
    return _Run(best.z, best.reason, best.iterations, found.generations, cut, best.free_cost)


def _param_dict(prob: _Problem, z: np.ndarray) -> dict[str, float]:
    v = prob.values(z[:prob.k][None])
    return {n: float(v[n][0]) for n in prob.structure.names}


def _sse(prob: _Problem, z: np.ndarray) -> float:
    r = prob.fun(z)
    return float(r @ r)


def _measured_and_model(prob: _Problem, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Measured (NaN where missing) and modelled readings of all records, stacked (N, 3)."""
    return prob.remembered("readings", z, lambda: _readings(prob, z))


def _readings(prob: _Problem, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    vals = prob.values(z[:prob.k][None])
    meas, model = [], []
    for j, r in enumerate(prob.records):
        meas.append(np.where(r.mask, r.y, np.nan))
        model.append(prob.predict(j, vals, prob.x0_of(z, j)[None])[0] + prob.offsets_of(z, j))
    return np.concatenate(meas), np.concatenate(model)


def _per_zone(prob: _Problem, z: np.ndarray) -> dict[str, dict[str, float]]:
    return zone_metrics(*_measured_and_model(prob, z), prob.structure.furnace.zones)


def _residual_matrix(prob: _Problem, z: np.ndarray) -> np.ndarray:
    measured, model = _measured_and_model(prob, z)
    return measured - model


def _warnings(experiments, unc: Uncertainty, undetermined: list[str], combos: list[str],
              run: _Run, budget, at_bound: dict[str, str],
              params: dict[str, float]) -> list[str]:
    out = []
    for e in experiments:
        if e.burner_steps == 0:
            out.append(f"{e.name}: no burner change in the data: too little excitation to "
                       "identify the model; do not trust these values")
    for name, side in at_bound.items():
        out.append(f"{name} ended on the {side} bound of its search range ({params[name]:g}): "
                   "the best fit within the range lies on its edge, so the value is the "
                   "bound, not an estimate, and no sd or interval applies to it")
    if undetermined:
        pairs = [c for c in combos if c not in unc.names]
        out.append(f"the data do not determine {', '.join(undetermined)} (95% interval wider "
                   f"than +-{100 * WIDE:.0f}%)"
                   + (f"; they do determine {', '.join(pairs)}" if pairs else ""))
    for a, b, r in unc.strong_correlations():
        out.append(f"{a} and {b} are strongly correlated (r = {r:+.3f}): the data fix a "
                   "combination of them better than either")
    if run.truncated:
        out.append(f"time budget of {budget:g} s ran out: the search stopped early")
    elif run.stop_reason == "iteration_limit":
        out.append(f"the least-squares polish did not converge in {POLISH_MAX_ITER} iterations")
    elif run.stop_reason == "not_finite":
        out.append("the model could not be simulated where the polish started: these values "
                   "are that start, not a fit")
    return out


def score(params: dict, experiments: list[Experiment],
          structure: ModelStructure | None = None, zone_offsets: bool = False,
          offsets: np.ndarray | None = None) -> dict:
    """Per-zone MAE, RMSE and fit % of given parameters on experiments (the paper's
    Table VI), each experiment's initial state (and with `zone_offsets` its thermocouple
    offsets, from the carried `offsets`) estimated from its data."""
    structure = structure or ModelStructure()
    missing = [n for n in structure.names if n not in params]
    if missing:
        raise FurnaceError(f"parameter(s) {', '.join(missing)} missing for {structure.label}")
    return Model(structure, params, zone_offsets, offsets).refine(experiments).per_zone


@dataclass
class Model:
    """A structure with parameter values and no records: what a parameter file holds.
    `zone_offsets`: a record's thermocouple offsets are estimated with its initial state,
    starting from `offsets` (zones,; the fitted records' own, carried) and held within the
    bias a thermocouple can have."""

    structure: ModelStructure
    params: dict[str, float]
    zone_offsets: bool = False
    offsets: np.ndarray | None = None

    def __post_init__(self):
        missing = [n for n in self.structure.names if n not in self.params]
        if missing:
            raise FurnaceError(f"parameter(s) {', '.join(missing)} missing for "
                               f"{self.structure.label}")
        self.params = {n: float(self.params[n]) for n in self.structure.names}
        if self.offsets is not None:
            self.offsets = np.asarray(self.offsets, dtype=float).reshape(self.structure.n_zones)

    @property
    def model(self) -> Model:
        return self

    def response(self, exp: Experiment, x0: np.ndarray | None = None,
                 states: bool = True) -> Response:
        """The simulated run on exp's samples from zone temperatures (or all states) x0;
        x0 estimated from exp's data if None."""
        if x0 is None:
            x0 = self.refine([exp]).x0[0]
        return self.structure.simulate(self.params, exp.inputs(), exp.t_min,
                                       np.asarray(x0, dtype=float)[None], states=states)

    def predict(self, exp: Experiment, x0: np.ndarray | None = None,
                offsets: np.ndarray | None = None) -> np.ndarray:
        """What exp's thermocouples read (N, 3) as zone means. With x0 None the initial
        state (and with `zone_offsets` the offsets) are estimated from exp; else the run
        starts at x0 and `offsets` (zones,; none if None) are added."""
        if x0 is None:
            return self.refine([exp]).predict(0)
        prob = _Problem([exp], self.structure, self.params, {},
                        held_offsets=None if offsets is None else [offsets])
        return prob.predict(0, prob.values(np.zeros((1, 0))), np.asarray(x0, float)[None])[0]

    def refine(self, data: Sequence[Experiment], free: Sequence[str] = (), *,
               x0: Sequence[np.ndarray] | None = None,
               offsets: Sequence[np.ndarray] | None = None,
               sigma: float | None = None) -> Refinement:
        """Re-estimate the parameters named in `free` on `data`, the others held at these
        values, with each record's initial state (and with `zone_offsets` its thermocouple
        offsets): what scoring held-out records needs (their start and biases are theirs,
        and a parameter the fitted data did not see is theirs to set), and what a recent
        span of a long window says about one parameter. Estimated offsets start from the
        carried ones (`offsets`) and stay within the thermocouples' bias bound, the initial
        states within what the record allows (`furnace_model.plausible`); either on its
        bound is flagged (`Refinement.flags`).

        The free parameters are shared by all records. With none free each record is
        estimated alone: its initial state cannot depend on which other records were passed.
        x0 (per record, zone temperatures or all states) starts the search of the initial
        states (the first readings if None). `offsets` (per record, (3,)) are held, not
        estimated: offsets known from more data than a span holds. `sigma` (°C) is the
        noise level for the free parameters' covariance; None takes the refinement's own
        residual.
        """
        data = list(data)
        free = tuple(free)
        unknown = [n for n in free if n not in self.structure.names]
        if unknown:
            raise FurnaceError(f"unknown parameter(s) {unknown}; the model has "
                               f"{self.structure.names}")
        if not data:
            raise FurnaceError("no data to refine on")
        fixed = {n: v for n, v in self.params.items() if n not in free}
        estimate = self.zone_offsets and offsets is None
        groups = [list(range(len(data)))] if free else [[j] for j in range(len(data))]
        nz = self.structure.n_zones
        x0s: list[np.ndarray] = [np.zeros(nz)] * len(data)
        offs: list[np.ndarray] = [np.zeros(nz)] * len(data)
        params = dict(self.params)
        sse, n_obs, reasons, iterations = 0.0, 0, [], 0
        flags: list[Flag] = []
        cov = np.zeros((len(free), len(free)))
        carried = None if self.offsets is None or not estimate else [self.offsets] * len(data)
        for group in groups:
            prob = _Problem([data[j] for j in group], self.structure, fixed, {}, estimate,
                            None if offsets is None else [offsets[j] for j in group])
            start = prob.start(prob.to_z(np.array([self.params[n] for n in prob.names])),
                               None if carried is None else [carried[j] for j in group])
            if x0 is not None:
                for i, j in enumerate(group):
                    at = prob.k + prob.block * i
                    start[at:at + nz] = np.asarray(x0[j], dtype=float)[:nz]
            p = prob.polish(start, None)
            flags += prob.flags(p.z, prob.held_by_bounds(p))
            for i, j in enumerate(group):
                x0s[j] = prob.x0_of(p.z, i).copy()
                offs[j] = (prob.offsets_of(p.z, i).copy() if offsets is None
                           else np.asarray(offsets[j], dtype=float))
            sse += float(p.r @ p.r)
            n_obs += prob.n_obs
            reasons.append(p.reason)
            iterations += p.iterations
            if free:
                params.update(_param_dict(prob, p.z))
                cov = _free_cov(prob, p, sigma)
        std = {n: float(np.sqrt(cov[i, i])) if np.isfinite(cov[i, i]) else float("nan")
               for i, n in enumerate(free)}
        by_zone = None
        if estimate or offsets is not None:
            by_zone = [dict(zip(self.structure.furnace.zones, map(float, o), strict=True))
                       for o in offs]
        return Refinement(
            structure=self.structure, params=params, free=free, data=data, x0=x0s,
            zone_offsets_c=by_zone, zone_offsets=self.zone_offsets, std=std, cov=cov,
            sse=sse, n_obs=n_obs,
            stop_reason=next((r for r in reasons if r != "converged"), "converged"),
            iterations=iterations, flags=flags, carried_c=self.offsets if estimate else None)


def _free_cov(prob: _Problem, polished: _Polished, sigma: float | None) -> np.ndarray:
    """Covariance (own units) of the free parameters, the initial states and offsets
    marginalised out, the residuals taken as white with standard deviation sigma (the
    refinement's own if None). NaN where the data do not determine them."""
    J = polished.J
    k = prob.k
    if sigma is None:
        sigma = float(np.sqrt(polished.r @ polished.r / max(J.shape[0] - J.shape[1], 1)))
    normal = gram(J, prob.blocked)
    if not np.all(np.isfinite(normal)) or np.linalg.cond(normal) > 1e12:
        return np.full((k, k), np.nan)
    cov = sigma ** 2 * np.linalg.inv(normal)[:k, :k]
    scale = np.where(prob.log, prob.from_z(polished.z[:k]), 1.0)  # d p = p d log p
    return cov * np.outer(scale, scale)


@dataclass
class Refinement(_Predicts):
    """Parameters re-estimated on records (`free`; the others held), with the records'
    initial states and offsets: it predicts its records, and new ones, as a fit does."""

    structure: ModelStructure
    params: dict[str, float]
    free: tuple[str, ...]
    data: list[Experiment]
    x0: list[np.ndarray]
    zone_offsets_c: list[dict[str, float]] | None
    zone_offsets: bool
    std: dict[str, float]
    """The free parameters' standard deviations, own units (white residuals of `sigma`)."""
    cov: np.ndarray
    """Their covariance, own units, in `free` order."""
    sse: float
    n_obs: int
    stop_reason: str
    iterations: int
    flags: list[Flag] = field(default_factory=list)
    """The records' offsets and initial temperatures that ended on their physical bound."""
    carried_c: np.ndarray | None = None
    """The offsets (zones,) the estimated ones started from: the model's, carried."""

    def corrections(self) -> list[dict[str, float]] | None:
        """Per record, how far its estimated offsets moved from the carried ones, per zone
        (None unless offsets were estimated from carried ones)."""
        if self.carried_c is None or self.zone_offsets_c is None:
            return None
        return [{z: o[z] - float(c) for z, c in zip(self.structure.furnace.zones, self.carried_c,
                                                     strict=True)}
                for o in self.zone_offsets_c]

    @property
    def per_zone(self) -> dict[str, dict[str, float]]:
        """MAE, RMSE and fit % per zone over the records (the paper's Table VI)."""
        return zone_metrics(np.concatenate([e.zone_temp for e in self.data]),
                            np.concatenate([self.predict(j) for j in range(len(self.data))]),
                            self.structure.furnace.zones)
