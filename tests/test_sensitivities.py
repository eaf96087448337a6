"""The fit's Jacobian against central differences of its own residuals, for linear,
drive-transforming, sensor-offsetting and nonlinear structures; and the shortcuts the
Jacobian takes where the nonlinear terms vanish (closed form, first order in them)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from heatups import TC_SD

from furnace_model.effects import (
    DeadTime,
    FuelChange,
    Radiation,
    SensorDrift,
    SensorLag,
    ZoneBurners,
)
from furnace_model.identification.problem import Problem
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.parameters import PAPER_TABLE_V
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import SensorSpec, load_scenario
from furnace_model.simulation.structure import Inputs, ModelStructure

SCENARIOS = Path(__file__).resolve().parent.parent / "config" / "scenarios"


@pytest.fixture(scope="module")
def record():
    # Table V's furnace with some radiation and burners in every zone, so that every
    # parameter moves the residuals and none of the structures fits them exactly; 2-minute
    # samples keep the nonlinear integrations short.
    scn = load_scenario(SCENARIOS / "paper_exp2_zone_burners.yaml")
    plant = Plant(ModelStructure([Radiation(furnace=PAPER)],
                                 furnace=PAPER), {**PAPER_TABLE_V, "rad_share": 0.2},
                  SensorSpec(noise_sd_c=TC_SD, bias_sd_c=0.0), seed=1)
    t = np.arange(0.0, 3800.0 + 1e-9, 2.0)
    return plant.run(scn.inputs(), t, scn.initial_c).to_experiment("exp1")


CASES = [
    ([], {}),
    ([ZoneBurners(furnace=PAPER), DeadTime(furnace=PAPER)], {"f_heat": 0.3, "f_preheat": 0.2, "theta_dead": 7.5}),
    ([FuelChange(furnace=PAPER)], {"t_fuel": 1201.0, "fuel_ratio": 0.85}),
    ([SensorDrift(sensor="heat_2", furnace=PAPER)], {"drift_rate": 0.004, "t_drift": 901.0}),
    ([SensorLag(furnace=PAPER)], {"tau_lag": 3.0}),
    ([Radiation(furnace=PAPER)], {"rad_share": 0.3}),
    ([Radiation(furnace=PAPER)], {"rad_share": 0.0}),
    ([Radiation(exponent=None, furnace=PAPER)], {"rad_share": 0.0, "rad_exponent": 4.5}),
    ([Radiation(furnace=PAPER), SensorLag(furnace=PAPER)], {"rad_share": 0.0, "tau_lag": 3.0}),
    ([Radiation(furnace=PAPER), ZoneBurners(furnace=PAPER)], {"rad_share": 0.1, "f_heat": 0.3, "f_preheat": 0.2}),
]


def _problem(effects, values, record):
    structure = ModelStructure(effects, furnace=PAPER)
    prob = Problem([record], structure, {}, {}, zone_offsets=True)
    v = {**PAPER_TABLE_V, **values}
    z = prob.start(prob.to_z(np.array([v[n] for n in prob.names])))
    z[prob.k:prob.k + 3] += np.array([4.0, -3.0, 2.0])  # off the readings' start
    z[prob.k + 3:prob.k + 6] = np.array([0.5, -0.4, 0.3])
    return prob, z


INSTANTS = ("theta_dead", "t_fuel", "t_drift")
"""Instants at which something starts: on a sample time the residual has a kink there."""


def _step(prob: Problem, z: np.ndarray, i: int) -> float:
    """The reference's step in unknown i. An instant's is finer: its column is an impulse
    response, whose third derivative carries the square of the fastest mode's rate, and a
    hundredth of a minute would err by about 1e-6 of the column."""
    if i >= prob.k:
        return 1e-2
    return (1e-6 if prob.names[i] in INSTANTS else 1e-5) * max(1.0, abs(z[i]))


def _central(prob: Problem, z: np.ndarray) -> np.ndarray:
    cols = []
    for i in range(z.size):
        h = _step(prob, z, i)
        up, down = z.copy(), z.copy()
        up[i] += h
        down[i] -= h
        R = prob.fun_many(np.array([up, down]))
        cols.append((R[0] - R[1]) / (2 * h))
    return np.array(cols).T


@pytest.mark.parametrize(("effects", "values"), CASES,
                         ids=[("+".join(e.name for e in c[0]) or "baseline")
                              + "".join(f"-{k}{v:g}" for k, v in c[1].items() if "rad" in k)
                              for c in CASES])
def test_jacobian_agrees_with_central_differences(effects, values, record):
    prob, z = _problem(effects, values, record)
    J = prob.jac(z)
    ref = _central(prob, z)
    assert J.shape == ref.shape == (prob.fun(z).size, prob.n)
    for i, name in enumerate(prob.names + [f"x0_{w}" for w in range(3)]
                             + [f"offset_{w}" for w in range(3)]):
        scale = np.abs(ref[:, i]).max()
        if scale == 0.0:  # unseen: no radiation, no exponent; no preheating burner fires
            assert name in ("rad_exponent", "f_preheat") and not J[:, i].any(), name
            continue
        if name == "rad_share":
            assert scale > 1.0  # the column that switches radiation on is felt
        err = np.abs(J[:, i] - ref[:, i]).max()
        assert err <= 1e-4 * scale, f"{name}: {err:.3g} against a column of {scale:.3g}"


def test_null_share_is_the_linear_model(record):
    """At zero share the radiation structure is eq. 11: the closed form it takes there is
    what the exponential integrator gives, to rounding."""
    inputs, t = Inputs.of(record), record.t_min
    x0 = record.zone_temp[0]
    rad = ModelStructure([Radiation(furnace=PAPER)], furnace=PAPER)
    values = {**PAPER_TABLE_V, "rad_share": np.array([0.0, 0.0])}
    fast = rad.simulate(values, inputs, t, x0).zones
    theta = rad.theta(values)
    sysm = rad.system(theta)
    stepped = rad._exprb(theta, sysm, rad.drive(theta, inputs), np.atleast_2d(x0),
                         float(inputs.t[0]), t, sysm.C)
    plain = ModelStructure(furnace=PAPER).simulate(PAPER_TABLE_V, inputs, t, x0).zones
    assert np.abs(fast - stepped).max() < 1e-8
    assert np.array_equal(fast[0], plain[0])


def test_first_order_is_the_derivative_at_zero_share(record):
    """simulate_first_order departs from the integrated solution by the square of the
    share (so its difference quotient at zero is the derivative), and its derivative is
    the integrator's to some hundred-thousandths (the two schemes' discretisations)."""
    inputs, t = Inputs.of(record), record.t_min
    x0 = record.zone_temp[0]
    rad = ModelStructure([Radiation(furnace=PAPER)], furnace=PAPER)
    base = rad.simulate({**PAPER_TABLE_V, "rad_share": 0.0}, inputs, t, x0).zones[0]
    gaps = []
    for w in (1e-2, 1e-3):
        v = {**PAPER_TABLE_V, "rad_share": w}
        full = rad.simulate(v, inputs, t, x0).zones[0]
        first = rad.simulate_first_order(v, inputs, t, x0)[0]
        gaps.append(np.abs(full - first).max())
        assert np.abs(first - base).max() > 10 * gaps[-1]  # the first order carries the change
    assert gaps[0] / gaps[1] > 50  # second order in the share
    h = 1e-6
    v = {**PAPER_TABLE_V, "rad_share": h}
    fd = (rad.simulate(v, inputs, t, x0).zones[0] - base) / h
    fo = (rad.simulate_first_order(v, inputs, t, x0)[0] - base) / h
    assert np.abs(fo - fd).max() <= 5e-5 * np.abs(fd).max()


def test_first_order_of_a_linear_set_is_its_response(record):
    inputs, t = Inputs.of(record), record.t_min
    rad = ModelStructure([Radiation(furnace=PAPER), SensorLag(furnace=PAPER)], furnace=PAPER)
    v = {**PAPER_TABLE_V, "rad_share": 0.0, "tau_lag": 4.0}
    x0 = record.zone_temp[0]
    assert np.abs(rad.simulate_first_order(v, inputs, t, x0)
                  - rad.simulate(v, inputs, t, x0).zones).max() < 1e-9


LINEAR = ("zone_burners", "zone_losses", "sensor_lag", "dead_time", "wall_storage",
          "burner_nonlinearity", "fuel_change", "sensor_drift")


@pytest.mark.parametrize("shipped", ["paper", "six-zone", "modulated", "production"])
def test_exact_jacobian_on_random_parameter_sets(shipped):
    """Every column the closed form gives matches central differences of the residuals to
    1e-6 of the column, on random parameter sets around the truth, for the baseline and each
    linear effect on each shipped furnace (the modulated one has rates, a pulse-fired zone
    and a disturbance), and on a record of production in closed loop, whose burners change
    nearly every minute (the closed form's branch for many short segments)."""
    from furnace_model.diagnosis.cases import draw_case, draw_closed_loop_case, network_truth
    from furnace_model.effects import EFFECTS
    from furnace_model.simulation.furnacefile import load_furnace

    rng = np.random.default_rng(11)
    if shipped == "production":
        data = draw_closed_loop_case(None, rng).fit
        furnace = data[0].furnace
    else:
        furnace = load_furnace(SCENARIOS.parent / "furnaces" / f"{shipped}.yaml")
        data = draw_case(None, rng, furnace=furnace).fit
    rec = data[0].rows(data[0].t_min <= data[0].t_min[0] + 1500.0)
    for name in ("baseline",) + LINEAR:
        try:
            effects = [] if name == "baseline" else [EFFECTS[name](furnace=furnace)]
        except ValueError as e:  # zone_burners, on a furnace whose burners heat their zone
            assert "does not apply" in str(e)
            continue
        structure = ModelStructure(effects, furnace=furnace)
        prob = Problem([rec], structure, {}, {}, zone_offsets=True)
        truth = {**network_truth(furnace), **structure.defaults(), **network_truth(furnace)}
        for _ in range(2):
            v = prob.to_z(np.array([truth[n] for n in prob.names]))
            v = v + np.where(prob.log, rng.normal(0.0, 0.2, v.size), 0.0)
            # an instant on a sample time is a kink of the residual: no derivative there
            v = v + np.isin(prob.names, INSTANTS) * rng.uniform(0.2, 0.8)
            z = prob.start(np.clip(v, prob.lo, prob.hi))
            z[prob.k:prob.k + prob.nz] += rng.normal(0.0, 3.0, prob.nz)
            J, ref = prob.jac(z), _central(prob, z)
            # what the reference itself rounds to: the residuals' last digits over its step
            rounding = 50 * np.finfo(float).eps * np.abs(prob.fun(z)).max()
            for i, col in enumerate(prob.names + [f"x0_{w}" for w in range(prob.nz)]):
                scale = np.abs(ref[:, i]).max()
                err = np.abs(J[:, i] - ref[:, i]).max()
                assert err <= 1e-6 * scale + rounding / _step(prob, z, i), (
                    f"{shipped} {name} {col}: {err:.3g} against a column of {scale:.3g}")


@pytest.mark.parametrize("steps", [4, 150], ids=["few segments", "many segments"])
def test_closed_form_with_a_conjugate_pair_of_modes(steps):
    """A network with a cycle has a conjugate pair of modes: the closed form's real
    products must give the derivatives of the real response there too, in both its
    branches (a heat-up's few long segments, and an input that moves every sample or two),
    against central differences of the simulator."""
    from furnace_model.simulation.lti import Drive, response
    from furnace_model.simulation.sensitivity import response_sensitivity

    rng = np.random.default_rng(5)
    n, m = 4, 2
    T = np.eye(n) + 0.3 * rng.normal(size=(n, n))
    core = np.zeros((n, n))
    core[:2, :2] = [[-0.05, 0.03], [-0.03, -0.05]]
    core[2, 2], core[3, 3] = -0.1, -0.2
    A = T @ core @ np.linalg.inv(T)
    assert np.iscomplexobj(np.linalg.eigvals(A))
    B, C = rng.normal(size=(n, m)), rng.normal(size=(3, n))
    E, F, g = 0.01 * rng.normal(size=(n, n)), rng.normal(size=(n, m)), rng.normal(size=m)
    t = np.arange(0.0, 300.0, 1.0)
    s = np.sort(rng.uniform(1.0, 290.0, steps))
    u0, du = rng.normal(size=(1, m)), rng.normal(size=(1, steps, m))
    x0 = rng.normal(size=n)

    def simulated(theta, x=x0):
        drive = Drive(0.0, u0 + theta[2] * g, s, du)
        return response((A + theta[0] * E)[None], (B + theta[1] * F)[None], x[None], 0.0,
                        drive, t, C)[0]

    p = 3
    dA = np.stack([E, np.zeros((n, n)), np.zeros((n, n))])
    dB = np.stack([np.zeros((n, m)), F, np.zeros((n, m))])
    d_u0 = np.stack([np.zeros(m), np.zeros(m), g])
    dy, dy0 = response_sensitivity(A, B, C, dA, dB, Drive(0.0, u0, s, du), d_u0,
                                   np.zeros((p, steps, m)), x0, np.eye(n), 0.0, t)
    h = 1e-5
    for i in range(p):
        up, down = np.zeros(p), np.zeros(p)
        up[i], down[i] = h, -h
        ref = (simulated(up) - simulated(down)) / (2 * h)
        assert np.abs(dy[i] - ref).max() <= 1e-6 * np.abs(ref).max(), i
    for i in range(n):
        ref = simulated(np.zeros(p), x0 + np.eye(n)[i]) - simulated(np.zeros(p))
        assert np.abs(dy0[i] - ref).max() <= 1e-9 * np.abs(ref).max(), i


def test_jacobian_with_every_rate_held(record):
    """A refit of a record's own unknowns (its initial states and offsets) under rates held
    fixed, as a held-out record's is: no column moves the drive, and the closed form gives
    the state's and offsets' columns all the same."""
    structure = ModelStructure([FuelChange(furnace=PAPER)], furnace=PAPER)
    fixed = {**PAPER_TABLE_V, "t_fuel": 1201.0, "fuel_ratio": 0.85}
    prob = Problem([record], structure, fixed, {}, zone_offsets=True)
    assert prob.k == 0
    z = prob.start(np.zeros(0))
    z[:3] += np.array([4.0, -3.0, 2.0])
    J, ref = prob.jac(z), _central(prob, z)
    assert J.shape == ref.shape == (prob.fun(z).size, 6)
    assert np.abs(J - ref).max() <= 1e-6 * np.abs(ref).max()
