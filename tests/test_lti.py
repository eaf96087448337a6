"""The exact simulator against an independent integrator, and its batching."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from furnace_model.effects import (
    DeadTime,
    FuelChange,
    Radiation,
    SensorLag,
    WallStorage,
    ZoneBurners,
)
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.furnacefile import load_furnace
from furnace_model.simulation.lti import Modes
from furnace_model.simulation.parameters import PAPER_TABLE_V
from furnace_model.simulation.structure import FIRST_STEP_MIN, Inputs, ModelStructure, _first_step


def random_values(structure: ModelStructure, rng: np.random.Generator, P: int) -> dict:
    out = {}
    for p in structure.params:
        if p.name in PAPER_TABLE_V:
            out[p.name] = PAPER_TABLE_V[p.name] * np.exp(rng.uniform(-1.0, 1.0, P))
        elif p.log:
            out[p.name] = p.default * np.exp(rng.uniform(-1.0, 1.0, P))
        else:
            out[p.name] = np.full(P, p.default)
    return out


def random_inputs(rng: np.random.Generator, duration: float = 2000.0) -> Inputs:
    J = int(rng.integers(2, 8))
    t = np.concatenate(([0.0], np.sort(rng.uniform(1.0, duration - 1.0, J - 1))))
    burners = np.column_stack([rng.integers(0, 11, J), rng.integers(0, 9, J),
                               rng.integers(0, 9, J)]).astype(float)
    return Inputs(t, burners, rng.uniform(10.0, 40.0, J))


def reference(structure: ModelStructure, values: dict, inputs: Inputs, t: np.ndarray,
              x0: np.ndarray, delay: float = 0.0) -> np.ndarray:
    """Radau at tight tolerance on the plain ODE, piece by piece between input changes."""
    sysm = structure.system(structure.theta(values))
    A, B, C = sysm.A[0], sysm.B[0], sysm.C[0]
    burner_t = inputs.t + delay

    def u_at(tt):
        jb = max(np.searchsorted(burner_t, tt, side="right") - 1, 0)
        ja = np.searchsorted(inputs.t, tt, side="right") - 1
        return np.r_[inputs.burners[jb], inputs.t_air[ja]]

    edges = np.unique(np.concatenate(([0.0], inputs.t, burner_t, [t[-1]])))
    edges = edges[edges <= t[-1]]
    x = structure.full_state(x0)[0]
    out = np.empty((t.size, A.shape[0]))
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        u = u_at(lo)
        idx = np.nonzero((t >= lo) & (t < hi))[0]
        sol = solve_ivp(lambda _t, xv, u=u: A @ xv + B @ u, (lo, hi), x, method="Radau",
                        rtol=1e-12, atol=1e-10, t_eval=np.append(t[idx], hi))
        out[idx] = sol.y[:, :-1].T
        x = sol.y[:, -1]
    out[t >= edges[-1]] = x
    return out @ C.T


@pytest.mark.parametrize("seed", range(6))
def test_exact_against_solve_ivp_random(seed):
    rng = np.random.default_rng(seed)
    ms = ModelStructure(furnace=PAPER)
    values = {k: v[0] for k, v in random_values(ms, rng, 1).items()}
    inputs = random_inputs(rng)
    # irregular sample times, some of them exactly on input changes
    t = np.unique(np.concatenate((np.sort(rng.uniform(0, 2000, 400)), inputs.t[1:3], [0.0])))
    x0 = rng.uniform(20, 900, 3)
    y = ms.simulate(values, inputs, t, x0).zones[0]
    ref = reference(ms, values, inputs, t, x0)
    assert np.max(np.abs(y - ref) / np.abs(ref)) < 1e-6


@pytest.mark.parametrize("effects", [
    [ZoneBurners(furnace=PAPER)], [SensorLag(furnace=PAPER)], [WallStorage(furnace=PAPER)], [SensorLag(order=2, furnace=PAPER), ZoneBurners(furnace=PAPER)],
], ids=lambda e: "+".join(x.name for x in e))
def test_exact_extended_structures_against_solve_ivp(effects):
    rng = np.random.default_rng(7)
    ms = ModelStructure(effects, furnace=PAPER)
    values = {k: v[0] for k, v in random_values(ms, rng, 1).items()}
    inputs = random_inputs(rng)
    t = np.linspace(0, 2000, 701)
    x0 = np.array([400.0, 300.0, 150.0])
    ref = reference(ms, values, inputs, t, x0)
    y = ms.simulate(values, inputs, t, x0).zones[0]
    assert np.max(np.abs(y - ref) / np.abs(ref)) < 1e-6


def test_per_parameter_step_times_dead_time_exact():
    """A dead time moves the burner steps per parameter set (the superposition path)."""
    rng = np.random.default_rng(3)
    ms = ModelStructure([DeadTime(furnace=PAPER)], furnace=PAPER)
    inputs = random_inputs(rng)
    t = np.linspace(0, 2000, 501)
    x0 = np.array([300.0, 250.0, 100.0])
    delays = np.array([0.5, 7.0, 33.3])
    values = {**PAPER_TABLE_V, "theta_dead": delays}
    y = ms.simulate(values, inputs, t, x0).zones
    for p, delay in enumerate(delays):
        ref = reference(ModelStructure(furnace=PAPER), PAPER_TABLE_V, inputs, t, x0, delay=delay)
        assert np.max(np.abs(y[p] - ref) / np.abs(ref)) < 1e-6


def test_fuel_change_equals_scaled_schedule():
    """A fuel change at t_c is the same as burners scaled from t_c on (checked on the segment
    path, which the fuel change's per-parameter instant does not use)."""
    ms = ModelStructure([FuelChange(furnace=PAPER)], furnace=PAPER)
    inputs = Inputs(np.array([0.0, 500.0, 1500.0]), np.array([[2, 0, 0], [6, 0, 0], [10, 4, 0.0]]),
                    np.full(3, 25.0))
    t = np.linspace(0, 2500, 1001)
    x0 = np.full(3, 25.0)
    y = ms.simulate({**PAPER_TABLE_V, "t_fuel": 1000.0, "fuel_ratio": 0.7}, inputs, t, x0).zones[0]
    scaled = Inputs(np.array([0.0, 500.0, 1000.0, 1500.0]),
                    np.array([[2, 0, 0], [6, 0, 0], [4.2, 0, 0], [7, 2.8, 0.0]]), np.full(4, 25.0))
    ref = ModelStructure(furnace=PAPER).simulate(PAPER_TABLE_V, scaled, t, x0).zones[0]
    np.testing.assert_allclose(y, ref, rtol=1e-9)


def test_batched_call_equals_loop_of_single_calls():
    rng = np.random.default_rng(11)
    for structure in (ModelStructure(furnace=PAPER),
                      ModelStructure([DeadTime(furnace=PAPER), ZoneBurners(furnace=PAPER)],
                                     furnace=PAPER)):
        values = random_values(structure, rng, 40)
        inputs = random_inputs(rng)
        t = np.linspace(0, 2000, 300)
        x0 = rng.uniform(20, 500, (40, 3))
        batch = structure.simulate(values, inputs, t, x0).zones
        for p in range(40):
            single = structure.simulate({k: v[p] for k, v in values.items()}, inputs, t,
                                        x0[p]).zones
            np.testing.assert_allclose(batch[p], single[0], rtol=1e-10, atol=1e-9)


def test_the_carry_from_step_to_step_equals_the_recursion():
    """`carried` against its recursion, step by step, on irregular steps with one long
    gap, modes from hours to a fraction of a second (a sensor lag at its lower bound decays
    by hundreds of e-folds in a minute step), complex pairs, and one row of modes for several
    of contributions: to 1e-11 of the carried value."""
    from furnace_model.simulation.lti import carried

    rng = np.random.default_rng(4)
    for _ in range(60):
        P, K, n = int(rng.integers(1, 4)), int(rng.integers(1, 500)), int(rng.integers(1, 6))
        lam = -(10.0 ** rng.uniform(-4.0, 2.5, (P, n)))
        if rng.random() < 0.3:
            lam = lam + 1j * rng.normal(0.0, 0.5, (P, n))
        if rng.random() < 0.3:
            lam = lam[:1]
        # irregular steps, or minute steps as a furnace in closed loop changes its burners
        gaps = rng.exponential(1.0, K) if rng.random() < 0.5 else np.ones(K)
        if rng.random() < 0.5:
            gaps[rng.integers(0, K)] = 300.0
        T = np.concatenate([[0.0], np.cumsum(gaps)])
        c = rng.normal(size=(P, K, n)) * (1 + 0j if np.iscomplexobj(lam) else 1.0)
        got = carried(lam, T, c)
        ref = np.zeros(got.shape, got.dtype)
        every = np.broadcast_to(lam, (P, n))
        for k in range(1, K):
            ref[:, k] = np.exp(every * (T[k] - T[k - 1])) * ref[:, k - 1] + c[:, k - 1]
        scale = np.abs(ref) + 1e-3 * np.abs(c).max()
        assert np.all(np.abs(got - ref) <= 1e-11 * scale)


def test_samples_before_start_are_refused():
    ms = ModelStructure(furnace=PAPER)
    inputs = Inputs(np.array([10.0]), np.array([[2, 0, 0.0]]), np.array([30.0]))
    with pytest.raises(ValueError, match="precedes"):
        ms.simulate(PAPER_TABLE_V, inputs, np.array([5.0, 20.0]), np.full(3, 30.0))


def test_lag_coinciding_with_a_furnace_mode_stays_exact():
    """A sensor time constant equal to a furnace mode makes A defective: no eigenbasis."""
    ms = ModelStructure([SensorLag(furnace=PAPER)], furnace=PAPER)
    A = ms.system(ms.theta({**PAPER_TABLE_V, "tau_lag": 1.0})).A[0, :3, :3]
    tau = -1.0 / np.sort(np.linalg.eigvals(A).real)[1]
    values = {**PAPER_TABLE_V, "tau_lag": tau}
    inputs = Inputs(np.array([0.0, 100.0]), np.array([[2, 0, 0], [8, 0, 0.0]]), np.full(2, 30.0))
    t = np.linspace(0, 400, 201)
    x0 = np.array([300.0, 200.0, 100.0])
    y = ms.simulate(values, inputs, t, x0).zones[0]
    ref = reference(ms, values, inputs, t, x0)
    assert np.max(np.abs(y - ref) / np.abs(ref)) < 1e-6


def test_per_parameter_step_times_on_an_irregular_grid():
    """Irregular samples (gaps, a step exactly on a sample, steps after the last sample):
    the blockwise impulse sum agrees with the integrator for every parameter set."""
    rng = np.random.default_rng(21)
    ms = ModelStructure([DeadTime(furnace=PAPER), FuelChange(furnace=PAPER),
                         ZoneBurners(furnace=PAPER)], furnace=PAPER)
    inputs = random_inputs(rng)
    t = np.unique(np.concatenate((np.sort(rng.uniform(0, 1500, 300)), inputs.t[1:2], [0.0])))
    x0 = np.array([350.0, 300.0, 120.0])
    delays = np.array([0.3, 12.5, 600.0])
    values = {**PAPER_TABLE_V, "theta_dead": delays, "t_fuel": np.array([700.0, 1e5, 50.0]),
              "fuel_ratio": 1.0, "f_heat": 0.4, "f_preheat": 0.2}
    y = ms.simulate(values, inputs, t, x0).zones
    for p, delay in enumerate(delays):
        ref = reference(ModelStructure([ZoneBurners(furnace=PAPER)],
                                       furnace=PAPER), {**PAPER_TABLE_V, "f_heat": 0.4,
                                                          "f_preheat": 0.2},
                        inputs, t, x0, delay=delay)
        assert np.max(np.abs(y[p] - ref) / np.abs(ref)) < 1e-6


def test_many_per_parameter_step_times_in_blocks_equal_single_calls():
    """More sets than one block of the batched path, with a furnace that never cools (a zero
    eigenvalue, summed directly) among them."""
    rng = np.random.default_rng(5)
    ms = ModelStructure([DeadTime(furnace=PAPER)], furnace=PAPER)
    P = 300
    values = random_values(ms, rng, P)
    values["theta_dead"] = rng.uniform(0.1, 100.0, P)
    values["e"] = values["e"].copy()
    values["e"][7] = 1e-300  # no loss to ambient: the chain keeps all heat
    inputs = random_inputs(rng)
    t = np.arange(0.0, 2001.0)
    x0 = rng.uniform(20, 500, (P, 3))
    batch = ms.simulate(values, inputs, t, x0).zones
    for p in (0, 7, 150, 299):
        single = ms.simulate({k: v[p] for k, v in values.items()}, inputs, t, x0[p]).zones
        np.testing.assert_allclose(batch[p], single[0], rtol=1e-9, atol=1e-8)


@pytest.mark.parametrize("modes", ["real", "complex"])
@pytest.mark.parametrize("steps", [1200, 12])
def test_per_set_step_times_equal_the_direct_sum(modes, steps):
    """A furnace in closed loop moves its inputs nearly every sample, a heat-up a dozen
    times: either way the impulses (summed per sample and carried, or spread over their
    blocks: lti._impulse_response) equal one exponential per sample and step
    (`direct_sum`), for steps between samples, on them and after the last."""
    from furnace_model.simulation import lti

    rng = np.random.default_rng(3)
    P, n, N = 6, 4, 1200
    lam = -np.exp(rng.uniform(-6.0, 1.0, (P, n)))
    if modes == "complex":
        lam = lam + 1j * np.array([0.05, -0.05, 0.2, -0.2])
    t = np.cumsum(rng.choice([1.0, 1.0, 1.0, 0.5, 30.0], N))
    on = t[::N // (steps // 10)][:steps // 10]
    s = np.sort(np.concatenate([rng.uniform(-5.0, t[-1] + 5.0, (P, steps - on.size)),
                                np.broadcast_to(on, (P, on.size))], axis=1), axis=1)
    z = rng.normal(0.0, 100.0, (P, n)) + 0j * lam
    w = rng.normal(0.0, 10.0, (P, n)) + 0j * lam
    dw = rng.normal(0.0, 1.0, (P, s.shape[1], n)) + 0j * lam[:, None, :]
    if modes == "real":
        z, w, dw = z.real, w.real, dw.real
    fast = lti._superposed(lam, z, w, s, dw, -2.0, t)
    direct = direct_sum(lam, z, w, s, dw, -2.0, t)
    np.testing.assert_allclose(fast, direct, rtol=1e-9, atol=1e-9 * np.abs(direct).max())


def direct_sum(lam, z, w, s, dw, t_start, t):
    """The reference of the closed forms: every step's response summed at every sample, one
    exponential per sample and step, phi(tau) = tau where an eigenvalue is zero."""
    from furnace_model.simulation.lti import _propagators

    lam3 = lam[:, :, None]
    e, phi = _propagators(lam3, (t - t_start)[None, None, :])
    Z = z[:, :, None] * e + w[:, :, None] * phi
    for k in range(s.shape[1]):
        _, phi = _propagators(lam3, np.maximum(t[None, :] - s[:, k, None], 0.0)[:, None, :])
        Z += dw[:, k, :, None] * phi
    return Z


@pytest.mark.parametrize("steps", ["per set", "shared"])
@pytest.mark.parametrize("modes", ["real", "complex"])
def test_a_set_with_a_zero_eigenvalue_is_walked_exactly(modes, steps):
    """A set whose furnace keeps its heat (an eigenvalue zero, or too small for -w/lam) among
    others, under steps every sample or so (each set's own, or the record's), between
    samples, on them and after the last: each set equals the direct sum of its steps'
    responses."""
    from furnace_model.simulation import lti

    rng = np.random.default_rng(8)
    P, n, N, K = 4, 3, 900, 700
    lam = -np.exp(rng.uniform(-6.0, 1.0, (P, n)))
    lam[1, 0], lam[2, 2] = 0.0, -3e-11
    if modes == "complex":
        lam = lam + 1j * np.array([0.0, 0.05, -0.05])
    t = np.cumsum(rng.choice([1.0, 1.0, 0.5, 30.0], N))
    s = np.sort(np.concatenate([rng.uniform(0.0, t[-1] + 5.0, (P, K - 50)),
                                np.broadcast_to(t[::18], (P, 50))], axis=1), axis=1)
    z = rng.normal(0.0, 100.0, (P, n)) + 0j * lam
    w = rng.normal(0.0, 10.0, (P, n)) + 0j * lam
    dw = rng.normal(0.0, 1.0, (P, K, n)) + 0j * lam[:, None, :]
    if modes == "real":
        z, w, dw = z.real, w.real, dw.real
    if steps == "shared":
        s = s[0]
    walked = lti._superposed(lam, z, w, s, dw, 0.0, t)
    direct = direct_sum(lam, z, w, np.broadcast_to(s, (P, K)), dw, 0.0, t)
    np.testing.assert_allclose(walked, direct, rtol=1e-9, atol=1e-9 * np.abs(direct).max())


def reference_nonlinear(structure: ModelStructure, values: dict, inputs: Inputs, t: np.ndarray,
                        x0: np.ndarray) -> np.ndarray:
    """Radau at tight tolerance on x' = A x + B u + the effects' nonlinear terms."""
    theta = structure.theta(values)
    sysm = structure.system(theta)
    A, B = sysm.A[0], sysm.B[0]

    def rhs(_t, x, u):
        dx = A @ x + B @ u
        for eff in structure.effects:
            if not eff.linear:
                dx = dx + eff.nonlinear_rhs(theta, x[None], sysm.A, sysm.B, u[None])[0]
        return dx

    x = structure.full_state(x0)[0]
    out = np.empty((t.size, x.size))
    out[t <= inputs.t[0]] = x
    edges = np.concatenate((inputs.t, [t[-1]]))
    for j, (lo, hi) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        u = np.r_[inputs.burners[j], inputs.t_air[j]]
        idx = np.nonzero((t > lo) & (t <= hi))[0]
        sol = solve_ivp(rhs, (lo, hi), x, method="Radau", rtol=1e-12, atol=1e-10,
                        t_eval=np.append(t[idx[t[idx] < hi]], hi), args=(u,))
        out[idx] = sol.y[:, :idx.size].T
        x = sol.y[:, -1]
    return out @ sysm.C[0].T


@pytest.mark.parametrize("effects,values", [
    ([Radiation(furnace=PAPER)], {"rad_share": 0.8}),
    ([Radiation(exponent=3.0, t_ref_c=650.0, furnace=PAPER), ZoneBurners(furnace=PAPER)],
     {"rad_share": 0.9, "f_heat": 2.0, "f_preheat": 3.0}),
    ([Radiation(exponent=5.0, furnace=PAPER), SensorLag(order=2, furnace=PAPER)], {"rad_share": 0.5, "tau_lag": 6.0}),
], ids=["radiation", "cubic+zone_burners", "fifth+lag2"])
def test_radiation_batched_integrator_against_tight_radau(effects, values):
    """A heat-up from cold to 850-1450 degC with a jump of 9 burners: the batched
    exponential integrator stays within 0.01 degC (noise: 1.06) of Radau at
    1e-12, for every set of a batch."""
    ms = ModelStructure(effects, furnace=PAPER)
    inputs = Inputs(np.array([0.0, 700.0, 1500.0, 2300.0]),
                    np.array([[2, 0, 0], [6, 2, 0], [4, 0, 0], [8, 3, 2.0]]), np.full(4, 25.0))
    t = np.arange(0.0, 2601.0)
    x0 = np.full(3, 25.0)
    shares = np.array([0.1, values["rad_share"]])
    y = ms.simulate({**PAPER_TABLE_V, **values, "rad_share": shares}, inputs, t, x0).zones
    for p, share in enumerate(shares):
        ref = reference_nonlinear(ms, {**PAPER_TABLE_V, **values, "rad_share": share}, inputs,
                                  t, x0)
        assert 850 < ref.max() < 1450
        assert np.max(np.abs(y[p] - ref)) < 0.01


def test_radiation_with_per_set_step_times():
    ms = ModelStructure([Radiation(furnace=PAPER), DeadTime(furnace=PAPER)], furnace=PAPER)
    inputs = Inputs(np.array([0.0, 400.0, 900.0]), np.array([[2, 0, 0], [8, 0, 0], [5, 0, 0.0]]),
                    np.full(3, 30.0))
    t = np.arange(0.0, 1201.0, 2.0)
    x0 = np.full(3, 30.0)
    delays = np.array([3.3, 40.0])
    y = ms.simulate({**PAPER_TABLE_V, "rad_share": 0.6, "theta_dead": delays}, inputs, t, x0).zones
    for p, delay in enumerate(delays):
        shifted = Inputs(np.array([0.0, 400.0 + delay, 900.0 + delay]), inputs.burners,
                         inputs.t_air)
        ref = reference_nonlinear(ModelStructure([Radiation(furnace=PAPER)], furnace=PAPER),
                                  {**PAPER_TABLE_V, "rad_share": 0.6}, shifted, t, x0)
        assert np.max(np.abs(y[p] - ref)) < 0.01


def test_a_diverged_set_is_nan_and_leaves_the_batch_alone():
    """A search may propose a set that blows up; it must cost that set an infinite misfit,
    not stop the batch (one eigen-decomposition serves every set)."""
    ms = ModelStructure([Radiation(furnace=PAPER)], furnace=PAPER)
    inputs = Inputs(np.array([0.0, 300.0]), np.array([[2, 0, 0], [6, 0, 0.0]]), np.full(2, 30.0))
    t = np.arange(0.0, 601.0, 5.0)
    x0 = np.array([[30.0, 30.0, 30.0], [np.nan, 30.0, 30.0]])
    y = ms.simulate({**PAPER_TABLE_V, "rad_share": np.array([0.5, 0.5])}, inputs, t, x0).zones
    alone = ms.simulate({**PAPER_TABLE_V, "rad_share": 0.5}, inputs, t, x0[:1]).zones
    assert np.isnan(y[1]).all()
    np.testing.assert_allclose(y[0], alone[0], rtol=0, atol=1e-9)


def test_a_slower_network_relaxes_on_longer_steps_and_stays_exact():
    """The six-zone furnace's fastest mode takes minutes: the relaxation's steps start at
    that scale (a few per hourly input instead of a dozen), and an hourly record about
    its operating point stays within 1e-4 degC of Radau at 1e-12."""
    six = load_furnace(Path(__file__).resolve().parent.parent / "config/furnaces/six-zone.yaml")
    rng = np.random.default_rng(5)
    hours = np.arange(0.0, 2 * 1440.0, 60.0)
    burners = 3.0 * (1.0 + 0.05 * rng.standard_normal((hours.size, six.n_zones)))
    inputs = Inputs(hours, burners, np.full(hours.size, 25.0))
    hold = Inputs(np.array([0.0]), burners[:1], np.array([25.0]))
    linear = ModelStructure([], furnace=six)
    held = linear.simulate(linear.defaults(), hold, np.array([3e4]),
                           np.full(six.n_zones, 25.0)).zones[0, 0]
    ms = ModelStructure([Radiation(t_ref_c=float(held.mean()), furnace=six)], furnace=six)
    values = {**ms.defaults(), "rad_share": 0.8}
    x0 = ms.simulate(values, hold, np.array([3e4]), held).zones[0, 0]
    t = np.arange(0.0, 2 * 1440.0 + 1, 60.0)
    theta = ms.theta(values)
    sysm = ms.system(theta)
    assert _first_step(Modes.of(sysm.A).lam) > FIRST_STEP_MIN
    _, relaxed, _ = ms._relaxed(theta, sysm, ms.drive(theta, inputs), x0[None], 0.0, t)
    assert relaxed.all()
    y = ms.simulate(values, inputs, t, x0).zones[0]
    ref = reference_nonlinear(ms, values, inputs, t, x0)
    assert np.ptp(ref) > 10
    assert np.max(np.abs(y - ref)) < 1e-4


def _operating_point_record(days: int):
    """Hourly inputs a few percent about a hold near radiation's reference temperature (the
    relaxation takes it), from the hold's steady state, with a strong radiative share."""
    rng = np.random.default_rng(3)
    hours = np.arange(0.0, days * 1440.0, 60.0)
    burners = np.array([6.0, 3.0, 2.0]) * (1.0 + 0.05 * rng.standard_normal((hours.size, 3)))
    inputs = Inputs(hours, burners, np.full(hours.size, 25.0))
    hold = Inputs(np.array([0.0]), burners[:1], np.array([25.0]))
    ms = ModelStructure([Radiation(t_ref_c=1200.0, furnace=PAPER)], furnace=PAPER)
    values = {**PAPER_TABLE_V, "rad_share": 0.8}
    x0 = ms.simulate(values, hold, np.array([3e4]), np.full(3, 1200.0)).zones[0, 0]
    return ms, values, inputs, x0, np.arange(0.0, days * 1440.0 + 1, 60.0)


def test_a_record_about_its_operating_point_is_relaxed_and_exact():
    """Hourly inputs that move a few percent about a hold near the law's reference
    temperature: the waveform relaxation takes the whole record (no step-by-step
    integration) and stays within 1e-4 degC of Radau at 1e-12; a heat-up from cold with a
    strong radiative share does not converge and is left to the stepping integrator."""
    ms, values, inputs, x0, t = _operating_point_record(days=4)
    theta = ms.theta(values)
    sysm = ms.system(theta)
    _, relaxed, _ = ms._relaxed(theta, sysm, ms.drive(theta, inputs), x0[None], 0.0, t)
    assert relaxed.all()
    y = ms.simulate(values, inputs, t, x0).zones[0]
    ref = reference_nonlinear(ms, values, inputs, t, x0)
    assert np.ptp(ref) > 20  # the record moves, and radiation bends it
    assert np.max(np.abs(y - ref)) < 1e-4

    heatup = Inputs(np.array([0.0, 700.0]), np.array([[2, 0, 0], [8, 3, 2.0]]), np.full(2, 25.0))
    cold = ModelStructure([Radiation(furnace=PAPER)], furnace=PAPER)
    theta = cold.theta(values)
    _, relaxed, _ = cold._relaxed(theta, cold.system(theta), cold.drive(theta, heatup),
                               np.full((1, 3), 25.0), 0.0, np.arange(0.0, 1401.0))
    assert not relaxed.any()


def test_a_jacobians_sets_relaxed_from_the_first_give_its_differences(monkeypatch):
    """Known truth: the differences of sets relaxed each from its own linear response
    (`together`). Relaxed from the first set's trajectory with its linear part
    (`differences`), the first set is what it is alone and every forward difference
    (a rate, the share, an initial state) the same to 1e-5 of its size; and they are
    relaxed so, the first alone and then all from it, not sent back to `together`."""
    ms, values, inputs, x0, t = _operating_point_record(days=2)
    sweeps = ModelStructure._sweeps
    started = []

    def counted(self, theta, *args, **kwargs):
        about = args[7] if len(args) > 7 else kwargs.get("about")
        started.append((next(iter(theta.values())).shape[0], about is not None))
        return sweeps(self, theta, *args, **kwargs)

    names = ["a", "d", "rad_share"]
    P = 1 + len(names) + 1
    sets = {k: np.full(P, float(v)) for k, v in values.items()}
    for i, name in enumerate(names):
        sets[name][1 + i] *= 1.0 + 1e-6
    x0s = np.repeat(x0[None], P, axis=0)
    x0s[-1, 2] += 1e-3
    together = ms.simulate(sets, inputs, t, x0s).zones
    monkeypatch.setattr(ModelStructure, "_sweeps", counted)
    apart = ms.simulate(sets, inputs, t, x0s, batch="differences").zones
    monkeypatch.undo()
    assert started == [(1, False), (P, True)]
    alone = ms.simulate(values, inputs, t, x0).zones[0]
    np.testing.assert_allclose(apart[0], alone, rtol=0, atol=1e-9)
    for p in range(1, P):
        d_together, d_apart = together[p] - together[0], apart[p] - apart[0]
        size = np.abs(d_together).max()
        assert size > 1e-6, p  # each set moves the response
        assert np.abs(d_apart - d_together).max() < 1e-5 * size, p


def test_sets_scored_each_on_its_own_step_only_those_the_relaxation_leaves():
    """A population with a member far from the law's reference (a heat-up from cold with
    a strong share, which the relaxation does not take) beside members it takes: scored
    `each`, the members taken are what they are alone and the other is what the stepping
    integrator gives it alone; `together`, all are stepped."""
    ms, values, inputs, x0, t = _operating_point_record(days=2)
    cold = np.full(3, 25.0)
    sets = {k: np.full(3, float(v)) for k, v in values.items()}
    sets["rad_share"] = np.array([0.8, 0.9, 0.8])
    x0s = np.stack([x0, x0, cold])
    each = ms.simulate(sets, inputs, t, x0s, batch="each").zones
    for p in range(3):
        alone = ms.simulate({k: v[p] for k, v in sets.items()}, inputs, t, x0s[p]).zones[0]
        np.testing.assert_allclose(each[p], alone, rtol=0, atol=1e-8)
    theta = ms.theta(sets)
    _, relaxed, _ = ms._relaxed(theta, ms.system(theta), ms.drive(theta, inputs), x0s, 0.0, t,
                                "each")
    assert relaxed.tolist() == [True, True, False]
    together = ms.simulate(sets, inputs, t, x0s).zones
    assert np.abs(together[:2] - each[:2]).max() > 1e-9  # stepped, not relaxed


@pytest.mark.parametrize("pieces", ["a handful of lengths", "each its own length"])
@pytest.mark.parametrize("first", [0.5, 2.0, 64.0])
def test_the_grid_laid_out_once_is_the_steps_piece_by_piece(first, pieces):
    """A record with thousands of input changes, of a handful of lengths (a minute grid) or
    each its own (a logger's rows seconds off their grid): its steps come from one layout
    cut per piece, and are those `_step_bounds` takes piece by piece (to rounding of the
    pieces' start times)."""
    from furnace_model.simulation.lti import Drive
    from furnace_model.simulation.structure import _Grid, _step_bounds

    rng = np.random.default_rng(11)
    if pieces == "a handful of lengths":
        s = np.cumsum(rng.choice([1.0, 1.0, 2.5, 60.0, 0.3], 3000))
    else:
        s = np.cumsum(5.0 + rng.uniform(-0.7, 0.7, 3000) + rng.choice([0.0, 300.0], 3000,
                                                                        p=[0.99, 0.01]))
    drive = Drive(0.0, np.zeros((1, 1)), s, np.zeros((1, s.size, 1)))
    end = float(s[-1]) + 17.0
    grid = _Grid.of(drive, 0.25, end, 1, first)
    edges = np.concatenate(([0.25], s[s > 0.25], [end]))
    bounds = [_step_bounds(lo, hi, first)
              for lo, hi in zip(edges[:-1], edges[1:], strict=True) if hi > lo]
    np.testing.assert_allclose(grid.a, np.concatenate([b[:-1] for b in bounds]), rtol=0,
                               atol=1e-9)
    np.testing.assert_allclose(grid.h, np.concatenate([np.diff(b) for b in bounds]), rtol=0,
                               atol=1e-9)
    assert grid.a[0] == 0.25 and grid.a[-1] + grid.h[-1] == end


def test_levels_of_per_set_steps_are_the_levels_at_each_time():
    """Per-set step times (a fuel switch moves the steps after its instant), unsorted, some
    on the times asked and some before the drive's start: the levels found by one
    cumulative sum per set, for every set or one, are those in force at each time."""
    from furnace_model.simulation.lti import Drive

    rng = np.random.default_rng(12)
    P, K, m = 3, 400, 2
    s = rng.uniform(-10.0, 500.0, (P, K))
    times = np.sort(np.concatenate([rng.uniform(-20.0, 520.0, 150), s[1, :20]]))
    for du_sets in (P, 1):  # increments per set, or shared
        drive = Drive(0.0, rng.normal(0.0, 5.0, (P, m)), s, rng.normal(0.0, 1.0, (du_sets, K, m)))
        each = np.stack([drive.level_at(float(x)) for x in times], axis=1)
        np.testing.assert_allclose(drive.levels_at(times), each, rtol=0, atol=1e-9)
        for p in range(P):
            np.testing.assert_allclose(drive.levels_at(times, p)[0], each[p], rtol=0,
                                       atol=1e-9)


def test_the_relaxations_quadrature_is_the_forced_response_at_its_nodes_and_between():
    """Known truth: d' = A d + g(t), d(t0) = 0, for g quadratic on each step through its
    values at the step's start, middle and end, integrated step by step by Radau at 1e-12.
    A sweep's convolver (at the grid's own nodes, weighing each step's middle only) and the
    convolver at any times (the samples) both give it; sets with real and complex modes,
    steps from a fraction of the fastest mode's time constant to many of them."""
    from furnace_model.simulation.lti import Drive
    from furnace_model.simulation.structure import _Grid

    A = np.array([[[-0.9, 0.4], [0.1, -0.05]], [[-0.2, 0.5], [-0.6, -0.3]]])  # real, complex
    s = np.array([3.0, 3.5, 40.0, 41.0, 90.0])
    drive = Drive(0.0, np.zeros((2, 1)), s, np.zeros((2, s.size, 1)))
    grid = _Grid.of(drive, 0.0, 130.0, 2, 0.25)
    nodes = grid.nodes
    g = np.stack([np.stack([np.sin(nodes / (7.0 + p)), np.cos(nodes / 5.0) * (1 + p)], -1)
                  for p in range(2)])  # (P, nodes, n)
    modes = Modes.of(A)
    times = np.sort(np.random.default_rng(4).uniform(0.0, 130.0, 40))
    at_nodes = grid.node_convolver(modes)(grid.at_nodes(g))
    anywhere = grid.convolved(modes, grid.at_nodes(g), times, 0.0)
    assert grid.a.size > 30 and np.iscomplexobj(modes.lam)

    for p in range(2):
        d, ref_nodes, ref_times = np.zeros(2), [np.zeros(2)], []
        for k, (a, h) in enumerate(zip(grid.a, grid.h, strict=True)):
            g0, gh, g1 = g[p, 2 * k], g[p, 2 * k + 1], g[p, 2 * k + 2]
            c1, c2 = (4 * gh - 3 * g0 - g1) / h, 2 * (g1 - 2 * gh + g0) / h ** 2
            inside = times[(times > a) & (times <= a + h)]
            at = np.unique(np.concatenate([[a + h / 2, a + h], inside]))
            sol = solve_ivp(lambda t, x, a=a, g0=g0, c1=c1, c2=c2, M=A[p]: M @ x + g0
                            + c1 * (t - a) + c2 * (t - a) ** 2, (a, a + h), d, method="Radau",
                            rtol=1e-12, atol=1e-12, t_eval=at)
            ref_nodes += [sol.y[:, at == a + h / 2][:, 0], sol.y[:, -1]]
            ref_times += [sol.y[:, at == x][:, 0] for x in inside]
            d = sol.y[:, -1]
        ref = np.array(ref_nodes)
        np.testing.assert_allclose(at_nodes[p].reshape(-1, 2)[0::3], ref[0:-1:2], atol=1e-8)
        np.testing.assert_allclose(at_nodes[p, :, 1], ref[1::2], atol=1e-8)
        np.testing.assert_allclose(at_nodes[p, :, 2], ref[2::2], atol=1e-8)
        np.testing.assert_allclose(anywhere[p], np.array(ref_times), atol=1e-8)
