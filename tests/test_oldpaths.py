"""Plug-ins and scripts written against the module paths from before the split into
identification, simulation and log keep working, and are told the new path."""

from __future__ import annotations

import subprocess
import sys

from furnace_model.oldpaths import MOVED


def _run(code: str, *flags: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *flags, "-c", code], capture_output=True,
                          text=True, timeout=120)


def test_an_old_path_is_the_module_at_its_new_path():
    """Every old path, in one interpreter started clean (the paths are imported fresh)."""
    pairs = sorted(MOVED.items())
    proc = _run("import importlib, warnings\nwarnings.simplefilter('ignore')\n"
                f"for old, new in {pairs!r}:\n"
                "    a = importlib.import_module('furnace_model.' + old)\n"
                "    b = importlib.import_module('furnace_model.' + new)\n"
                "    assert a is b, (old, a, b)\n"
                "    print(a.__name__)")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == [f"furnace_model.{new}" for _, new in pairs]


def test_an_old_path_warns_with_the_new_one():
    proc = _run("from furnace_model.lti import Drive", "-W", "error::DeprecationWarning")
    assert proc.returncode != 0
    assert "furnace_model.lti is now furnace_model.simulation.lti" in proc.stderr


def test_the_old_fit_module_still_hands_out_its_names():
    proc = _run("import warnings\nwarnings.simplefilter('ignore')\n"
                "from furnace_model.fit import FitResult, Model, Refinement, WarmStart, fit, score\n"
                "from furnace_model.identification.model import Model as M\nassert Model is M")
    assert proc.returncode == 0, proc.stderr


def test_names_that_never_existed_still_fail():
    proc = _run("import furnace_model.no_such_module")
    assert proc.returncode != 0
    assert "ModuleNotFoundError" in proc.stderr
