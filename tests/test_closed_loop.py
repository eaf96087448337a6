"""Closed-loop scenarios: the PLC's PI loops on the plant simulator, their setpoint
programmes, anti-windup, whole burners, a drifting thermocouple under control, and the
open-loop scenarios untouched."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from furnace_model.errors import ConfigError
from furnace_model.shipped import SCENARIOS, shipped_named
from furnace_model.simulation.control import Loop, PIController, staged
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.plant import Plant, PlantRun
from furnace_model.simulation.programme import Programme, ProgrammeStep
from furnace_model.simulation.scenario import Scenario, load_scenario

ROOT = Path(__file__).resolve().parent.parent
REFERENCE = ROOT / "tests" / "data" / "open_loop_reference.npz"

PLANT = """\
furnace: paper-production
sample_min: 1.0
t_air_c: 30.0
initial_c: 30.0
model: {k_soak_heat: 0.020121, k_heat_soak: 0.299049, k_heat_preheat: 0.061544,
        k_preheat_heat: 0.873573, loss_preheat: 0.727504, gain_soak: 0.224131,
        gain_heat: 8.0, gain_preheat: 8.0, gain_charging_heat: -0.1,
        gain_charging_preheat: -0.05}
disturbances: {charging: {steps: [{at_min: 0, value: 0}]}}
"""
"""paper_production.yaml's plant, whose zones each have burners of their own."""


def scenario_of(tmp_path: Path, text: str, name: str = "s", effect: str = "") -> Scenario:
    """The plant with `text` (duration, control) and one more `effect` (a line of YAML)."""
    path = tmp_path / f"{name}.yaml"
    path.write_text(PLANT + text + (f"effects:\n  {effect}\n" if effect else ""))
    return load_scenario(path)


def run(scenario: Scenario, seed: int = 1) -> PlantRun:
    return Plant.from_scenario(scenario, seed=seed).run_scenario(scenario)


def soak_loop(steps: str, extra: str = "") -> str:
    """paper_production.yaml's loops, with the soaking zone's programme `steps` (and
    `extra` keys for its loop); the heating and preheating zones ramp up and hold."""
    return f"""\
control:
  zones:
    soak:
      kp: 0.2
      ti_min: 60{extra}
      setpoint:
        steps: {steps}
    heat:
      kp: 0.05
      ti_min: 10
      setpoint:
        steps: [{{at_min: 0, target_c: 1150, ramp_c_per_min: 2}}]
    preheat:
      kp: 0.2
      ti_min: 5
      setpoint:
        steps: [{{at_min: 0, target_c: 660, ramp_c_per_min: 1.1}}]
"""


def test_pi_tracks_a_ramp_and_a_step_on_the_paper_furnace(tmp_path):
    """The soaking zone's loop: a start-up ramp of 2 °C/min to 1200 °C, a hold, a step of
    +40 °C at minute 900. What the loop controls (the zone's mean reading) stays within
    8 °C of the ramp once the integral has caught up with it (from minute 175; before, the
    loop lags the ramp while it heats the cold furnace), and after the step
    overshoots by less than 15 °C and is back within 5 °C (the mean of 15 minutes) by 150
    minutes after it."""
    s = scenario_of(tmp_path, "duration_min: 1200\n" + soak_loop(
        "[{at_min: 0, target_c: 1200, ramp_c_per_min: 2}, {at_min: 900, target_c: 1240}]"))
    r = run(s)
    measured = PAPER.zone_means(r.tc)[:, 0]
    sp = r.setpoints[:, 0]
    ramp = (r.t_min >= 175) & (r.t_min < 585)
    assert np.abs(measured[ramp] - sp[ramp]).max() < 8.0
    after = r.t_min >= 900
    assert measured[after].max() < 1240 + 15.0
    settled = (r.t_min >= 1050) & (r.t_min < 1065)
    assert abs(measured[settled].mean() - 1240.0) < 5.0


def test_programme_ramps_holds_and_steps():
    p = Programme(30.0, (ProgrammeStep(0.0, 1000.0, 2.0), ProgrammeStep(600.0, 900.0),
                         ProgrammeStep(700.0, 1100.0, 1.0), ProgrammeStep(750.0, 1000.0, 4.0),
                         ProgrammeStep(800.0, 800.0, 5.0)))
    assert p.at(0.0) == 30.0
    assert p.at(100.0) == 230.0
    assert p.at(485.0) == 1000.0  # reached at 485 and held
    assert p.at(599.0) == 1000.0
    assert p.at(600.0) == 900.0  # a step
    assert p.at(740.0) == 940.0
    assert p.at(750.0) == 950.0  # a ramp cut short by the next step, from where it stood
    assert p.at(760.0) == 990.0  # on at 4 °C/min
    assert p.at(762.5) == 1000.0  # and held
    assert p.at(820.0) == 900.0  # down at 5 °C/min
    assert p.at(1e6) == 800.0


def test_clamping_keeps_the_integral_from_winding_up():
    """Saturated for 1000 periods with a large error, the PI leaves its limit the first
    period the error changes sign; a PI that kept integrating would stay there."""
    pi = PIController(kp=0.2, ti_min=60.0, lo=0.0, hi=10.0)
    for _ in range(1000):
        assert pi.update(300.0, 1.0) == 10.0
    assert pi.update(-2.0, 1.0) < 10.0
    assert pi.integral <= 60.0 * 10.0 / 0.2  # at most what the limit needs


def test_no_overshoot_blow_up_after_saturation(tmp_path):
    """An unreachable setpoint (1800 °C) holds the soaking zone's burners at their limit
    for 600 minutes; set back to 1300 °C, the zone overshoots by less than 15 °C: the
    integral did not grow while saturated."""
    s = scenario_of(tmp_path, "duration_min: 1400\n" + soak_loop(
        "[{at_min: 0, target_c: 1800}, {at_min: 600, target_c: 1300}]"))
    r = run(s)
    assert (r.burners[200:600, 0] == 10).all()
    measured = PAPER.zone_means(r.tc)[:, 0]
    assert measured[:600].max() < 1300.0  # still below the new setpoint when it comes
    assert measured[600:].max() < 1300.0 + 15.0
    assert abs(measured[-60:].mean() - 1300.0) < 5.0


def test_a_drifting_controlled_thermocouple_moves_the_true_zone_by_the_drift(tmp_path):
    """The loop on soak_1 alone; soak_1 drifts at -0.05 °C/min from minute 800. The loop
    holds the reading at its setpoint, so the true soaking zone rises by the drift: at the
    end 20 °C hotter than the same run without the drift, within 2 °C."""
    loop = soak_loop("[{at_min: 0, target_c: 1200, ramp_c_per_min: 2}]",
                     "\n      sensor: soak_1")
    clean = scenario_of(tmp_path, "duration_min: 1200\n" + loop, "clean")
    drift = scenario_of(tmp_path, "duration_min: 1200\n" + loop, "drift",
                        "sensor_drift: {sensor: soak_1, drift_rate: -0.05, t_drift: 800}")
    assert [e.name for e in drift.effects] == ["sensor_drift"]
    a, b = run(clean), run(drift)
    end = b.t_min >= 1140
    shift = (b.zone_true[end, 0] - a.zone_true[end, 0]).mean()
    expected = 0.05 * (b.t_min[end] - 800.0).mean()
    assert abs(shift - expected) < 2.0, (shift, expected)
    assert np.allclose(a.zone_true[b.t_min < 800], b.zone_true[b.t_min < 800])


@pytest.mark.parametrize("effect", ["dead_time: {theta_dead: 30}",
                                    "fuel_change: {t_fuel: 150, fuel_ratio: 0.75}"])
def test_an_effect_that_reaches_back_runs_as_its_fired_inputs_run_whole(tmp_path, effect):
    """A dead time or a fuel switch moves burner steps per parameter set; the stepped plant
    simulates each control period from the inputs they can still need (`reach_back`), not
    the whole past. The truth must be what the whole run of the inputs fired gives, and the
    effect must have changed the firing (else the check would be empty)."""
    text = "duration_min: 300\n" + soak_loop("[{at_min: 0, target_c: 1200, ramp_c_per_min: 2}]")
    plain = scenario_of(tmp_path, text, "plain")
    s = scenario_of(tmp_path, text, "effect", effect)
    a, r = run(plain), run(s)
    assert not np.array_equal(a.burners, r.burners)
    again = Plant.from_scenario(s, seed=1).run(_held(r), r.t_min, s.initial_c)
    assert np.allclose(again.zone_true, r.zone_true, atol=1e-6)


def test_reach_back_is_what_the_effects_say_and_all_of_it_when_unsaid():
    from furnace_model.effects import EFFECTS
    from furnace_model.effects.base import Effect
    from furnace_model.simulation.plant import reach_back
    from furnace_model.simulation.structure import ModelStructure

    class Moves(Effect):  # shifts steps in time and says nothing of how far
        name, physics = "moves_steps", "test"

        def _params(self):
            return ()

        def transform_drive(self, theta, drive):
            return drive

    def reach(*effects, **values):
        ms = ModelStructure(effects, furnace=PAPER)
        return reach_back(ms, {**ms.defaults(), **values})

    assert reach() == 0.0
    assert reach(*(EFFECTS[n](furnace=PAPER) for n in ("zone_losses", "sensor_lag",
                                                        "fuel_change", "radiation"))) == 0.0
    assert reach(EFFECTS["dead_time"](furnace=PAPER), theta_dead=17.5) == 17.5
    assert reach(Moves(furnace=PAPER)) == np.inf


def test_staged_output_is_whole_burners_within_limits():
    r = run(dataclasses.replace(load_scenario(shipped_named(SCENARIOS, "paper_production")),
                                duration_min=900.0))
    assert np.array_equal(r.burners, np.round(r.burners))
    assert (r.burners >= 0).all() and (r.burners <= np.array(PAPER.burners)).all()
    assert (r.burners.max(axis=0) > 0).all()  # every zone's loop fires
    both = Loop(0, None, (0, 1, 2), 0.2, 60.0, Programme(30.0, ()))
    assert staged(13.4, both, PAPER) == {0: 10.0, 1: 3.0, 2: 0.0}
    assert staged(13.5, both, PAPER) == {0: 10.0, 1: 4.0, 2: 0.0}
    assert staged(26.0, both, PAPER) == {0: 10.0, 1: 8.0, 2: 8.0}
    assert staged(0.0, both, PAPER) == {0: 0.0, 1: 0.0, 2: 0.0}


def test_the_run_logs_what_was_fired_and_the_setpoints(tmp_path):
    """The record carries the setpoints as signals beside the burners fired, which are
    exactly the loops' output (the plant re-run open loop on them reads the same truth)."""
    s = dataclasses.replace(load_scenario(shipped_named(SCENARIOS, "paper_production")),
                            duration_min=300.0)
    r = run(s)
    exp = r.to_experiment()
    assert sorted(exp.signals) == ["setpoint_heat", "setpoint_preheat", "setpoint_soak"]
    assert exp.signals["setpoint_soak"][100] == 30.0 + 2.0 * 100
    again = Plant.from_scenario(s, seed=1).run(
        _held(r), r.t_min, s.initial_c)
    assert np.allclose(again.zone_true, r.zone_true, atol=1e-6)


def _held(r: PlantRun):
    from furnace_model.simulation.structure import Inputs
    return Inputs(r.t_min, r.burners, r.t_air, r.disturbances)


@pytest.mark.parametrize("name", ["paper_exp1", "modulated_production", "six_zone_effects"])
def test_open_loop_scenarios_run_bit_for_bit_as_before(name):
    """Runs recorded before closed-loop scenarios existed (240 minutes, seed 7): the inputs
    bit for bit, the temperatures to the rounding of sums taken in another order (the
    segment walks run in blocks)."""
    ref = np.load(REFERENCE)
    s = dataclasses.replace(load_scenario(shipped_named(SCENARIOS, name)), duration_min=240.0)
    assert s.control is None
    r = Plant.from_scenario(s, seed=7).run_scenario(s)
    for key in ("t_min", "burners", "t_air", "disturbances"):
        assert np.array_equal(ref[f"{name}.{key}"], getattr(r, key)), key
    for key in ("zone_true", "tc"):
        np.testing.assert_allclose(getattr(r, key), ref[f"{name}.{key}"], rtol=0, atol=1e-9,
                                   err_msg=key)
    assert r.setpoints is None and not r.to_experiment().signals


@pytest.mark.parametrize("control, match", [
    ("control: {zones: {bogus: {}}}", r"control.zones.bogus: unknown key"),
    ("control: {zones: {}}", r"control.zones: name at least one zone"),
    ("control: {zones: {soak: {ti_min: 60, setpoint: {steps: [{at_min: 0, target_c: 900}]}}}}",
     r"control.zones.soak.kp: required key is missing"),
    ("control: {zones: {soak: {kp: -1, ti_min: 60, setpoint: {steps: [{at_min: 0, "
     "target_c: 900}]}}}}", r"control.zones.soak.kp: must be at least"),
    ("control: {zones: {soak: {kp: 1, ti_min: 60, sensor: heat_1, setpoint: {steps: "
     "[{at_min: 0, target_c: 900}]}}}}", r"control.zones.soak.sensor: must be one of"),
    ("control: {zones: {soak: {kp: 1, ti_min: 60, setpoint: {steps: [{at_min: 50, "
     "target_c: 900}, {at_min: 10, target_c: 950}]}}}}",
     r"control.zones.soak.setpoint.steps\[1\].at_min: steps must be in time order"),
    ("control: {zones: {soak: {kp: 1, ti_min: 60, setpoint: {steps: [{at_min: 0, "
     "target_c: 900, ramp_c_per_min: 0}]}}}}",
     r"control.zones.soak.setpoint.steps\[0\].ramp_c_per_min: must be at least"),
    ("control: {zones: {soak: {kp: 1, ti_min: 60, drives: [soak, heat], setpoint: {steps: "
     "[{at_min: 0, target_c: 900}]}}, heat: {kp: 1, ti_min: 9, setpoint: {steps: [{at_min: 0, "
     "target_c: 900}]}}}}",
     r"control.zones.heat.kp: zone heat's input is already set by the loop of zone soak"),
    ("control: {period_min: 0, zones: {soak: {kp: 1, ti_min: 60, setpoint: {steps: "
     "[{at_min: 0, target_c: 900}]}}}}", r"control.period_min: must be at least"),
])
def test_bad_control_sections_name_the_key(tmp_path, control, match):
    path = tmp_path / "bad.yaml"
    path.write_text(PLANT + "duration_min: 100\n" + control + "\n")
    with pytest.raises(ConfigError, match=match) as info:
        load_scenario(path)
    assert str(path) in str(info.value)


def test_the_simulated_plc_serves_its_loops_burners():
    """paper_production.yaml in the simulated PLC over Modbus, on thermocouples without noise
    or bias so that the loops are reproducible: the flame states served at each PLC second
    are what the same loops fire offline at that second."""
    import asyncio

    from pymodbus.client import AsyncModbusTcpClient

    from furnace_daq.registers import decode
    from furnace_daq.simplc import SimPLC, states_from_counts
    from furnace_model.simulation.scenario import SensorSpec

    s = dataclasses.replace(load_scenario(shipped_named(SCENARIOS, "paper_production")),
                            duration_min=400.0,
                            sensors=SensorSpec(noise_sd_c=0.0, bias_c=(0.0,) * 6))
    offline = run(s)

    async def serve() -> list[tuple[int, list[bool]]]:
        plc = SimPLC(s, speed=3000.0, port=0, scan_s=0.05)
        await plc.start()
        client = AsyncModbusTcpClient("127.0.0.1", port=plc.port)
        reads = []
        try:
            await client.connect()
            for _ in range(8):
                await asyncio.sleep(0.3)
                plc.frozen = True  # one scan's registers, read whole
                ir = await client.read_input_registers(0, count=10, device_id=1)
                di = await client.read_discrete_inputs(0, count=26, device_id=1)
                plc.frozen = False
                assert not ir.isError() and not di.isError()
                reads.append((decode(ir.registers[7:9], "uint32", "big"), di.bits[:26]))
        finally:
            client.close()
            await plc.stop()
        return reads

    reads = asyncio.run(serve())
    seconds = [sec for sec, _ in reads]
    assert seconds == sorted(seconds) and seconds[-1] > seconds[0]
    fired = 0
    for sec, bits in reads:
        row = min(int(sec // 60), offline.burners.shape[0] - 1)
        assert bits == states_from_counts(offline.burners[row], PAPER), sec
        fired += sum(bits)
    assert fired > 0


def test_the_modulated_furnace_in_production_holds_its_setpoints_with_rates():
    """The shipped modulated scenario in closed loop: the loops' outputs are the soaking
    zone's firing rate and the heating zone's fuel flow, continuous, within their ranges and
    off their limits in production, and hold the zones' mean readings on the programmes;
    the preheating zone, driven by no loop, fires its hand-set pulse counts."""
    s = load_scenario(shipped_named(SCENARIOS, "modulated_closed_loop"))
    r = run(s)
    furnace = s.furnace
    measured = furnace.zone_means(r.tc)
    production = r.t_min >= 2400  # after the start-up's ramps and their first hold
    for i, zone in enumerate(("soak", "heat")):
        miss = measured[production, i] - r.setpoints[production, i]
        assert abs(np.median(miss)) < 2.0 and np.percentile(np.abs(miss), 95) < 8.0, zone
        out = r.burners[production, i]
        top = furnace.heat_inputs[i].max
        assert ((out > 0.01 * top) & (out < 0.99 * top)).mean() > 0.9, zone
        assert len(np.unique(np.round(out, 3))) > 50, f"{zone}: a rate, not staged burners"
    late = r.burners[r.t_min >= 3300, 2]
    assert np.all(np.isclose(late, 3.0) | np.isclose(late, 5.0))
