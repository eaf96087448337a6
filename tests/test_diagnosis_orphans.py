"""An online diagnosis leaves no process behind: neither when the daemon stops it (a stop
or its time run out) nor when the daemon itself is killed (SIGKILL, an OOM kill), while
its pool's workers are fitting candidates."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from proctree import alive, children

from furnace_daq.daqconfig import DiagnosisConfig
from furnace_daq.diagnosisrunner import DiagnosisRunner
from furnace_daq.diagnosistrigger import DiagnosisRequest
from furnace_model.diagnosis.cases import draw_case
from furnace_model.simulation.furnace import PAPER

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs /proc")


def request() -> DiagnosisRequest:
    """A heat-up whose candidates take the pool a while: zone burners, every effect. Its
    first 1200 minutes: the baseline, fitted before the pool starts, costs their length."""
    exp = draw_case("zone_burners", np.random.default_rng(11), furnace=PAPER).fit[0]
    exp = exp.between(0.0, 1200.0)
    end = int(exp.t_min[-1] * 60e9)
    return DiagnosisRequest("drift", "test", exp, (0, end), exp, (0, end), seed=1)


def tree_of(runner: DiagnosisRunner, deadline: float) -> set[int]:
    """The diagnosis process and its pool's workers, once the workers are there."""
    assert runner.in_flight is not None
    child = runner.in_flight[2].proc.pid
    while time.monotonic() < deadline:
        workers = children(child)
        if workers:
            return {child} | workers
        runner.pump(0.1)
        assert runner.in_flight is not None, "the diagnosis ended before its pool started"
    raise AssertionError("no pool worker was started")


def gone(pids: set[int], within_s: float) -> set[int]:
    deadline = time.monotonic() + within_s
    left = alive(pids)
    while left and time.monotonic() < deadline:
        time.sleep(0.1)
        left = alive(left)
    return left


def test_a_stopped_diagnosis_takes_its_workers_along():
    runner = DiagnosisRunner(DiagnosisConfig(time_limit_s=600.0), lambda *a: None)
    runner.request(request())
    tree: set[int] = set()
    try:
        tree = tree_of(runner, time.monotonic() + 120)
    finally:
        runner.close()
    assert not gone(tree, 20), "outlived the stopped diagnosis"


CHILD = """
import sys, time
sys.path.insert(0, {tests!r})
from test_diagnosis_orphans import DiagnosisConfig, DiagnosisRunner, request, tree_of
runner = DiagnosisRunner(DiagnosisConfig(time_limit_s=600.0), lambda *a: None)
runner.request(request())
print(" ".join(map(str, tree_of(runner, time.monotonic() + 120))), flush=True)
time.sleep(600)
"""


def test_a_killed_daemon_leaves_no_diagnosis_behind():
    """The owner of the runner (the daemon's refit thread) killed with SIGKILL, which no
    handler sees: the diagnosis dies with it (parent-death signal), and its workers with
    the diagnosis."""
    owner = subprocess.Popen([sys.executable, "-c", CHILD.format(tests=str(ROOT / "tests"))],
                             cwd=ROOT, stdout=subprocess.PIPE, text=True)
    tree: set[int] = set()
    try:
        line = owner.stdout.readline() if owner.stdout else ""
        tree = {int(p) for p in line.split()}
        assert len(tree) >= 2, f"no diagnosis with workers was reported: {line!r}"
        os.kill(owner.pid, signal.SIGKILL)
        owner.wait(timeout=30)
        assert not gone(tree, 20), "outlived the killed daemon"
    finally:
        if owner.poll() is None:
            owner.kill()
            owner.wait(timeout=30)
        for p in alive(tree):  # what the test started ends with it, whatever it found
            with contextlib.suppress(OSError):
                os.kill(p, signal.SIGKILL)
