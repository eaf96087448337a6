"""Effects written by users: registered like ours from one file, used by the simulator, the
diagnosis and the selfcheck with no change elsewhere; and a broken plug-in stopped with one
line that names its file and what is wrong."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from furnace_model.diagnosis import diagnose
from furnace_model.diagnosis.cases import case_rng, draw_case
from furnace_model.diagnosis.selfcheck import judge_case
from furnace_model.effects import EFFECTS, FuelChange, Option, plugins
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.furnacefile import load_furnace
from furnace_model.simulation.parameters import Param
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario
from furnace_model.simulation.structure import ModelStructure

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "examples" / "slab_charging"


class BurnerDerate(FuelChange):
    """A toy: from a time the plant's log gives, every burner gives a share of its heat (a
    derated gas supply); the physics is the fuel switch's, at a known instant."""

    name = "burner_derate"
    physics = "from a known time on, every burner gives only a share of its heat"
    option_specs = {"at_min": Option(1500.0, "number", lo=0.0, hi=1e6, doc="the derating")}
    null = {"derate": 1.0}
    ranges = {"derate": (0.6, 0.8)}

    def _params(self):
        return (Param("derate", 0.9, 0.1, 2.0, unit="-", doc="heat per burner after / before"),)

    def transform_drive(self, theta, drive):
        at = np.full_like(theta["derate"], self.options["at_min"])
        return super().transform_drive({"t_fuel": at, "fuel_ratio": theta["derate"]}, drive)

    @classmethod
    def draw(cls, rng, form, duration_min, furnace):
        # at the time the log gives
        return cls(furnace=furnace), {"derate": cls.uniform(rng, "derate")}


@pytest.fixture
def toy():
    plugins.register(BurnerDerate, "tests/test_plugins.py")
    yield BurnerDerate
    plugins.unregister(BurnerDerate.name)


def test_an_effect_in_one_file_serves_simulator_diagnosis_and_selfcheck(toy, tmp_path):
    assert "burner_derate" in EFFECTS
    # the scenario loader reads it from YAML and the plant simulates it
    doc = (ROOT / "config" / "scenarios" / "paper_exp2.yaml").read_text()  # fires 18 burners
    path = tmp_path / "own.yaml"
    path.write_text(doc.replace("effects: {}", "effects:\n  burner_derate: {at_min: 2000, derate: 0.7}")
                    )
    scenario = load_scenario(path)
    assert [e.name for e in scenario.effects] == ["burner_derate"]
    own = Plant.from_scenario(scenario, seed=0).run_scenario(scenario)
    paper = Plant(ModelStructure(furnace=PAPER), scenario.values(), scenario.sensors, seed=0).run_scenario(
        scenario)
    soak = PAPER.zones.index("soak")
    gap = paper.zone_true[:, soak] - own.zone_true[:, soak]
    assert np.max(np.abs(gap[own.t_min < 2000])) < 1e-9 and np.max(gap) > 50.0
    # the selfcheck draws it, and the diagnosis tries it and names it
    case = draw_case("burner_derate", case_rng(0, "burner_derate", 0), furnace=PAPER)
    assert case.expected_status == "explained" and "derate" in case.truth["burner_derate"]
    d = diagnose(case.fit, case.holdout, effects=("burner_derate", "dead_time"))
    correct, _absorbed, why = judge_case(case, d)
    assert correct, (why, d.verdict.sentence)
    best = d.best()
    assert best.effects == ("burner_derate",)
    truth = case.truth["burner_derate"]["derate"]
    assert best.ci95["derate"][0] <= truth <= best.ci95["derate"][1]
    assert "only a share of its heat" in d.verdict.sentence


def test_a_plug_in_whose_physics_fails_in_a_fit_costs_its_candidate_only(tmp_path):
    path = tmp_path / "fragile.py"
    path.write_text(textwrap.dedent('''
        from furnace_model.effects import Effect
        from furnace_model.simulation.parameters import Param

        class Fragile(Effect):
            name = "fragile"
            physics = "works at its default strength only"
            null = {"k_fragile": 0.0}

            def _params(self):
                return (Param("k_fragile", 0.01, 1e-4, 1.0),)

            def extend(self, A, B, C, theta, first):
                if abs(float(theta["k_fragile"].max()) - 0.01) > 1e-12:
                    raise RuntimeError("fragile physics")
    '''))
    plugins.load_file(path)
    try:
        case = draw_case("zone_burners", np.random.default_rng(21), furnace=PAPER)
        d = diagnose(case.fit, case.holdout, effects=("zone_burners", "fragile"))
    finally:
        plugins.unregister("fragile")
    assert d.verdict.status == "explained" and d.verdict.effects == ["zone_burners"]
    failed = next(c for c in d.candidates if c.effects == ("fragile",))
    assert "fit failed: RuntimeError: fragile physics" in failed.note and not failed.identifiable


GOOD = '''
from furnace_model.effects import Effect
from furnace_model.simulation.parameters import Param

class Leak(Effect):
    name = "leak"
    physics = "the soaking zone leaks"
    null = {"g_soak_leak": 0.0}

    def _params(self):
        return (Param("g_soak_leak", 0.005, 1e-6, 1.0),)

    def extend(self, A, B, C, theta, first):
        A[:, 0, 0] -= theta["g_soak_leak"]
        B[:, 0, self.u_air] += theta["g_soak_leak"]
'''

BROKEN = {
    "syntax": (GOOD.replace("def _params(self):", "def _params(self)"),
               r"broken\.py: line 10: syntax error"),
    "import": ("import no_such_module_here\n" + GOOD,
               r"broken\.py: fails when loaded at line 1: ModuleNotFoundError"),
    "no effect": ("X = 1\n", r"broken\.py: defines no effect"),
    "no physics": (GOOD.replace('    physics = "the soaking zone leaks"\n', ""),
                   r"broken\.py: effect 'leak': `physics` must say"),
    "no null": (GOOD.replace('    null = {"g_soak_leak": 0.0}\n', ""),
                r"broken\.py: effect 'leak': `null` must name"),
    "bad bounds": (GOOD.replace("Param(\"g_soak_leak\", 0.005, 1e-6, 1.0)",
                                "Param(\"g_soak_leak\", 0.005, 1.0, 1e-6)"),
                   r"broken\.py: effect 'leak': parameter 'g_soak_leak': bounds 1\.\.1e-06 "),
    "taken name": (GOOD.replace('name = "leak"', 'name = "dead_time"'),
                   r"broken\.py: effect 'dead_time': the name 'dead_time' is taken"),
    "physics raises": (GOOD.replace("        A[:, 0, 0] -= theta",
                                    "        1 / 0\n        A[:, 0, 0] -= theta"),
                       r"broken\.py: effect 'leak': its physics fails on a short heat-up at "
                       r"its default values at line 14: ZeroDivisionError"),
}


@pytest.mark.parametrize("kind", list(BROKEN))
def test_a_broken_plug_in_is_one_line_naming_its_file(kind, tmp_path):
    text, pattern = BROKEN[kind]
    path = tmp_path / "broken.py"
    path.write_text(text)
    with pytest.raises(plugins.PluginError, match=pattern):
        plugins.load_file(path)
    assert set(EFFECTS) == set(plugins.BUILT_IN), "nothing half-registered"


def test_broken_plug_in_on_the_command_line_exits_2_without_a_traceback(tmp_path):
    path = tmp_path / "broken.py"
    path.write_text(BROKEN["bad bounds"][0])
    r = subprocess.run([sys.executable, "-m", "furnace_model.cli", "simulate", "--scenario",
                        "config/scenarios/paper_exp1.yaml", "--out", str(tmp_path / "x.csv"),
                        "--effects-from", str(path)],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.count("\n") == 1 and str(path) in r.stderr, r.stderr
    assert not (tmp_path / "x.csv").exists()


def model(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "furnace_model.cli", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def charging(tmp_path_factory) -> tuple[Path, Path]:
    """docs/diagnosis.md's worked example: the paper's two experiments in a furnace that
    charges cold slabs into its preheating zone, simulated through the plug-in."""
    d = tmp_path_factory.mktemp("charging")
    out = []
    for k, seed in ((1, "0"), (2, "1")):
        path = d / f"charging_exp{k}.csv"
        r = model("simulate", "--scenario", str(EXAMPLE / f"exp{k}.yaml"), "--out", str(path),
                  "--seed", seed, "--effects-from", str(EXAMPLE / "slab_charging.py"))
        assert r.returncode == 0, r.stderr
        out.append(path)
    return out[0], out[1]


def test_the_plug_in_names_slab_charging_and_closes_the_gap(charging, tmp_path):
    fit, hold = charging
    r = model("diagnose", str(fit), "--holdout", str(hold), "--effects", "slab_charging",
              "--effects-from", str(EXAMPLE / "slab_charging.py"), "--json", str(tmp_path / "d.json"))
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("Verdict: explained (slab_charging)"), r.stdout[:2000]
    import json

    doc = json.loads((tmp_path / "d.json").read_text())
    assert doc["verdict"]["gap_closed_pct"] >= 50
    lo, hi = doc["candidates"][0]["ci95"]["q_charge"]
    assert lo <= 9.0 <= hi, (lo, hi)


@pytest.mark.slow
def test_without_the_plug_in_the_gap_is_unexplained_and_in_the_preheating_zone(charging):
    fit, hold = charging
    r = model("diagnose", str(fit), "--holdout", str(hold))
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("Verdict: unexplained"), r.stdout[:2000]
    first = r.stdout[:r.stdout.index("\n\n")]
    assert "preheating zone" in first, first


def _install(site: Path, name: str, module_text: str) -> None:
    """A package with an entry point in `furnace_model.effects`, as pip would leave it."""
    (site / f"{name}.py").write_text(module_text)
    info = site / f"{name}-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[furnace_model.effects]\nleak = {name}:Leak\n")


def test_an_installed_package_registers_its_effect_and_a_broken_one_is_skipped(tmp_path):
    site = tmp_path / "site"
    site.mkdir()
    _install(site, "leakplug", GOOD)
    scenario = tmp_path / "leak.yaml"
    scenario.write_text((ROOT / "config" / "scenarios" / "paper_exp1.yaml").read_text()
                        .replace("effects: {}", "effects:\n  leak: {g_soak_leak: 0.01}"))
    env = {"PYTHONPATH": f"{site}:{ROOT}"}
    argv = [sys.executable, "-m", "furnace_model.cli", "simulate", "--scenario", str(scenario),
            "--out", str(tmp_path / "leak.csv")]
    r = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=60,
                       env={**os.environ, **env})
    assert r.returncode == 0 and "warning" not in r.stderr, r.stderr
    assert (tmp_path / "leak.csv").exists()
    # the same package broken: the command says so once, and what needs no plug-in still runs
    (site / "leakplug.py").write_text(BROKEN["bad bounds"][0])
    argv[5] = str(ROOT / "config" / "scenarios" / "paper_exp1.yaml")
    r = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=60,
                       env={**os.environ, **env})
    assert r.returncode == 0, r.stderr
    assert "warning: effect plug-in not loaded: entry point leak (leakplug:Leak)" in r.stderr
    assert "bounds 1..1e-06" in r.stderr and "Traceback" not in r.stderr


def test_selfcheck_refuses_by_name_an_effect_it_cannot_draw(tmp_path):
    path = tmp_path / "nodraw.py"
    path.write_text(GOOD)
    r = model("selfcheck", "--effects", "leak", "--draws", "1", "--effects-from", str(path),
              timeout=60)
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert "effect leak has no `draw`" in r.stderr


OLD_STYLE = '''
import numpy as np

from furnace_model.effects import U_AIR, Effect
from furnace_model.lti import Drive
from furnace_model.parameters import Param


class AirDip(Effect):
    name = "air_dip"
    physics = "the air around the furnace is colder for an hour"
    null = {"dip": 0.0}
    ranges = {"dip": (20.0, 40.0)}

    def _params(self):
        return (Param("dip", 5.0, 0.0, 100.0, log=False, unit="degC", doc="how much colder"),)

    def transform_drive(self, theta, drive):
        P, m = theta["dip"].shape[0], drive.du.shape[-1]
        du = np.zeros((P, 2, m))
        du[:, 0, U_AIR], du[:, 1, U_AIR] = -theta["dip"], theta["dip"]
        s = np.concatenate([drive.s, [600.0, 660.0]])
        old = np.broadcast_to(drive.du, (P,) + drive.du.shape[1:])
        return Drive(drive.t0, drive.u0, s, np.concatenate([old, du], axis=1))

    @classmethod
    def draw(cls, rng, form, duration_min):
        return cls(), {"dip": cls.uniform(rng, "dip")}
'''


def test_a_plug_in_written_for_the_paper_s_furnace_alone_still_works(tmp_path):
    """Written against the old module paths and the paper's input channels, constructed
    without a furnace, drawn without one: it loads, is drawn for the paper's furnace with
    DeprecationWarnings that name the new ways, and refuses another furnace in words."""
    path = tmp_path / "air_dip.py"
    path.write_text(OLD_STYLE)
    with pytest.warns(DeprecationWarning):
        plugins.load_file(path)
    try:
        with pytest.warns(DeprecationWarning, match="pass furnace="):
            case = draw_case("air_dip", case_rng(0, "air_dip", 0), furnace=PAPER)
        assert 20.0 <= case.truth["air_dip"]["dip"] <= 40.0
        six = load_furnace(ROOT / "config" / "furnaces" / "six-zone.yaml")
        with pytest.raises(ValueError, match="its draw takes no furnace"):
            draw_case("air_dip", case_rng(0, "air_dip", 0), furnace=six)
    finally:
        plugins.unregister("air_dip")
