"""An installed wheel carries the shipped files and finds them by name, away from any clone:
the wheel is built from this tree, installed without its dependencies into a directory of
its own (the shared environment provides numpy, pandas, ...), and run from an empty working
directory, so that neither the checkout nor its config/ can stand in for the package."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from wheel_build import ROOT, build_wheel, shipped_in_tree

SHIPPED_PREFIX = "furnace_model/shipped_files/"


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, Path]:
    """The wheel, and the directory it is installed into."""
    work = tmp_path_factory.mktemp("wheel")
    wheel = build_wheel(work)
    target = work / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps",
                    "--no-compile", "--target", str(target), str(wheel)],
                   check=True, capture_output=True, text=True, timeout=120)
    return wheel, target


def run(target: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(target)}  # the installed copy, not the checkout
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=60)


def test_the_wheel_carries_every_shipped_file(installed):
    wheel, _ = installed
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        shipped = sorted(n.removeprefix(SHIPPED_PREFIX) for n in names
                         if n.startswith(SHIPPED_PREFIX))
        assert shipped == shipped_in_tree()
        paper = z.read(SHIPPED_PREFIX + "config/furnaces/paper.yaml")
    assert paper == (ROOT / "config/furnaces/paper.yaml").read_bytes()


def test_the_installed_package_is_the_one_imported(installed, tmp_path):
    _, target = installed
    out = run(target, tmp_path, "-c", "import furnace_model, furnace_daq;"
              "from furnace_model.shipped import shipped;"
              "print(furnace_model.__file__); print(furnace_daq.__file__);"
              "print(shipped('config/furnaces'))")
    assert out.returncode == 0, out.stderr
    assert all(Path(line).is_relative_to(target) for line in out.stdout.split()), out.stdout


def test_shipped_furnaces_by_name_from_an_installation(installed, tmp_path):
    _, target = installed
    paper = run(target, tmp_path, "-m", "furnace_daq.cli", "config", "--furnace", "paper")
    assert paper.returncode == 0, paper.stderr
    assert "register map of furnace 'paper'" in paper.stdout
    six = run(target, tmp_path, "-m", "furnace_daq.cli", "config", "--furnace", "six-zone",
              "--out", "six.yaml")
    assert six.returncode == 0, six.stderr
    # the written config names the shipped description by name, which resolves anywhere
    assert "\nfurnace: six-zone\n" in (tmp_path / "six.yaml").read_text()
    check = run(target, tmp_path, "-c", "from furnace_daq.daqconfig import load_config;"
                "print(load_config('six.yaml').furnace.name)")
    assert check.returncode == 0 and check.stdout.strip() == "six-zone", check.stderr


def test_shipped_scenarios_by_name_from_an_installation(installed, tmp_path):
    _, target = installed
    # a scenario that names its furnace `furnace: modulated`, under --furnace modulated
    sim = run(target, tmp_path, "-m", "furnace_model.cli", "simulate", "--scenario",
              "modulated_production", "--furnace", "modulated", "--out", "m.csv")
    assert sim.returncode == 0, sim.stderr
    assert (tmp_path / "m.csv").stat().st_size > 0
    plc = run(target, tmp_path, "-m", "furnace_daq.cli", "sim-plc", "--scenario",
              "six_zone_heatup", "--port", "0", "--duration", "0.5")
    assert plc.returncode == 0, plc.stderr
    assert "six_zone_heatup" in plc.stdout + plc.stderr


def test_an_unknown_name_lists_the_shipped_ones(installed, tmp_path):
    _, target = installed
    out = run(target, tmp_path, "-m", "furnace_daq.cli", "config", "--furnace", "tunnel")
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert "tunnel" in out.stderr and "modulated, paper, paper-production, six-zone" in out.stderr, out.stderr


def test_the_demo_finds_its_scenarios_and_config_from_an_installation(installed, tmp_path):
    _, target = installed
    code = ("import argparse, pathlib;"
            "from furnace_daq.demo import _of_furnace;"
            "a = argparse.Namespace(furnace={!r}, scenario=None, config=None, protocol=None,"
            " out=pathlib.Path('demo'));"
            "f = _of_furnace(a); print(f.name, a.scenario, a.config, sep='\\n')")
    for furnace, name in ((None, "paper"), ("six-zone", "six-zone")):
        out = run(target, tmp_path, "-c", code.format(furnace))
        assert out.returncode == 0, out.stderr
        got, scenario, config = out.stdout.split("\n")[:3]
        assert got == name and Path(scenario).is_relative_to(target), out.stdout
        assert Path(tmp_path, config).is_file()
