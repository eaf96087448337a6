"""mbpoll, a Modbus master we did not write, reads the simulated PLC's documented map."""

from __future__ import annotations

import re
import shutil
import subprocess
import time

import numpy as np
import pytest
from daq_processes import SCENARIO, start_simplc, stop

from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

pytestmark = pytest.mark.skipif(shutil.which("mbpoll") is None,
                                reason="mbpoll not installed (make system-deps)")


def mbpoll(port: int, *args: str) -> list[int]:
    out = subprocess.run(["mbpoll", "-m", "tcp", "-p", str(port), "-a", "1", "-1", "-o", "2",
                          *args, "127.0.0.1"], capture_output=True, text=True, timeout=20)
    assert out.returncode == 0, out.stdout + out.stderr
    return [int(v) for v in re.findall(r"^\[\d+\]:\s+(-?\d+)", out.stdout, re.M)]


def test_mbpoll_reads_thermocouples_clock_and_burners():
    scenario = load_scenario(SCENARIO)
    proc, port = start_simplc("--speed", "60")
    try:
        burners = mbpoll(port, "-t", "1", "-r", "1", "-c", "26")  # FC2, 1-based reference
        regs = mbpoll(port, "-t", "3", "-r", "1", "-c", "10")     # FC4
    finally:
        assert stop(proc) == 0
    assert len(regs) == 10 and len(burners) == 26
    seconds = (regs[7] << 16) | regs[8]  # UINT32, high word first
    assert 0 <= seconds < 5 * 60, "60x for a few wall seconds stays in the first step"
    assert regs[9] > 0, "heartbeat counts scans"
    run = Plant.from_scenario(scenario).run(scenario.inputs(), np.array([seconds / 60.0]),
                                            scenario.initial_c)
    expected = np.round(run.tc[0] * 10).astype(int)
    np.testing.assert_array_equal(regs[:6], expected)
    assert regs[6] == round(scenario.t_air_c * 10)
    assert burners == [1, 1] + [0] * 24  # schedule: 2 soaking-zone burners at the start


def test_mbpoll_coil_writes_drive_manual_burners():
    proc, port = start_simplc("--speed", "60", "--manual")
    try:
        written = [1, 0, 1, 1, 0, 0, 0, 0, 0, 0] + [1] * 8 + [0, 1, 0, 0, 0, 0, 0, 1]
        subprocess.run(["mbpoll", "-m", "tcp", "-p", str(port), "-a", "1", "-t", "0", "-r",
                        "1", "-o", "2", "127.0.0.1", *map(str, written)],
                       capture_output=True, text=True, timeout=20, check=True)
        time.sleep(0.5)  # a few PLC scans
        burners = mbpoll(port, "-t", "1", "-r", "1", "-c", "26")
    finally:
        assert stop(proc) == 0
    assert burners == written
