"""Each effect moves the output the way its physics says, and the plant equals the model
when every effect and all noise are off."""

from __future__ import annotations

import numpy as np
import pytest

from furnace_model.effects import (
    EFFECTS,
    BurnerNonlinearity,
    DeadTime,
    FuelChange,
    Radiation,
    SensorDrift,
    SensorLag,
    WallStorage,
    ZoneBurners,
    ZoneLosses,
)
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.parameters import PAPER_TABLE_V
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import SensorSpec, load_scenario
from furnace_model.simulation.structure import Inputs, ModelStructure

X0 = np.full(3, 30.0)
T = np.arange(0.0, 4001.0, 1.0)
STEP = Inputs(np.array([0.0, 2000.0]), np.array([[2, 0, 0], [10, 8, 4.0]]), np.full(2, 30.0))


def run(effects=(), **values):
    ms = ModelStructure(list(effects), furnace=PAPER)
    return ms.simulate({**ms.defaults(), **PAPER_TABLE_V, **values}, STEP, T, X0).zones[0]


BASE = run()


def test_contract_lists_every_effect():
    assert list(EFFECTS) == ["zone_burners", "zone_losses", "sensor_lag", "dead_time",
                             "wall_storage", "radiation", "burner_nonlinearity", "fuel_change",
                             "sensor_drift"]


def test_zone_burners_heat_their_own_zone():
    y = run([ZoneBurners(furnace=PAPER)], f_heat=0.3, f_preheat=0.3)
    before, after = T < 2000, T > 2100
    np.testing.assert_allclose(y[before], BASE[before], rtol=1e-9)  # only soak burners yet
    # the heating zone now gets the heating-zone burners directly: it overtakes the soak
    # zone's lead, and the soak zone, deprived of 12 burners, falls behind the baseline
    assert np.all((y[after, 1] - y[after, 0]) > (BASE[after, 1] - BASE[after, 0]))
    assert np.all(y[after, 0] < BASE[after, 0])


def test_zone_losses_lower_the_steady_state():
    y = run([ZoneLosses(furnace=PAPER)], g_soak=0.005, g_heat=0.005)
    assert np.all(y[100:] < BASE[100:])
    assert np.all(np.diff(BASE[-50:] - y[-50:], axis=0)[:, 0] > -1e-9)  # gap does not close


def test_sensor_lag_delays_a_step_response():
    y = run([SensorLag(furnace=PAPER)], tau_lag=10.0)
    rise_base = BASE[2000:2100] - BASE[2000]
    rise_lag = y[2000:2100] - y[2000]
    assert np.all(rise_lag[1:] < rise_base[1:])
    # time to half of the 100-minute rise comes later
    half = rise_base[-1, 0] / 2
    assert np.argmax(rise_lag[:, 0] > half) > np.argmax(rise_base[:, 0] > half)


def test_dead_time_shifts_the_response():
    """From rest at the first input level, a delayed furnace answers the burner step late by
    exactly the dead time (the input before the record is taken to be its first level)."""
    ms = ModelStructure([DeadTime(furnace=PAPER)], furnace=PAPER)
    sysm = ModelStructure(furnace=PAPER).system(ModelStructure(furnace=PAPER).theta(PAPER_TABLE_V))
    rest = -np.linalg.solve(sysm.A[0], sysm.B[0] @ np.r_[STEP.burners[0], STEP.t_air[0]])
    base = ModelStructure(furnace=PAPER).simulate(PAPER_TABLE_V, STEP, T, rest).zones[0]
    y = ms.simulate({**PAPER_TABLE_V, "theta_dead": 20.0}, STEP, T, rest).zones[0]
    np.testing.assert_allclose(y[20:], base[:-20], rtol=1e-9)
    np.testing.assert_allclose(y[:2021], np.broadcast_to(rest, (2021, 3)), rtol=1e-9)


def test_wall_storage_slows_heating_but_keeps_the_steady_state():
    y = run([WallStorage(furnace=PAPER)], k_gw=0.2, k_wg=0.01)
    assert np.all(y[10:1500] < BASE[10:1500])
    long = np.arange(0.0, 600001.0, 1000.0)  # the wall slows the slowest mode
    ms = ModelStructure([WallStorage(furnace=PAPER)], furnace=PAPER)
    inputs = Inputs(np.array([0.0]), np.array([[4, 0, 0.0]]), np.array([30.0]))
    ys = ms.simulate({**PAPER_TABLE_V, "k_gw": 0.2, "k_wg": 0.01}, inputs, long, X0).zones[0]
    yb = ModelStructure(furnace=PAPER).simulate(PAPER_TABLE_V, inputs, long, X0).zones[0]
    np.testing.assert_allclose(ys[-1], yb[-1], rtol=1e-6)


def test_wall_of_two_layers_and_wall_in_one_zone():
    one = run([WallStorage(furnace=PAPER)], k_gw=0.2, k_wg=0.01)
    # a back layer that takes no heat is the one-layer wall; one that takes heat slows the
    # heat-up further
    idle = run([WallStorage(layers=2, furnace=PAPER)], k_gw=0.2, k_wg=0.01, k_wb=0.0, k_bw=0.001)
    np.testing.assert_allclose(idle, one, rtol=1e-9)
    two = run([WallStorage(layers=2, furnace=PAPER)], k_gw=0.2, k_wg=0.01, k_wb=0.01, k_bw=0.001)
    assert np.all(two[10:1500] < one[10:1500])
    # a preheating-zone wall holds back the preheating zone first, the soaking zone last
    pre = run([WallStorage(zones=("preheat",), furnace=PAPER)], k_gw=0.2, k_wg=0.01)
    lag = (BASE - pre)[5:400]
    assert np.all(lag[:, 2] > lag[:, 1]) and np.all(lag[:, 1] > lag[:, 0])
    assert ModelStructure([WallStorage(zones=("heat",), layers=2, furnace=PAPER)],
                          furnace=PAPER).n_states == 5


def test_radiation_weakens_exchange_below_and_strengthens_it_above_the_reference():
    t = np.arange(0.0, 1501.0, 10.0)
    inputs = Inputs(np.array([0.0]), np.array([[4, 0, 0.0]]), np.array([30.0]))
    base = ModelStructure(furnace=PAPER).simulate(PAPER_TABLE_V, inputs, t, X0).zones[0]
    assert base.max() < 700
    none = ModelStructure([Radiation(furnace=PAPER)],
                          furnace=PAPER).simulate({**PAPER_TABLE_V, "rad_share": 0.0},
                                                  inputs, t, X0).zones[0]
    np.testing.assert_allclose(none, base, rtol=1e-6)
    # everything below the 900 C reference: weaker exchange, the burner zone keeps its heat
    cold = ModelStructure([Radiation(furnace=PAPER)],
                          furnace=PAPER).simulate({**PAPER_TABLE_V, "rad_share": 0.8},
                                                  inputs, t, X0).zones[0]
    assert np.all(cold[5:, 0] > base[5:, 0])
    # a furnace far above a 100 C reference: stronger exchange, the burner zone passes heat on
    warm = X0 + 500.0
    base_warm = ModelStructure(furnace=PAPER).simulate(PAPER_TABLE_V, inputs, t, warm).zones[0]
    hot = ModelStructure([Radiation(t_ref_c=100.0, furnace=PAPER)], furnace=PAPER).simulate(
        {**PAPER_TABLE_V, "rad_share": 0.8}, inputs, t, warm).zones[0]
    assert np.all(hot[5:, 0] < base_warm[5:, 0])


def _radiative_exchange(effect: Radiation, theta: dict, t0: float, t1: float) -> float:
    """Heat flow into zone 0 from zone 1 with one unit exchange, all of it radiative."""
    A = np.zeros((1, 3, 3))
    A[0, 0, 1] = 1.0
    x = np.array([[t0, t1, 0.0]])
    u = np.array([[0.0, 0.0, 0.0, 25.0]])
    extra = effect.nonlinear_rhs({"rad_share": np.array([1.0]), **theta}, x, A,
                                 np.zeros((1, 3, 4)), u)
    return float((t1 - t0) + extra[0, 0])


@pytest.mark.parametrize("options, theta, law", [
    ({"exponent": 4.0}, {}, lambda tk, tr: tr / 4 * (tk / tr) ** 4),
    ({"exponent": None}, {"rad_exponent": np.array([4.5])},
     lambda tk, tr: tr / 4.5 * (tk / tr) ** 4.5),
    ({"emissivity_slope": 0.6}, {},
     lambda tk, tr: tr / 4.6 * (tk / tr) ** 4 * (1 + 0.6 * (tk / tr - 1))),
])
def test_radiation_laws(options, theta, law):
    # a fitted exponent acts as the same fixed one; an emissivity changing with temperature
    # is another law with the same unit slope at the reference
    effect = Radiation(t_ref_c=900.0, **options, furnace=PAPER)
    tr = 900.0 + 273.15
    for t0, t1 in [(300.0, 1200.0), (850.0, 950.0), (1250.0, 1300.0)]:
        expect = law(t1 + 273.15, tr) - law(t0 + 273.15, tr)
        assert _radiative_exchange(effect, theta, t0, t1) == pytest.approx(expect, rel=1e-9)
    near = _radiative_exchange(effect, theta, 899.95, 900.05)
    assert near == pytest.approx(0.1, rel=1e-3)  # the paper's linear exchange at T_ref


def test_burner_nonlinearity_falling_heat_per_burner():
    y = run([BurnerNonlinearity(furnace=PAPER)], k_nl=-0.02)
    rel_early = (BASE[1999] - y[1999]) / (BASE[1999] - 30)
    rel_late = (BASE[-1] - y[-1]) / (BASE[-1] - 30)
    assert np.all(y[1:] < BASE[1:])
    assert rel_late[0] > rel_early[0]  # more burners firing, bigger shortfall
    assert run([BurnerNonlinearity(furnace=PAPER)], k_nl=0.02)[-1, 0] > BASE[-1, 0]


@pytest.mark.parametrize("form, factor", [
    ("linear", lambda n: 1 - 0.02 * n),
    ("power", lambda n: n ** -0.2),
    ("exponential", lambda n: np.exp(-0.02 * n)),
    ("quadratic", lambda n: (1 - 0.01 * n) ** 2),
])
def test_burner_curve_forms(form, factor):
    u = np.array([[[0.0, 0, 0, 25], [4, 0, 0, 25], [10, 8, 8, 25]]])
    out = BurnerNonlinearity(form=form,
                             furnace=PAPER).transform_levels({"k_nl": np.array([-0.02])}, u)
    n = u[0, :, :3].sum(axis=1)
    expect = u[0, :, :3] * np.where(n > 0, factor(np.maximum(n, 1)), 1.0)[:, None]
    np.testing.assert_allclose(out[0, :, :3], expect, rtol=1e-12)
    np.testing.assert_array_equal(out[0, :, 3], 25.0)  # ambient untouched


def test_fuel_change_lowers_heat_after_the_switch_only():
    y = run([FuelChange(furnace=PAPER)], t_fuel=1000.0, fuel_ratio=0.8)
    np.testing.assert_allclose(y[:1001], BASE[:1001], rtol=1e-12)
    assert np.all(y[1002:] < BASE[1002:])


def test_sensor_drift_moves_one_thermocouple_from_its_partner():
    ms = ModelStructure([SensorDrift(sensor="heat_2", furnace=PAPER)], furnace=PAPER)
    off = ms.sensor_offsets({**PAPER_TABLE_V, "drift_rate": 0.01, "t_drift": 500.0}, T)[0]
    assert np.all(off[:, [0, 1, 2, 4, 5]] == 0)
    assert np.all(off[T <= 500, 3] == 0)
    np.testing.assert_allclose(off[T > 500, 3], 0.01 * (T[T > 500] - 500))


def test_plant_without_effects_or_noise_equals_the_model(scenarios):
    scn = load_scenario(scenarios / "paper_exp2.yaml")
    plant = Plant(ModelStructure(furnace=PAPER), scn.params,
                  SensorSpec(noise_sd_c=0.0, bias_sd_c=0.0), seed=1)
    run_ = plant.run_scenario(scn)
    model = ModelStructure(furnace=PAPER).simulate(scn.params, scn.inputs(), scn.sample_times(),
                                      scn.initial_c).zones
    np.testing.assert_array_equal(run_.tc[:, ::2], model[0])
    np.testing.assert_array_equal(run_.tc[:, 1::2], model[0])


def test_plant_noise_and_bias_are_as_configured(scenarios):
    scn = load_scenario(scenarios / "paper_exp1.yaml")
    plant = Plant.from_scenario(scn, seed=5)
    run_ = plant.run_scenario(scn)
    err = run_.tc - run_.zone_true[:, [0, 0, 1, 1, 2, 2]]
    np.testing.assert_allclose(err.mean(axis=0), plant.bias, atol=0.1)
    np.testing.assert_allclose(err.std(axis=0), 1.5, rtol=0.06)
    again = Plant.from_scenario(scn, seed=5).run_scenario(scn)
    np.testing.assert_array_equal(again.tc, run_.tc)


@pytest.mark.parametrize("name", list(EFFECTS))
def test_stepper_matches_a_whole_run(name, scenarios):
    """The simulated PLC advances the plant in small steps; the result must not depend on
    the step size."""
    scn = load_scenario(scenarios / "paper_exp2.yaml")
    effect = EFFECTS[name](furnace=PAPER)
    ms = ModelStructure([effect], furnace=PAPER)
    values = {**ms.defaults(), **scn.params}
    if name == "fuel_change":
        values["t_fuel"] = 2000.0
    plant = Plant(ms, values, SensorSpec(noise_sd_c=0.0, bias_sd_c=0.0))
    t = np.arange(0.0, 3801.0, 100.0)
    whole = plant.run(scn.inputs(), t, scn.initial_c)
    stepper = plant.stepper(scn.initial_c, scn.burners_at(0.0), scn.t_air_c)
    for k, tt in enumerate(t[1:], start=1):
        for sub in np.linspace(t[k - 1], tt, 5)[1:]:
            stepper.set_inputs(scn.burners_at(stepper.t))
            stepper.advance(sub)
        np.testing.assert_allclose(stepper.readings(), whole.tc[k], rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("name", ["dead_time", "fuel_change"])
def test_look_ahead_matches_a_whole_run(name, scenarios):
    """The simulated PLC's look-ahead simulates each hour from the inputs the effect can
    still need (a dead time's worth before it), not the whole schedule; what it serves must
    be the whole run."""
    from furnace_model.simulation.plant import PlantAhead

    scn = load_scenario(scenarios / "paper_exp2.yaml")
    ms = ModelStructure([EFFECTS[name](furnace=PAPER)], furnace=PAPER)
    values = {**ms.defaults(), **scn.params, "theta_dead": 40.0, "t_fuel": 2000.0}
    values = {k: v for k, v in values.items() if k in ms.names}
    plant = Plant(ms, values, SensorSpec(noise_sd_c=0.0, bias_sd_c=0.0))
    t = np.arange(0.0, 3801.0, 100.0) + 0.5
    whole = plant.run(scn.inputs(), t, scn.initial_c)
    ahead = PlantAhead(plant, scn.inputs(), scn.initial_c)
    for k, tt in enumerate(t):
        np.testing.assert_allclose(ahead.readings(int(round(tt * 60))), whole.tc[k],
                                   rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("options", [{}, {"exponent": None}, {"emissivity_slope": -0.5}])
def test_radiation_over_many_states_is_its_law_row_by_row(options):
    """The simulators ask for the nonlinear terms at many states of each parameter set at
    once (`nonlinear_rhs_over`); radiation broadcasts over them itself. It must give what
    its law gives one state at a time, which the base class's default computes."""
    from furnace_model.effects.base import Effect

    rng = np.random.default_rng(3)
    effect = Radiation(t_ref_c=700.0, **options, furnace=PAPER)
    structure = ModelStructure([effect], furnace=PAPER)
    P, S = 4, 7
    values = {n: np.full(P, v) for n, v in structure.defaults().items()}
    values["rad_share"] = rng.uniform(0.1, 0.9, P)
    if "rad_exponent" in values:
        values["rad_exponent"] = rng.uniform(2.0, 5.0, P)
    theta = structure.theta(values)
    sys = structure.system(theta)
    X = rng.uniform(50.0, 1300.0, (P, S, sys.A.shape[1]))
    U = rng.uniform(0.0, 10.0, (P, S, sys.B.shape[2]))
    batched = effect.nonlinear_rhs_over(theta, X, sys.A, sys.B, U)
    rows = np.stack([np.stack([effect.nonlinear_rhs(
        {k: v[p:p + 1] for k, v in theta.items()}, X[p, s][None], sys.A[p:p + 1],
        sys.B[p:p + 1], U[p, s][None])[0] for s in range(S)]) for p in range(P)])
    assert np.abs(batched).max() > 1.0  # the terms are there
    np.testing.assert_allclose(batched, rows, rtol=1e-12, atol=1e-9)
    default = Effect.nonlinear_rhs_over(effect, theta, X, sys.A, sys.B, U)
    np.testing.assert_allclose(default, rows, rtol=1e-12, atol=1e-9)
