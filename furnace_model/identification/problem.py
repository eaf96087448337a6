"""The least-squares problem of a fit: records made ready for repeated simulation, the
unknown vector, its residuals and Jacobian, and the polish that walks it down."""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
from scipy.special import chdtri

from ..errors import FurnaceError
from ..experiment import Experiment
from ..simulation.response import Response
from ..simulation.structure import Batch, Inputs, ModelStructure
from .jacobian import jacobian
from .plausible import FLAG_LEVEL, Flag, start_band, zone_bias_bounds
from .scores import zone_metrics
from .uncertainty import gram

_T = TypeVar("_T")
_CELLS = 4_000_000
"""Model values (sets x samples x zones) per simulator call in the GA: about 32 MB each."""
POLISH_MAX_ITER = 60
POLISH_GAIN_TOL = 1e-7
"""The polish has converged when a step lowers the cost by less than this share of it: with
1e4 residuals at the noise, a thousandth of the noise variance, where an estimate moves by
a few hundredths of its sd. A tighter one keeps most polishes stepping to their iteration
limit for gains that change nothing (docs/performance.md)."""
POLISH_NOISE_SHARE = 1e-3
"""Nor does it go on once a step lowers the cost by less than this share of the residuals'
variance: what POLISH_GAIN_TOL comes to at 1e4 residuals, held on shorter records too. A
window of a furnace in production has about a thousand, where the relative tolerance alone
asks a ten-thousandth of the variance, a gain a polish along a valley's floor finds step
after step (docs/performance.md)."""
OUTSIDE_GAIN_TOL = 1e-3
"""An integrated model's polish with the records' own unknowns left free stops once they lie
outside their box and a step lowers the cost by less than this share: that optimum is not
physical, so the boxed polish that follows replaces it, and each step towards it costs a
simulation per unknown (docs/performance.md, "An integrated model's free polish")."""
STOP_REASONS = {
    "converged": f"the polish converged: its last step changed the cost by less than "
                 f"{POLISH_GAIN_TOL:g} relative or {POLISH_NOISE_SHARE:g} of the residuals' "
                 "variance, or the unknowns by less than 1e-9, or no step lowered the cost",
    "iteration_limit": f"the polish reached its limit of {POLISH_MAX_ITER} iterations before "
                       "converging",
    "time_budget": "the time budget ran out before the search finished",
    "ga_generations": "the genetic algorithm ran all its generations; method ga has no polish",
    "not_finite": "the model cannot be simulated at the point the polish started from",
    "above": "the polish's cost stays above the level asked whatever its steps left take "
             "(a profile's trial outside its interval)",
}
"""Why a run's search stopped (FitResult.stop_reason, the runs' stop_reason)."""



@dataclass
class Record:
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
           structure: ModelStructure | None = None) -> Record:
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
        return cls(exp.t_min, np.where(mask, y, 0.0), mask, Inputs.of(exp), np.clip(guess, lo, hi),
                   weight, bool(mask.all()), zone_of, exp.name, bias, lo, hi)


class Problem:
    """The least-squares problem: unknown vector = free parameters (log scale where the
    parameter is positive) followed by the initial zone temperatures of each experiment
    (and its zone offsets when fitted), one per zone. The records' own unknowns are held to
    what they can physically be (`furnace_model.identification.plausible`): the box `nuisance_lo`,
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
        self.records = [Record.of(e, structure.has_sensor_offsets, structure)
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

    def holding(self, i: int, z_i: float) -> Problem:
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
                first_order: np.ndarray | None = None, batch: Batch = "together") -> np.ndarray:
        """Model zone temperatures (P, N, zones) for experiment j; the sets marked in
        `first_order` (P,) to first order in the nonlinear terms (`jac`). `batch`: what the
        sets are to each other (`Batch`)."""
        r = self.records[j]
        with np.errstate(all="ignore"):
            if first_order is None:
                response = self._simulate(values, r, x0, batch)
            else:
                response = self._simulate_split(values, r, x0, first_order, batch)
            y = response.readings(weight=r.tc_weight)
        return y if self.held is None else y + self.held[j]

    def _simulate(self, values: dict[str, np.ndarray], r: Record, x0: np.ndarray,
                  batch: Batch = "together") -> Response:
        return self.structure.simulate(values, r.inputs, r.t, x0, batch=batch)

    def _simulate_split(self, values: dict[str, np.ndarray], r: Record, x0: np.ndarray,
                        first_order: np.ndarray, batch: Batch) -> Response:
        x0 = np.broadcast_to(x0, (first_order.size, x0.shape[-1]))
        fo, full = np.nonzero(first_order)[0], np.nonzero(~first_order)[0]
        out = np.empty((first_order.size, r.t.size, self.nz))
        out[full] = self._simulate({k: v[full] for k, v in values.items()}, r, x0[full],
                                   batch).zones
        out[fo] = self.structure.simulate_first_order({k: v[fo] for k, v in values.items()},
                                                      r.inputs, r.t, x0[fo])
        return Response(r.t, out, self.structure, values)

    def residuals(self, j: int, values: dict[str, np.ndarray], x0: np.ndarray,
                  first_order: np.ndarray | None = None, batch: Batch = "together"
                  ) -> np.ndarray:
        r = self.records[j]
        diff = self.predict(j, values, x0, first_order, batch) - r.y
        return diff.reshape(diff.shape[0], -1) if r.complete else diff[:, r.mask]

    def sse_params(self, zp: np.ndarray, own: np.ndarray | None = None) -> np.ndarray:
        """SSE (P,) for parameter sets (P, k), initial states at the first readings: the
        GA's objective, one simulation call per experiment for the whole population (in
        slices of about _CELLS values, so a long 1-second window stays within memory).

        `own`: the records' own unknowns (n - k,: initial states, and zone offsets when
        fitted) held there instead. A search around a warm start then scores the criterion
        its polish minimises, not one that the thermocouples' offsets bend."""
        total = np.zeros(zp.shape[0])
        for j, r in enumerate(self.records):
            x0, offsets = r.x0_guess, None
            if own is not None:
                at = self.block * j
                x0 = own[at:at + self.nz]
                if self.offsets_fitted:
                    offsets = own[at + self.nz:at + 2 * self.nz][r.zone_of]
            step = max(1, _CELLS // (self.nz * r.t.size))
            for p0 in range(0, zp.shape[0], step):
                sl = slice(p0, p0 + step)
                res = self.residuals(j, self.values(zp[sl]), x0[None], batch="each")
                if offsets is not None:
                    res = res + offsets
                total[sl] += np.einsum("pm,pm->p", res, res)
        return np.where(np.isfinite(total), total, np.inf)

    def x0_of(self, z: np.ndarray, j: int) -> np.ndarray:
        i = self.k + self.block * j
        return z[i:i + self.nz]

    def offsets_of(self, z: np.ndarray, j: int) -> np.ndarray:
        i = self.k + self.block * j + self.nz
        return z[i:i + self.nz] if self.offsets_fitted else np.zeros(self.nz)

    def at_bound(self, z: np.ndarray, share: float = 1e-6) -> dict[str, str]:
        """Free parameters within `share` of their search box's width (search scale) of an
        edge: {name: side}."""
        tol = share * (self.hi - self.lo)
        out = {}
        for i, name in enumerate(self.names):
            if z[i] <= self.lo[i] + tol[i]:
                out[name] = "lower"
            elif z[i] >= self.hi[i] - tol[i]:
                out[name] = "upper"
        return out

    def start(self, zp: np.ndarray, offsets: Sequence[np.ndarray] | None = None,
              x0: Sequence[np.ndarray] | None = None) -> np.ndarray:
        """The unknown vector from parameters zp: each record's initial state at its first
        readings, its zone offsets at zero, or at `offsets` (per record) when fitted and given,
        and then the first readings less them (a thermocouple's bias is in its reading), or
        at `x0` (per record, with `offsets`): where another fit of the records ended;
        inside the records' physical box."""
        per = []
        for j, r in enumerate(self.records):
            if offsets is None or not self.offsets_fitted:
                per.append(np.concatenate([r.x0_guess, np.zeros(self.block - self.nz)]))
            else:
                off = np.asarray(offsets[j], dtype=float)
                at = r.x0_guess - off if x0 is None else np.asarray(x0[j], dtype=float)
                per.append(np.concatenate([at, off]))
        own = np.clip(np.concatenate(per), self.nuisance_lo, self.nuisance_hi) if per else []
        return np.concatenate([zp, own])

    def held_by_bounds(self, polished: Polished) -> np.ndarray:
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
        tau = max([correlation_time(r[idx]) for idx in self.series()], default=1.0)
        rise = (float(r @ r) - polished.free_cost) / (sigma2 * tau)
        return on if rise > chdtri(int(on.sum()), 1.0 - FLAG_LEVEL) else np.zeros(on.size, dtype=bool)

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
        hit = self._memo.get(what)
        key = np.asarray(z, dtype=float).tobytes()
        if hit is None or hit[0] != key:
            hit = self._memo[what] = (key, compute())
        return hit[1]

    def _remembered_fun(self, z: np.ndarray) -> Generator[np.ndarray, np.ndarray, np.ndarray]:
        """`fun(z)` inside a polish (`_polish`): remembered as `remembered` does, the
        residuals asked for by yielding z where they are not."""
        key, hit = np.asarray(z, dtype=float).tobytes(), self._memo.get("fun")
        if hit is None or hit[0] != key:
            hit = self._memo["fun"] = (key, (yield z[None])[0])
        return hit[1]

    def fun(self, z: np.ndarray) -> np.ndarray:
        return self.remembered("fun", z, lambda: self.fun_many(z[None])[0])

    def fun_many(self, Z: np.ndarray) -> np.ndarray:
        """Residuals (P, m) of unknown vectors (P, n), each experiment in one batched call;
        each vector scored on its own (never differenced against the others)."""
        vals = self.values(Z[:, :self.k])
        out, nz = [], self.nz
        for j, r in enumerate(self.records):
            i = self.k + self.block * j
            res = self.residuals(j, vals, Z[:, i:i + nz], batch="each")
            out.append(res + Z[:, i + nz:i + 2 * nz][:, r.zone_of] if self.offsets_fitted
                       else res)
        return np.concatenate(out, axis=1)

    def jac(self, z: np.ndarray) -> np.ndarray:
        return self.remembered("jac", z, lambda: jacobian(self, z))

    def polish(self, z0: np.ndarray, deadline: float | None, max_iter: int = POLISH_MAX_ITER,
               gain_tol: float = POLISH_GAIN_TOL, damping: float = 1e-3,
               free_first: bool = True, above: float | None = None
               ) -> Polished:
        """Levenberg-Marquardt from z0, parameters kept in their box and the records' own
        unknowns in theirs; converged when a step lowers the cost by less than `gain_tol`
        of it. `damping`: the first step's, small for a start already near the minimum
        (Gauss-Newton converges there in a few steps).

        The records' own unknowns are first left free: where that optimum is physical it is
        the answer, reached by the path the parameters would take anyway; where it is not,
        the polish goes on from it inside their box. Boxed from the start, a bound that the
        optimum does not touch can still block the path to it and leave the fit in a side
        valley (docs/identification.md). `free_first=False`: boxed from the start, for a start
        next to a boxed optimum already found (a profile's trial values), whose bounds are
        already the ones that hold.

        `above`: a level of the cost that is all the caller asks about (a profile's trial,
        outside its interval or not). The polish stops ("above") once its cost less what
        the steps left to it could take at its last step's gain stays above that level: a
        trial far outside need not be refitted to the end to be known outside."""
        return self.polish_many([z0], deadline, max_iter, gain_tol, damping, free_first,
                                above)[0]

    def polish_many(self, starts: Sequence[np.ndarray], deadline: float | None,
                    max_iter: int = POLISH_MAX_ITER, gain_tol: float = POLISH_GAIN_TOL,
                    damping: float = 1e-3, free_first: bool = True,
                    above: float | None = None) -> list[Polished]:
        """`polish` from each start, each run on its own but their residuals evaluated
        together: a linear structure's batched simulation of a few parameter sets costs
        little more than one's, and gives each set what it gives alone: to the bit while
        the batch is simulated the way one set is, to rounding where its size takes the
        simulator another way (`lti.response`). A nonlinear one's runs go one after
        another: its batch agrees with each set alone only to rounding whatever its size,
        and a polish's path may turn on a rounding."""
        runs = [self._polish_run(z0, deadline, max_iter, gain_tol, damping, free_first, above)
                for z0 in starts]
        if not self.structure.linear:
            return [_driven(self, [run])[0] for run in runs]
        return _driven(self, runs)

    def _polish_run(self, z0: np.ndarray, deadline: float | None, max_iter: int,
                    gain_tol: float, damping: float, free_first: bool, above: float | None
                    ) -> PolishRun:
        if not free_first:
            return (yield from self._polish(z0, deadline, max_iter, gain_tol, damping,
                                            boxed=True, above=above))
        free = yield from self._polish(z0, deadline, max_iter, gain_tol, damping, boxed=False)
        if free.reason == "not_finite" or not self._outside(free.z):
            return free
        boxed = yield from self._polish(free.z, deadline, max_iter, gain_tol, damping,
                                        boxed=True)
        boxed.free_cost = float(free.r @ free.r)
        return boxed

    def _polish(self, z0: np.ndarray, deadline: float | None, max_iter: int,
                gain_tol: float, damping: float, boxed: bool, above: float | None = None
                ) -> PolishRun:
        """One Levenberg-Marquardt run; `boxed`: the records' own unknowns in their box.
        A generator: it yields the unknown vectors (P, n) whose residuals it needs and is
        sent them (P, m) (`_driven`).

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
        r = yield from self._remembered_fun(z)
        cost = float(r @ r)
        if not np.isfinite(cost):
            return Polished(z, r, np.zeros((r.size, self.n)), "not_finite", 0)
        if self.n == 0:
            return Polished(z, r, np.zeros((r.size, 0)), "converged", 0)
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
            # An unknown held on its bound by the gradient is left out of the step (an
            # active set), so that the others take Gauss-Newton steps; clipped after the
            # step instead, they would crawl along the bound to the iteration limit.
            move = ~(((z <= lo) & (g > 0)) | ((z >= hi) & (g < 0)))
            accepted = False
            while mu < 1e12 and not accepted:
                mus = mu * 4.0 ** np.arange(trials)
                Z = np.array([np.clip(z - _bounded_step(H, g, m * d, move, z, lo, hi), lo, hi)
                              for m in mus])
                R = yield Z
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
            drop = cost - c_new
            gain = drop / cost
            moved = np.max(np.abs(z_new - z) / (1.0 + np.abs(z)))
            z, r, cost = z_new, r_new, c_new
            done += 1
            mu = max(mu / 5.0, 1e-9)
            if above is not None and c_new - (max_iter - done) * drop > above:
                return Polished(z, r, np.full((r.size, self.n), np.nan), "above", done)
            J = self.jac(z)
            noise = POLISH_NOISE_SHARE * c_new / max(self.n_obs - self.n, 1)
            if gain < gain_tol or drop < noise or moved < 1e-9 or (
                    not boxed and not self.structure.linear and gain < OUTSIDE_GAIN_TOL
                    and self._outside(z)):
                reason = "converged"
                break
        if trials == 1:  # r came from a call of z alone: what fun(z) would compute
            self._memo["fun"] = (np.asarray(z, dtype=float).tobytes(), r)
        return Polished(z, r, J, reason, done)

    def _outside(self, z: np.ndarray) -> bool:
        """Whether a record's own unknown lies outside its box."""
        own = z[self.k:]
        return bool(np.any((own < self.nuisance_lo) | (own > self.nuisance_hi)))

    def param_dict(self, z: np.ndarray) -> dict[str, float]:
        v = self.values(z[:self.k][None])
        return {n: float(v[n][0]) for n in self.structure.names}

    def sse(self, z: np.ndarray) -> float:
        r = self.fun(z)
        return float(r @ r)

    def measured_and_model(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Measured (NaN where missing) and modelled readings of all records, stacked (N, 3)."""
        return self.remembered("readings", z, lambda: self.readings(z))

    def readings(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        vals = self.values(z[:self.k][None])
        meas, model = [], []
        for j, r in enumerate(self.records):
            meas.append(np.where(r.mask, r.y, np.nan))
            model.append(self.predict(j, vals, self.x0_of(z, j)[None])[0] + self.offsets_of(z, j))
        return np.concatenate(meas), np.concatenate(model)

    def per_zone(self, z: np.ndarray) -> dict[str, dict[str, float]]:
        return zone_metrics(*self.measured_and_model(z), self.structure.furnace.zones)

    def residual_matrix(self, z: np.ndarray) -> np.ndarray:
        measured, model = self.measured_and_model(z)
        return measured - model


@dataclass
class Polished:
    """Where a polish ended and why (a key of STOP_REASONS), after how many accepted steps;
    J is NaN where it stopped "above" (no caller of such a polish needs it)."""

    z: np.ndarray
    r: np.ndarray
    J: np.ndarray
    reason: str
    iterations: int
    free_cost: float | None = None
    """The cost where the polish with the records' own unknowns free ended, where that end
    was not physical and the polish went on inside their box: at or above the free optimum
    (an integrated model's stops short of it, `OUTSIDE_GAIN_TOL`), so that a bound that
    `held_by_bounds` finds costly is at least that costly."""


PolishRun = Generator[np.ndarray, np.ndarray, Polished]
"""A polish in progress (`Problem._polish`): yields unknown vectors, is sent their residuals."""


def _driven(prob: Problem, runs: list[PolishRun]) -> list[Polished]:
    """Each run to its end, the residuals all of them ask for at once from one batched
    evaluation (`Problem.fun_many`); their ends, in order."""
    ends: list[Polished | None] = [None] * len(runs)
    asked: dict[int, np.ndarray] = {}
    for i, run in enumerate(runs):
        try:
            asked[i] = next(run)
        except StopIteration as end:
            ends[i] = end.value
    while asked:
        rows = np.cumsum([0] + [Z.shape[0] for Z in asked.values()])
        R = prob.fun_many(np.concatenate(list(asked.values())))
        now = {}
        for (i, _), a, b in zip(asked.items(), rows[:-1], rows[1:], strict=True):
            try:
                now[i] = runs[i].send(R[a:b])
            except StopIteration as end:
                ends[i] = end.value
        asked = now
    return ends  # type: ignore[return-value]


def correlation_time(e: np.ndarray) -> float:
    """Samples per independent one of a residual series, by its lag-1 autocorrelation."""
    if e.size < 10:
        return 1.0
    e = e - e.mean()
    den = float(e @ e)
    rho = float(np.clip(e[1:] @ e[:-1] / den, 0.0, 0.999)) if den > 0 else 0.0
    return (1.0 + rho) / (1.0 - rho)


def _bounded_step(H: np.ndarray, g: np.ndarray, damping: np.ndarray, move: np.ndarray,
                  z: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The damped step of the unknowns in `move`, those it would carry past a bound they sit
    on held there as well and the step solved again. Freed by the gradient alone, such an
    unknown would be clipped back after the step, which is then no longer the one solved
    for: the rejections that follow raise the damping a hundredfold every few steps, and a
    network with many rates on their bounds crawls to the iteration limit
    (docs/performance.md, "The active set held by the step")."""
    step = _step(H, g, damping, move)
    for _ in range(g.size):
        out = move & (((z <= lo) & (z - step < lo)) | ((z >= hi) & (z - step > hi)))
        if not out.any():
            break
        move = move & ~out
        step = _step(H, g, damping, move)
    return step


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
