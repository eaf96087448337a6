"""Starting and stopping the real `furnace-daq` processes from tests."""

from __future__ import annotations

import os
import select
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data"
SCENARIO = DATA / "daq_steps.yaml"


def furnace_daq(*args: str, **kw) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1", **kw.pop("env", {})}
    return subprocess.Popen([sys.executable, "-m", "furnace_daq.cli", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            **kw)


def start_simplc(*args: str, timeout: float = 20.0) -> tuple[subprocess.Popen, int]:
    """Start `furnace-daq sim-plc` on a free port; return once it prints where it listens."""
    proc = furnace_daq("sim-plc", "--scenario", str(SCENARIO), "--port", "0", *args)
    deadline = time.monotonic() + timeout
    line = ""
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], 0.2)
        if ready:
            line = proc.stdout.readline()
            if line.startswith("listening on "):
                return proc, int(line.rsplit(":", 1)[1])
            if not line and proc.poll() is not None:
                break
    stop(proc)
    raise RuntimeError(f"sim-plc did not start: {line!r} {proc.stderr.read()!r}")


def stop(proc: subprocess.Popen, timeout: float = 10.0) -> int:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    for stream in (proc.stdout, proc.stderr):
        if stream:
            stream.close()
    return proc.returncode
