"""The paper's model (eq. 11) with optional effect terms: baseline, plant and candidates.

`ModelStructure(furnace=F)` is the thermal network of the furnace description F
(furnace_model.simulation.network); for the paper's furnace (`PAPER`) it is exactly eq. 11,
the network's three-zone case. `ModelStructure([ZoneBurners(furnace=F),
SensorLag(furnace=F)], furnace=F)` is the same model extended, used by the plant simulator
with chosen parameter values and by the diagnosis with fitted ones. All simulation is
batched over parameter sets: parameter values are arrays of length P and results carry a
leading P axis.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Literal

import numpy as np

from ..effects import Effect, Theta
from .furnace import Furnace
from .lti import Drive, Modes, carrier, response
from .network import fill, parameters
from .parameters import Param
from .response import Response

if TYPE_CHECKING:
    from ..experiment import Experiment

Batch = Literal["together", "each", "differences"]
"""What the parameter sets of one call are to each other, where the structure is nonlinear:
`together`, integrated by one scheme, so that a difference between any two is the model's
and not the schemes' (up to a few ten-thousandths of a degree); `each`, scored each on its
own (a population, a polish's trial steps), each by the cheapest scheme that holds for it;
`differences`, the first and small moves of it (a Jacobian's columns), all of them
integrated from the first one's trajectory."""


@dataclass(frozen=True)
class Inputs:
    """Piecewise-constant inputs: heat input per zone, ambient temperature, and the measured
    disturbances.

    Level j holds from t[j] until t[j+1] (and after the last). `burners` is (J, zones) (each
    zone's heat input: burners on, or its rate), `t_air` (J,), `disturbances` (J, k). This is
    the paper's input with more detail: the baseline adds the three counts into q1, an
    extended model (or a furnace whose burners heat their own zone) uses them apart. The
    input channels are the zones' heat inputs zone by zone, then ambient, then the
    disturbances (`Furnace.n_inputs`).
    """

    t: np.ndarray
    burners: np.ndarray
    t_air: np.ndarray
    disturbances: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.disturbances is None:
            object.__setattr__(self, "disturbances", np.zeros((np.size(self.t), 0)))

    def levels(self) -> np.ndarray:
        nz = self.burners.shape[1]
        k = self.disturbances.shape[1]
        u = np.empty((1, self.t.size, nz + 1 + k))
        u[0, :, :nz] = self.burners
        u[0, :, nz] = self.t_air
        u[0, :, nz + 1:] = self.disturbances
        return u

    @classmethod
    def of(cls, record: Experiment) -> Inputs:
        """A record's logged heat inputs, ambient and disturbances, as the model takes them."""
        return cls.from_samples(record.t_min, record.burners, record.t_air,
                                disturbances=record.disturbances)

    @classmethod
    def from_samples(cls, t: np.ndarray, burners: np.ndarray, t_air: np.ndarray,
                     air_deadband_c: float = 0.5,
                     disturbances: np.ndarray | None = None) -> Inputs:
        """Hold each sample's inputs until the next sample; keep only the changes.

        Ambient readings jitter from sample to sample; a change smaller than the deadband is
        not a step of the input (it moves zone 3 by far less than the sensor noise), and
        keeping them all would turn a handful of burner steps into thousands of segments.
        Every change of a heat input or a disturbance is kept: the model sees what was
        logged.
        """
        t = np.asarray(t, dtype=float)
        burners = np.asarray(burners, dtype=float)
        t_air = np.asarray(t_air, dtype=float)
        dist = (np.zeros((t.size, 0)) if disturbances is None
                else np.asarray(disturbances, dtype=float).reshape(t.size, -1))
        # Every input change is kept, so the pattern last kept is the previous sample's.
        both = np.concatenate([burners, dist], axis=1)
        changed = [False, *np.any(both[1:] != both[:-1], axis=1).tolist()]
        air = t_air.tolist()
        keep = [0]
        held_air = air[0] if air else 0.0
        for i in range(1, t.size):
            if changed[i] or abs(air[i] - held_air) > air_deadband_c:
                keep.append(i)
                held_air = air[i]
        idx = np.array(keep)
        return cls(t[idx], burners[idx], t_air[idx], dist[idx])


@dataclass(frozen=True)
class System:
    A: np.ndarray  # (P, n, n)
    B: np.ndarray  # (P, n, m)
    C: np.ndarray  # (P, zones, n): sensed zone temperatures


class ModelStructure:
    """Baseline plus effects: which states, which parameters, and how to simulate them.

    The baseline is the furnace's thermal network (eq. 11 for the paper's); each effect is
    made for the same furnace (`Effect(furnace=...)`), whose zones, thermocouples and input
    channels it reads. The furnace is named, never assumed: a structure of the wrong furnace
    would simulate without complaint and fit the wrong columns."""

    def __init__(self, effects: Sequence[Effect] = (), *, furnace: Furnace):
        names = [e.name for e in effects]
        if len(set(names)) != len(names):
            raise ValueError(f"an effect appears twice in {names}")
        other = [e.name for e in effects if getattr(e, "furnace", None) != furnace]
        if other:
            raise ValueError(f"effect(s) {', '.join(other)} were made for another furnace than "
                             f"'{furnace.name}' (make them with furnace=...)")
        self.furnace = furnace
        self.n_zones = furnace.n_zones
        self.effects: tuple[Effect, ...] = tuple(effects)
        self.params: tuple[Param, ...] = (parameters(furnace)
                                          + tuple(p for e in self.effects for p in e.params))
        pnames = [p.name for p in self.params]
        if len(set(pnames)) != len(pnames):
            raise ValueError(f"parameter names collide in {pnames}")
        self.n_states = self.n_zones + sum(len(e.state_zones) for e in self.effects)
        self.linear = all(e.linear for e in self.effects)

    def __repr__(self) -> str:
        return f"ModelStructure({[e.name for e in self.effects]}, furnace={self.furnace.name!r})"

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.params]

    @property
    def label(self) -> str:
        return "+".join(e.name for e in self.effects) or "baseline"

    def defaults(self) -> dict[str, float]:
        return {p.name: p.default for p in self.params}

    def theta(self, values: Mapping[str, float | np.ndarray]) -> Theta:
        """Parameter values as arrays of one common length P; every parameter must be given."""
        missing = [n for n in self.names if n not in values]
        if missing:
            raise KeyError(f"{self.label}: missing parameter(s) {missing}")
        arrays = [np.atleast_1d(np.asarray(values[n], dtype=float)) for n in self.names]
        P = max(a.size for a in arrays)
        return {n: a if a.shape == (P,) else np.broadcast_to(a, (P,))
                for n, a in zip(self.names, arrays, strict=True)}

    def system(self, theta: Theta) -> System:
        P, n, nz = next(iter(theta.values())).shape[0], self.n_states, self.n_zones
        A = np.zeros((P, n, n))
        B = np.zeros((P, n, self.furnace.n_inputs))
        fill(self.furnace, A, B, theta)  # eq. 11 for the paper's furnace
        C = np.zeros((P, nz, n))
        C[:, :, :nz] = np.eye(nz)
        first = nz
        for eff in self.effects:
            eff.extend(A, B, C, theta, first)
            first += len(eff.state_zones)
        return System(A, B, C)

    def drive(self, theta: Theta, inputs: Inputs) -> Drive:
        u = inputs.levels()
        for eff in self.effects:
            u = eff.transform_levels(theta, u)
        drive = Drive.from_levels(inputs.t, u)
        for eff in sorted(self.effects, key=lambda e: e.drive_stage):
            drive = eff.transform_drive(theta, drive)
        return drive

    def full_state(self, x_zone: np.ndarray) -> np.ndarray:
        """Extend zone temperatures (P|1, zones) to all states: each extra state starts at rest
        with its zone (a lagged sensor reads the zone, a wall is at the gas temperature)."""
        x_zone = np.atleast_2d(np.asarray(x_zone, dtype=float))
        extra = [z for e in self.effects for z in e.state_zones]
        return np.concatenate([x_zone, x_zone[:, extra]], axis=1)

    @property
    def has_sensor_offsets(self) -> bool:
        """Whether some effect adds its own error to single thermocouples (a drift)."""
        return any(type(e).sensor_offsets is not Effect.sensor_offsets for e in self.effects)

    @property
    def moves_inputs(self) -> bool:
        """Whether some effect changes the inputs the network sees (a fuel switch, a transport
        delay, a burner curve)."""
        return any(type(e).transform_drive is not Effect.transform_drive
                   or type(e).transform_levels is not Effect.transform_levels
                   for e in self.effects)

    def simulate(self, values: Mapping[str, float | np.ndarray], inputs: Inputs, t: np.ndarray,
                 x0: np.ndarray, t0: float | None = None, states: bool = False,
                 batch: Batch = "together") -> Response:
        """The run at times t from zone temperatures x0 at t0, for P parameter sets.

        x0 is (P|1, zones) zone temperatures, or (P|1, n) full states. t0 defaults to the first
        input time. The zone outputs are simulated; with states=True the states are too (one
        simulation gives both), else a response computes them on first use.

        `batch` says what the sets of a nonlinear structure are to each other (`Batch`).
        """
        theta = self.theta(values)
        sys = self.system(theta)
        drive = self.drive(theta, inputs)
        x0 = np.atleast_2d(np.asarray(x0, dtype=float))
        if x0.shape[-1] == self.n_zones and self.n_states != self.n_zones:
            x0 = self.full_state(x0)
        t0 = float(inputs.t[0]) if t0 is None else float(t0)
        t = np.asarray(t, dtype=float)

        def run(C: np.ndarray | None) -> np.ndarray:
            if self.linear:
                return response(sys.A, sys.B, x0, t0, drive, t, C=C, modes=Modes.of(sys.A))
            return self._integrate(theta, sys, drive, x0, t0, t, C, batch)

        if states:
            x = run(None)
            return Response(t, np.einsum("pqn,pNn->pNq", sys.C, x), self, theta, states=x)
        return Response(t, run(sys.C), self, theta, recompute_states=lambda: run(None))

    def nonlinear_off(self, values: Mapping[str, float | np.ndarray]) -> np.ndarray:
        """Parameter sets (P,) in which every nonlinear term vanishes: linear ones."""
        theta = self.theta(values)
        off = np.ones(next(iter(theta.values())).shape[0], dtype=bool)
        for eff in self.effects:
            if not eff.linear:
                off &= eff.nonlinear_off(theta)
        return off

    def simulate_first_order(self, values: Mapping[str, float | np.ndarray], inputs: Inputs,
                             t: np.ndarray, x0: np.ndarray,
                             t0: float | None = None) -> np.ndarray:
        """Sensed zone temperatures (P, N, 3) to first order in the nonlinear terms: the
        linear response x_l plus d, where d' = A d + N(x_l(t)) and d(t0) = 0.

        Why: about a set whose nonlinear terms vanish (radiation's share at zero), a small
        step of the effect's strength moves the solution by d to first order, and d is a
        linear convolution of a known forcing, with no state-dependent linearisation to step
        through. A finite difference of this against `simulate` at the vanishing set is the
        sensitivity to that strength (`Problem.jac`), for the cost of one closed-form
        response and one quadrature instead of a whole nonlinear integration.

        The quadrature runs on the steps the nonlinear integrator takes (`_step_bounds`),
        with N(x_l) quadratic in time on each (its values at the step's start, middle and
        end), integrated exactly against the modes of A.
        """
        theta = self.theta(values)
        sys = self.system(theta)
        drive = self.drive(theta, inputs)
        P, n = sys.A.shape[0], self.n_states
        x0 = np.atleast_2d(np.asarray(x0, dtype=float))
        if x0.shape[-1] == self.n_zones and n != self.n_zones:
            x0 = self.full_state(x0)
        x0 = np.broadcast_to(x0, (P, n))
        t0 = float(inputs.t[0]) if t0 is None else float(t0)
        t = np.asarray(t, dtype=float)
        modes = Modes.of(sys.A)
        x_lin = response(sys.A, sys.B, x0, t0, drive, t, modes=modes)
        grid = _Grid.of(drive, t0, max(float(t[-1]), t0) if t.size else t0, P,
                        _first_step(modes.lam))
        if grid is None:
            return np.einsum("pqn,pNn->pNq", sys.C, x_lin)
        X = grid.at_nodes(response(sys.A, sys.B, x0, t0, drive, grid.nodes, modes=modes))
        g = self._nonlinear_rhs(theta, sys, X, grid.u)
        x = x_lin + grid.convolved(modes, g, t, t0)
        return np.einsum("pqn,pNn->pNq", sys.C, x)

    def _nonlinear_rhs(self, theta, sys, X: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The effects' nonlinear terms at states X (P, K, 3, n) under the inputs u (P, K, m)
        of each step."""
        P, K, _, n = X.shape
        terms = _Nonlinear(self.effects, theta, sys, np.repeat(u, 3, axis=1))
        return terms(X.reshape(P, 3 * K, n)).reshape(P, K, 3, n)

    def _relaxed(self, theta, sys, drive, x0, t0, t, batch: Batch = "together"
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """States (P, N, n) of a weakly nonlinear structure by waveform relaxation, which
        sets converged (the others are to be integrated step by step), and which cannot be
        simulated at all (not finite from the start).

        Why: `_exprb` steps through time, a linearisation and an eigendecomposition per step
        and a dozen steps after every input change; on a record of hourly rows with an input
        that moves every hour, that is thousands of small steps, each costing the same
        whatever the batch. Where the nonlinear term departs little from its linearisation
        over the whole record (a room within a few degrees, or a furnace near its reference
        temperature), the trajectory is instead the fixed point of
        x = x_A'(t) + (e^{A' t} * R(x))(t), with A' = A + J the linear part at the trajectory's
        mean state and R(x) = N(x) - J x what is left: each sweep is one closed-form response
        and one quadrature over all steps at once (as `simulate_first_order`), vectorised
        over time. A set whose sweeps do not contract (strongly nonlinear over its range, as
        a heat-up from cold with radiation) is reported unconverged after a few sweeps.

        The sweeps run on steps that scale with the network's fastest mode (`_first_step`),
        the same for every set of a call, and to a tolerance far below a finite difference's
        effect, so the result is a smooth function of the parameters as the fit's Jacobian
        needs. The sweeps stop once a set leaves them (all are then stepped), or with `each`
        once every set still in them has converged.

        A Jacobian's sets (`differences`) are small moves of the first: that one is relaxed
        alone, and then all of them from its trajectory with its linear part A' (each set's
        own A - A' moved into R). They start within a finite difference's move of their
        answer and converge in two or three sweeps instead of eight from their linear
        responses, with one set of modes and of quadrature weights for them all; and the
        same sweeps from the same trajectory with one linear part make their differences
        those of one smooth map, whose sweeps' residue cancels as the schemes' does."""
        P, n = sys.A.shape[0], self.n_states
        x0 = np.broadcast_to(x0, (P, n))
        end = max(float(t[-1]), t0) if t.size else t0
        grid = _Grid.of(drive, t0, end, P, _first_step(Modes.of(sys.A).lam))
        if grid is None:
            ok = np.zeros(P, dtype=bool)
            return np.empty((P, t.size, n)), ok, ok
        if batch != "differences" or P == 1:
            return self._sweeps(theta, sys, drive, x0, grid, t0, t, batch == "each")[:3]
        x1, ok1, _, about = self._sweeps(*_sets(np.arange(1), theta, sys, drive, x0, grid),
                                         t0, t, False)
        if not ok1[0]:  # all stepped, as the first is
            unrelaxed = np.zeros(P, dtype=bool)
            return x1.repeat(P, axis=0), unrelaxed, unrelaxed
        # the first too, so that every set takes the same sweeps from the same trajectory:
        # a set the first's differs from by nothing (an unseen burner's gain) gives nothing
        x, ok, lost, _ = self._sweeps(theta, sys, drive, x0, grid, t0, t, False, about)
        if not (ok | lost).all():  # each from its own linear response, as `together`
            return self._sweeps(theta, sys, drive, x0, grid, t0, t, False)[:3]
        return x, ok, lost

    def _sweeps(self, theta, sys, drive, x0, grid, t0, t, each: bool,
                about: tuple[np.ndarray, np.ndarray, Modes] | None = None):
        """`_relaxed`'s sweeps on the grid: states (P, N, n), converged, lost, and the
        trajectory at the nodes with its linear part and modes (those of the first set).
        `about`: such a trajectory, linear part and modes (of one set) to start from and
        keep."""
        P, n = sys.A.shape[0], self.n_states
        u0 = np.broadcast_to(drive.level_at(t0), (P, sys.B.shape[2]))
        nonlinear = _Nonlinear(self.effects, theta, sys, u0[:, None])

        def centred(X):
            """The linear part at X's mean state and the response it alone gives."""
            _, J = _Linearised.jacobian(nonlinear, X.mean(axis=(1, 2)))
            A = sys.A + J
            finite = np.isfinite(A).all(axis=(1, 2))
            A = np.where(finite[:, None, None], A, -_eye(n))
            modes = Modes.of(A)
            usable = finite & (np.abs(modes.V).sum(axis=1).max(axis=1)
                               * np.abs(modes.Vinv).sum(axis=1).max(axis=1) < 1e10)
            base = grid.at_nodes(response(A, sys.B, x0, t0, drive, grid.nodes, modes=modes))
            return J, A, modes, modes, usable, base

        def kept():
            """The linear part of `about` for every set: each one's own rest in R."""
            _, A1, shared = about
            A = np.repeat(A1, P, axis=0)
            modes = Modes(*(np.repeat(a, P, axis=0) for a in (shared.lam, shared.V,
                                                              shared.Vinv)))
            base = grid.at_nodes(response(A, sys.B, x0, t0, drive, grid.nodes, modes=modes))
            usable = np.isfinite(base).all(axis=(1, 2, 3))
            return A - sys.A, A, modes, shared, usable, base

        def rest(X, J):
            return self._nonlinear_rhs(theta, sys, X, grid.u) - _times(J, X)

        if about is None:
            X = grid.at_nodes(response(sys.A, sys.B, x0, t0, drive, grid.nodes,
                                       modes=Modes.of(sys.A)))
        else:
            X = np.repeat(about[0], P, axis=0)
        lost = ~np.isfinite(X).all(axis=(1, 2, 3))
        X = np.where(lost[:, None, None, None], 0.0, X)
        scale = 1.0 + np.abs(X).max(axis=(1, 2, 3))
        change = np.full(P, np.inf)
        active = ~lost
        ok = np.zeros(P, dtype=bool)
        done = np.zeros(P, dtype=bool)  # with `each`: converged, and left where they are
        for sweep in range(RELAX_SWEEPS):
            if sweep == 0 or (about is None and sweep <= RELAX_CENTRINGS):
                J, A, modes, shared, usable, base = centred(X) if about is None else kept()
                active &= usable
                convolved = grid.node_convolver(shared)
            new = base + convolved(rest(X, J))
            step = np.abs(new - X).max(axis=(1, 2, 3))
            bad = ~np.isfinite(step)
            step = np.where(bad, np.inf, step)
            # a set within the tolerance has reached rounding, where steps no longer shrink
            slow = (sweep > RELAX_CENTRINGS + 1) & (step > RELAX_CONTRACTION * change) \
                & (step > RELAX_TOL * scale)
            active &= ~bad & ~slow | done
            X = np.where((active & ~done)[:, None, None, None], new, X)
            change = step
            ok = done | active & (step <= RELAX_TOL * scale)
            if each:
                done = ok
            if (ok | lost | ~active).all() if each else \
                    (not (active | lost).all() or (ok | lost).all()):
                break
        x = response(A, sys.B, x0, t0, drive, t, modes=modes) \
            + grid.convolved(shared, rest(X, J), t, t0)
        first = Modes(shared.lam[:1], shared.V[:1], shared.Vinv[:1])
        return x, ok, lost, (X[:1], A[:1], first)

    def sensor_offsets(self, values: Mapping[str, float | np.ndarray], t: np.ndarray) -> np.ndarray:
        """Per-thermocouple additive errors (P, N, thermocouples) from sensor effects; zeros
        without."""
        theta = self.theta(values)
        P = next(iter(theta.values())).shape[0]
        out = np.zeros((P, np.size(t), len(self.furnace.sensors)))
        for eff in self.effects:
            off = eff.sensor_offsets(theta, np.asarray(t, dtype=float))
            if off is not None:
                out += off
        return out

    def _integrate(self, theta, sys, drive, x0, t0, t, C, batch: Batch = "together"):
        """Nonlinear structures: the sets whose nonlinear terms all vanish (radiation's share
        at zero) are linear and take the closed form, the others `_stepped`. Both are the same
        function of the parameters: on a linear system the exponential scheme is exact, so
        the two agree to rounding and a finite difference may straddle them."""
        P, n = sys.A.shape[0], self.n_states
        off = np.ones(P, dtype=bool)
        for eff in self.effects:
            if not eff.linear:
                off &= eff.nonlinear_off(theta)
        if t.size and t[0] < t0:
            return self._exprb(theta, sys, drive, x0, t0, t, C)
        if not off.any():
            return self._stepped(theta, sys, drive, x0, t0, t, C, batch)
        x0 = np.broadcast_to(x0, (P, n))
        lin = np.nonzero(off)[0]
        A, B = sys.A[lin], sys.B[lin]
        y_lin = response(A, B, x0[lin], t0, _take_drive(drive, lin), t,
                         C=None if C is None else C[lin], modes=Modes.of(A))
        if lin.size == P:
            return y_lin
        out = np.empty((P,) + y_lin.shape[1:])
        out[lin] = y_lin
        rest = np.nonzero(~off)[0]
        out[rest] = self._stepped({k: v[rest] for k, v in theta.items()},
                                System(sys.A[rest], sys.B[rest], sys.C[rest]),
                                _take_drive(drive, rest), x0[rest], t0, t,
                                None if C is None else C[rest], batch)
        return out

    def _stepped(self, theta, sys, drive, x0, t0, t, C, batch: Batch = "together"):
        """Sets with nonlinear terms: by waveform relaxation where it converges for every set
        of the call, by `_exprb` otherwise. The two differ by their discretisations (up to a
        few ten-thousandths of a degree on a heat-up with a strong radiative share), as much
        as a forward difference moves the response: the sets of one call, which a Jacobian
        differences against each other, are all taken by the same scheme. Sets scored
        `each` on their own are stepped only where the relaxation does not take them: a
        population's few strongly nonlinear members then no longer cost the whole population
        a step-by-step run."""
        P, n = sys.A.shape[0], self.n_states
        x0 = np.broadcast_to(x0, (P, n))
        each = batch == "each"
        x, ok, lost = self._relaxed(theta, sys, drive, x0, t0, t, batch)
        rest = ~(ok | lost)
        if rest.any() and not each:
            return self._exprb(theta, sys, drive, x0, t0, t, C)
        if rest.any():
            p = np.nonzero(rest)[0]
            x[p] = self._exprb({k: v[p] for k, v in theta.items()},
                               System(sys.A[p], sys.B[p], sys.C[p]), _take_drive(drive, p),
                               x0[p], t0, t, None)
        x[lost] = np.nan  # as `_exprb` leaves a set that diverges, without costing the others
        if C is None:
            return x
        return np.einsum("pqn,pNn->pNq", C, x)

    def _exprb(self, theta, sys, drive, x0, t0, t, C):
        """Nonlinear structures (radiation): all parameter sets at once by an exponential
        Rosenbrock scheme (exprb32, third order) on steps that never straddle an input change.

        Each step linearises the right-hand side at its start, x' = F(x_n) + J_n (x - x_n)
        + rest, and treats the linear part exactly in the eigenbasis of J_n, as the linear
        simulator does: the preheating zone's sub-minute mode costs nothing, and one step
        spans many samples. Samples inside a step are each reached as a step of their own
        length from its start (the remainder interpolated in tau), so no output is
        interpolated. J_n's nonlinear part is a finite difference of the effects'
        `nonlinear_rhs`. Sets whose J_n has no reliable eigenbasis are integrated one by one
        by LSODA instead (`_integrate_lsoda`).
        """
        P, n = sys.A.shape[0], self.n_states
        x = np.array(np.broadcast_to(x0, (P, n)), dtype=float)
        out = np.empty((P, t.size, n))
        end = max(float(t[-1]), t0) if t.size else t0
        out[:, t <= t0] = x[:, None]
        cuts = np.unique(np.ravel(drive.s))
        edges = np.concatenate(([t0], cuts[(cuts > t0) & (cuts < end)], [end]))
        first = _first_step(np.linalg.eigvals(sys.A))
        hard = np.zeros(P, dtype=bool)
        diverged = np.zeros(P, dtype=bool)
        levels = np.broadcast_to(drive.levels_at(edges[:-1]), (P, edges.size - 1, sys.B.shape[2]))
        for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
            if hi <= lo:
                continue
            u = levels[:, i]
            Bu = np.einsum("pnm,pm->pn", sys.B, u)
            nonlinear = _Nonlinear(self.effects, theta, sys, u[:, None])
            bounds = _step_bounds(lo, hi, first)
            # the samples inside each step, and on its end (t ascending): one search per
            # piece, not a pass over the record per step
            after = np.searchsorted(t, bounds[:-1], side="right")
            below = np.searchsorted(t, bounds[1:], side="left")
            upto = np.searchsorted(t, bounds[1:], side="right")
            for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
                step = _Linearised(nonlinear, sys.A, Bu, x)
                x = step.end(b - a)
                if below[k] > after[k]:
                    out[:, after[k]:below[k]] = step.inside(t[after[k]:below[k]] - a)
                out[:, below[k]:(upto[k] if b < end else t.size)] = x[:, None]
                hard |= step.bad
                diverged |= step.diverged
        hard &= ~diverged
        out[diverged] = np.nan
        if hard.any():
            p = np.nonzero(hard)[0]
            out[p] = self._integrate_lsoda({k: v[p] for k, v in theta.items()},
                                           System(sys.A[p], sys.B[p], sys.C[p]),
                                           _take_drive(drive, p),
                                           np.broadcast_to(x0, (P, n))[p], t0, t, None)
        if C is None:
            return out
        return np.einsum("pqn,pNn->pNq", C, out)

    def _integrate_lsoda(self, theta, sys, drive, x0, t0, t, C):
        """Adaptive stiff integration, one parameter set and one constant-input piece at a
        time so that no step straddles a burner change: slow, for the sets the exponential
        scheme cannot take."""
        from scipy.integrate import solve_ivp  # a slow package to import, for a rare fallback

        P, n = sys.A.shape[0], self.n_states
        x0 = np.broadcast_to(x0, (P, n))
        out = np.empty((P, t.size, n))
        end = max(float(t[-1]), t0) if t.size else t0
        for p in range(P):
            th = {k: v[p:p + 1] for k, v in theta.items()}
            A, B = sys.A[p:p + 1], sys.B[p:p + 1]
            cuts = drive.breakpoints(p)
            edges = np.concatenate(([t0], cuts[(cuts > t0) & (cuts < end)], [end]))
            x = np.array(x0[p])
            levels = drive.levels_at(edges[:-1], p)[0]
            first = np.searchsorted(t, edges, side="left")  # the samples of each piece
            for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
                if hi <= lo:
                    continue
                u = levels[i][None]

                def rhs(_t, xv, A=A, B=B, u=u, th=th):
                    dx = A[0] @ xv + B[0] @ u[0]
                    for eff in self.effects:
                        if not eff.linear:
                            dx = dx + eff.nonlinear_rhs(th, xv[None], A, B, u)[0]
                    return dx

                idx = np.arange(first[i], first[i + 1])
                with warnings.catch_warnings():
                    # its complaints end in sol.success, which is checked: not for stderr
                    warnings.simplefilter("ignore")
                    sol = solve_ivp(rhs, (lo, hi), x, method="LSODA", rtol=1e-9, atol=1e-7,
                                    t_eval=np.append(t[idx], hi))
                if not sol.success:
                    raise RuntimeError(f"integration failed on [{lo}, {hi}] min: {sol.message}")
                out[p, idx] = sol.y[:, :-1].T
                x = sol.y[:, -1]
            out[p, t >= end] = x
        if C is None:
            return out
        return np.einsum("pqn,pNn->pNq", C, out)


RADIATION_STEP_MIN = 8.0
"""Longest step of the nonlinear integrators, reached after each input change by doubling
from the first (`_first_step`). The steps depend on the inputs and on the call's fastest mode
in powers of two, never on the values otherwise, so the result is a smooth function of the
parameters within a call (as finite-difference Jacobians need). At 8 minutes a heat-up to
1400 degC stays within 0.01 degC (mostly 0.001) of a tight adaptive integration
(tests/test_lti.py); at 20 it drifts to a hundredth, and a run cut into pieces (the
simulated PLC's stepper) would no longer match a whole run to 1e-6."""


FIRST_STEP_MIN = 0.5
"""First step after an input change, where the fast modes move: the paper's preheating zone
settles in about 0.6 minutes."""


def _step_bounds(lo: float, hi: float, first: float = FIRST_STEP_MIN) -> np.ndarray:
    """Step ends from lo to hi: `first` right after an input change, where the fast modes
    move, then doubling up to RADIATION_STEP_MIN (or first, if longer: the slow drift's
    curvature, not the fast modes, bounds the longest step on a heat-up)."""
    longest = max(RADIATION_STEP_MIN, first)
    ends, h, x = [lo], first, lo
    while x < hi:
        x = hi if hi - (x + h) < 0.1 * h else x + h
        ends.append(x)
        h = min(2 * h, longest)
    return np.array(ends)


def _piece_steps(spans: np.ndarray, first: float) -> tuple[np.ndarray, np.ndarray]:
    """`_step_bounds` from 0 over pieces of lengths `spans`: how many steps each piece takes,
    and each step's start within its piece, all pieces' in a row.

    Every piece starts the same sequence of steps (first, doubling, then the longest), so
    the sequence is laid out once, as far as the longest piece, and each piece keeps the
    steps that end short of its end by a tenth of a step; its last step runs to its end.
    A record with an input change every minute, or a logger whose rows are a few seconds off
    their grid, has thousands of pieces: built one by one, they cost a Python turn each."""
    longest = max(RADIATION_STEP_MIN, first)
    doublings = int(np.ceil(np.log2(longest / first))) if longest > first else 0
    h = np.minimum(first * 2.0 ** np.arange(doublings + 1), longest)
    more = max(0, int(np.ceil((float(spans.max()) + longest - h.sum()) / longest))) + 1
    h = np.concatenate([h, np.full(more, longest)])
    ends = np.cumsum(h)  # as _step_bounds adds them, one after another

    def cut(j: np.ndarray) -> np.ndarray:  # _step_bounds' test: the step at j ends the piece
        return (spans - ends[j]) < 0.1 * h[j]

    kept = np.minimum(np.searchsorted(ends + 0.1 * h, spans, side="right"), ends.size - 1)
    kept = kept - ((kept > 0) & cut(np.maximum(kept - 1, 0)))  # the test's rounding, exactly
    kept = kept + ~cut(kept)
    counts = kept + 1
    starts = np.concatenate(([0.0], np.cumsum(np.diff(np.concatenate(([0.0], ends))))))
    into = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    return counts, starts[into]


def _first_step(lam: np.ndarray) -> float:
    """The nonlinear integrators' first step after an input change for modes lam (P, n):
    FIRST_STEP_MIN doubled while it stays within the fastest mode's time constant over all
    the sets.

    Why: the first steps resolve the fast modes' moves after each change, and a network
    whose fastest mode takes hours (a room, a wall) moves on that scale: steps of minutes
    would make an hourly record cost like a record of minutes (a dozen steps per sample),
    and a record with an input change every minute two steps per sample. Powers of two keep the
    grid the same over a fit's neighbouring sets, so a Jacobian's columns share it, as do
    the sets of one call. On the paper's furnace the first step is the half minute."""
    rates = np.abs(np.real(lam))
    rates = rates[np.isfinite(rates)]
    fastest = float(rates.max()) if rates.size else 0.0
    if fastest * FIRST_STEP_MIN >= 1.0:
        return FIRST_STEP_MIN
    doublings = np.floor(np.log2(1.0 / (fastest * FIRST_STEP_MIN))) if fastest > 0 else 30.0
    return FIRST_STEP_MIN * 2.0 ** min(doublings, 30.0)


RELAX_SWEEPS = 40
"""Most sweeps of the waveform relaxation; a set that contracts converges in a handful."""
RELAX_TOL = 1e-11
"""Relaxation converged: the last sweep moved no state by more than this share of the
record's largest temperature."""
RELAX_CENTRINGS = 2
"""Sweeps after which the linear part is taken anew at the iterate's mean state: the linear
model's own mean can lie far from the nonlinear one's (a strong radiative share moves a
zone's level by hundreds of degrees)."""
RELAX_CONTRACTION = 0.5
"""From the third sweep on, a set whose sweep moves it by more than this share of the
previous one is left to the step-by-step integrator: it would take too many sweeps, or
none would do."""


@dataclass(frozen=True)
class _Grid:
    """The steps of the nonlinear integrators (`_step_bounds` on every constant-input piece):
    starts a (K,), lengths h (K,) and the input on each, u (P, K, m). A forcing is sampled
    at the nodes: each step's start and middle, and the last step's end."""

    a: np.ndarray
    h: np.ndarray
    u: np.ndarray

    @classmethod
    def of(cls, drive: Drive, t0: float, end: float, P: int,
           first: float = FIRST_STEP_MIN) -> _Grid | None:
        cuts = np.unique(np.ravel(drive.s))
        edges = np.concatenate(([t0], cuts[(cuts > t0) & (cuts < end)], [end]))
        spans = np.diff(edges)
        los, last = edges[:-1][spans > 0], edges[1:][spans > 0][-1:]
        spans = spans[spans > 0]
        if not los.size:
            return None
        counts, since = _piece_steps(spans, first)
        a = np.repeat(los, counts) + since
        u = np.broadcast_to(drive.levels_at(los), (P, los.size, drive.u0.shape[-1]))
        return cls(a, np.diff(np.concatenate((a, last))), np.repeat(u, counts, axis=1))

    @cached_property
    def nodes(self) -> np.ndarray:
        nodes = np.empty(2 * self.a.size + 1)
        nodes[0:-1:2], nodes[1::2] = self.a, self.a + self.h / 2
        nodes[-1] = self.a[-1] + self.h[-1]
        return nodes

    @staticmethod
    def at_nodes(x: np.ndarray) -> np.ndarray:
        """Values (P, 2K+1, n) at the nodes as (P, K, 3, n): each step's start, middle, end."""
        return np.stack([x[:, 0:-1:2], x[:, 1::2], x[:, 2::2]], axis=2)

    def convolved(self, modes: Modes, g: np.ndarray, t: np.ndarray, t0: float) -> np.ndarray:
        """d (P, N, n) at times t, where d' = A d + g(t) and d(t0) = 0, for the forcing g
        quadratic in time on each step through its values g (P, K, 3, n) at the step's start,
        middle and end: integrated exactly against the modes of A."""
        return self.convolver(modes, t, t0)(g)

    def convolver(self, modes: Modes, t: np.ndarray, t0: float
                  ) -> Callable[[np.ndarray], np.ndarray]:
        """`convolved` for many forcings against the same modes and times: the modes'
        weights over each step and up to each time (exponentials and phi functions) are most
        of a convolution's cost, and are taken once."""
        a, K = self.a, self.a.size
        k_of = np.clip(np.searchsorted(a, t, side="left") - 1, 0, K - 1)
        e, *w = self._node_weights(modes.lam, np.maximum(t - a[k_of], 0.0), k_of)
        before = t <= t0
        starts = self._starts(modes, K)

        def convolve(g: np.ndarray) -> np.ndarray:
            gm, sig = starts(g)
            d = e * sig[:, k_of]
            for j in range(3):
                d += w[j] * gm[:, j, k_of]
            d[:, before] = 0.0
            return _times(modes.V, d).real
        return convolve

    def node_convolver(self, modes: Modes) -> Callable[[np.ndarray], np.ndarray]:
        """`convolver` at the grid's own nodes, as `at_nodes` lays them out (P, K, 3, n):
        a step's start is what the steps before carry to it and its end what it carries on,
        so only its middle is weighed, and no node is looked up among the steps. The grid
        starts at t0, where the forcing has carried nothing yet."""
        K = self.a.size
        e, *w = self._node_weights(modes.lam, self.nodes[1::2] - self.a, np.arange(K))
        starts = self._starts(modes, K + 1)

        def convolve(g: np.ndarray) -> np.ndarray:
            gm, sig = starts(g)
            d = np.empty(gm.shape, np.result_type(gm, e))  # start, middle, end: each contiguous
            d[:, 0], d[:, 2] = sig[:, :K], sig[:, 1:]
            mid = d[:, 1]
            np.multiply(e, sig[:, :K], out=mid)
            for j in range(3):
                mid += w[j] * gm[:, j]
            return _times(modes.V, np.swapaxes(d, 1, 2)).real
        return convolve

    def _starts(self, modes: Modes, count: int
                ) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
        """For a forcing g (P, K, 3, n): its modal values (P, 3, K, n), each node of the
        steps contiguous (a product over (K, 3, n) with n of two or three runs its innermost
        loop over n), and what the steps carry to the first `count` steps' starts (K + 1:
        the last step's end too)."""
        K = self.a.size
        _, *w = self._node_weights(modes.lam, self.h, np.arange(K))
        ends = np.append(self.a, self.a[-1] + self.h[-1])
        carry = carrier(modes.lam, np.append(ends, ends[-1]), count)

        def starts(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            gm = _times(modes.Vinv, np.swapaxes(g, 1, 2))  # modal forcing
            inc = np.zeros((gm.shape[0], count, gm.shape[-1]), dtype=gm.dtype)
            for j in range(3):
                inc[:, :K] += w[j] * gm[:, j]
            return gm, carry(inc)
        return starts

    def _node_weights(self, lam: np.ndarray, tau: np.ndarray, k_of: np.ndarray
                      ) -> tuple[np.ndarray, ...]:
        """How the state carried to a step's start and the forcing's values at the step's
        start, middle and end (through the quadratic through them, g(a + s) = g0 + c1 s +
        c2 s^2) weigh in the state tau (S,) into step k_of (S,): e and w0, wh, w1, (P, S, n)
        each. Taken once per convolver, so that a sweep is three products per weight.

        The steps' lengths repeat (each input change starts the same doubling), as do the
        samples' places in their steps on a regular grid: the phi functions, two dozen
        passes each, are taken once per distinct place and length."""
        # each pair as one complex number: unique sorts those as pairs, twenty times faster
        # than it sorts rows
        pairs, back = np.unique(tau + 1j * self.h[k_of], return_inverse=True)
        u, h = pairs.real[None, :, None], pairs.imag[None, :, None]
        e, p1, p2, p3 = _phi123(lam[:, None, :] * u)
        # c1 = (4 gh - 3 g0 - g1) / h, c2 = 2 (g1 - 2 gh + g0) / h^2
        s0, s1, s2 = u * p1, u * u * p2, 2.0 * u ** 3 * p3  # of the value, slope, curvature
        a1, a2 = s1 / h, 2.0 * s2 / (h * h)
        out = (e, s0 - 3.0 * a1 + a2, 4.0 * a1 - 2.0 * a2, a2 - a1)
        return tuple(np.take(w, back, axis=1) for w in out)


class _Nonlinear:
    """The effects' nonlinear terms for states (P, S, n) under the inputs U (P, S, m), or
    (P, 1, m) on a constant-input piece."""

    def __init__(self, effects, theta, sys, U):
        self.effects = [e for e in effects if not e.linear]
        self.theta, self.A, self.B, self.U = theta, sys.A, sys.B, U

    def __call__(self, X: np.ndarray) -> np.ndarray:
        dx = self.effects[0].nonlinear_rhs_over(self.theta, X, self.A, self.B, self.U)
        for eff in self.effects[1:]:
            dx = dx + eff.nonlinear_rhs_over(self.theta, X, self.A, self.B, self.U)
        return dx


class _Linearised:
    """exprb32 from state x (P, n): U = x + tau phi1(tau J) F(x) is the exponential
    Rosenbrock-Euler step, X = U + 2 tau phi3(tau J) (N(U) - N(x) - Jn (U - x)) the
    third-order one (J = A + Jn the Jacobian at x, N the nonlinear part of F)."""

    def __init__(self, nonlinear: _Nonlinear, A: np.ndarray, Bu: np.ndarray, x: np.ndarray):
        P, n = x.shape
        self.N0, self.Jn = self.jacobian(nonlinear, x)
        F = (A @ x[:, :, None])[:, :, 0] + Bu + self.N0
        J = A + self.Jn
        # A set that has blown up (non-finite state or Jacobian) must not stop the batch: it
        # is stepped with a stand-in Jacobian and its result is NaN (an infinite misfit).
        self.diverged = ~(np.isfinite(J).all(axis=(1, 2)) & np.isfinite(F).all(axis=1))
        if self.diverged.any():
            J = np.where(self.diverged[:, None, None], -_eye(n), J)
            F = np.where(self.diverged[:, None], 0.0, F)
        self.lam, self.V = np.linalg.eig(J)
        self.Vinv = np.linalg.inv(self.V)
        # 1-norm condition number of V: a (nearly) defective J has no usable eigenbasis
        self.bad = (np.abs(self.V).sum(axis=1).max(axis=1)
                    * np.abs(self.Vinv).sum(axis=1).max(axis=1) > 1e10)
        self.Fm = self.Vinv @ F[:, :, None]
        self.x, self.nonlinear = x, nonlinear

    @staticmethod
    def jacobian(nonlinear: _Nonlinear, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The nonlinear terms N(x) (P, n) and their Jacobian (P, n, n), by forward
        differences."""
        n = x.shape[1]
        delta = 1e-5 * np.maximum(1.0, np.abs(x))
        probes = np.repeat(x[:, None], n + 1, axis=1)
        probes[:, 1:] += _eye(n) * delta[:, :, None]
        Np = nonlinear(probes)  # (P, 1 + n, n): at x, then x moved along each state
        N0 = Np[:, 0]
        return N0, np.swapaxes(Np[:, 1:] - N0[:, None], 1, 2) / delta[:, None, :]

    def _u(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        phi1, phi3 = _phi13(self.lam[:, :, None] * tau)
        return self.x[:, :, None] + (self.V @ (tau * phi1 * self.Fm)).real, phi3

    def _corr(self, tau: np.ndarray, phi3: np.ndarray, D: np.ndarray) -> np.ndarray:
        return (self.V @ (2.0 * tau * phi3 * (self.Vinv @ D))).real

    def end(self, h: float) -> np.ndarray:
        """States (P, n) at x's time + h. The remainder D is
        evaluated at h/2 and h and kept as D(tau) = c2 tau^2 + c3 tau^3 (it starts at
        second order in tau) for the samples inside the step."""
        tau = np.array([h / 2, h])
        U, phi3 = self._u(tau)
        x = self.x[:, :, None]
        D = np.swapaxes(self.nonlinear(np.swapaxes(U, 1, 2)), 1, 2) - self.N0[:, :, None] \
            - self.Jn @ (U - x)
        self.c3 = (D[:, :, 1:] - 4.0 * D[:, :, :1]) * (2.0 / h ** 3)
        self.c2 = (D[:, :, 1:] - self.c3 * h ** 3) * (1.0 / h ** 2)
        corr = self._corr(tau[1:], phi3[:, :, 1:], D[:, :, 1:])
        return U[:, :, 1] + corr[:, :, 0]

    def inside(self, tau: np.ndarray) -> np.ndarray:
        """States (P, S, n) at x's time + tau, for 0 < tau < h of the last `end`."""
        U, phi3 = self._u(tau)
        D = (self.c2 + self.c3 * tau) * (tau * tau)
        return np.swapaxes(U + self._corr(tau, phi3, D), 1, 2)


_EYES: dict[int, np.ndarray] = {}


def _times(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    """M (P, n, n) applied to every state of x (P, ..., n): one matrix product per set, which
    is far faster than einsum's loop for these shapes."""
    out = x.reshape(x.shape[0], -1, x.shape[-1]) @ np.swapaxes(M, 1, 2)
    return out.reshape((out.shape[0],) + x.shape[1:-1] + (M.shape[1],))


def _eye(n: int) -> np.ndarray:
    if n not in _EYES:
        _EYES[n] = np.eye(n)
    return _EYES[n]


def _phi13(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """phi1(z) = (e^z - 1)/z and phi3(z) = (e^z - 1 - z - z^2/2)/z^3. Where |z| < 1e-3 phi3
    is its Taylor series (the closed form cancels there); above, the cancellation costs at
    most 1e-7 of phi3, which only scales a correction of thousandths of a degree."""
    em1 = np.expm1(z)
    small = np.abs(z) < 1e-3
    nz = np.where(small, 1.0, z)
    phi1 = np.where(z == 0, 1.0, em1 / np.where(z == 0, 1.0, z))
    series = ((z / 5040 + 1 / 720) * z + 1 / 120) * z + 1 / 24  # z^j / (j+4)!, j < 4
    phi3 = np.where(small, series * z + 1 / 6, (em1 - z - z * z / 2) / nz ** 3)
    return phi1, phi3


def _phi123(z: np.ndarray) -> tuple[np.ndarray, ...]:
    """e^z and phi_j(z) = (e^z - sum_{i<j} z^i / i!) / z^j for j = 1, 2, 3: the weights of
    a constant, linear and quadratic forcing convolved with one mode. Near zero each is
    its Taylor series (the closed form cancels there), accurate to rounding for |z| < 0.5."""
    e = np.exp(z)
    small = np.abs(z) < 0.5
    zs = np.where(small, z, 0.0)
    nz = np.where(small, 1.0, z)
    em1 = np.expm1(z)
    out = [e]
    for j in (1, 2, 3):
        series = np.zeros_like(zs)
        for i in range(16, -1, -1):  # sum_i z^i / (i + j)!
            series = series * zs + 1.0 / _FACT[i + j]
        closed = em1 / nz if j == 1 else (out[-1] - 1.0 / _FACT[j - 1]) / nz
        out.append(np.where(small, series, closed))
    return tuple(out)


_FACT = np.cumprod(np.concatenate(([1.0], np.arange(1.0, 21.0))))
"""k! for k = 0..20."""


def _sets(p: np.ndarray, theta, sys: System, drive: Drive, x0: np.ndarray, grid: _Grid):
    """Parameter sets p alone: their theta, system, drive, initial states and grid."""
    return ({k: v[p] for k, v in theta.items()}, System(sys.A[p], sys.B[p], sys.C[p]),
            _take_drive(drive, p), x0[p], _Grid(grid.a, grid.h, grid.u[p]))


def _take_drive(drive: Drive, p: np.ndarray) -> Drive:
    """The drive of parameter sets p only."""
    def take(a: np.ndarray) -> np.ndarray:
        return a[np.minimum(p, a.shape[0] - 1)] if a.shape[0] > 1 else a
    s = drive.s if drive.s.ndim == 1 else drive.s[p]
    return Drive(drive.t0, take(drive.u0), s, take(drive.du))
