"""The shipped unit passes systemd's own checks.

`systemd-analyze verify` insists that ExecStart's program exists. The unit names the install
location (/opt/furnace-daq); the test checks a copy whose ExecStart points at this checkout's
installed `furnace-daq` entry point, so the program verified is the real one."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from furnace_daq.liveview import LiveViewConfig

ROOT = Path(__file__).resolve().parents[1]
UNIT = ROOT / "systemd" / "furnace-daq.service"
INSTALLED = "/opt/furnace-daq/.venv/bin/furnace-daq"

pytestmark = pytest.mark.skipif(shutil.which("systemd-analyze") is None,
                                reason="systemd-analyze not available")


def local_copy(tmp_path: Path) -> Path:
    entry = Path(sys.prefix) / "bin" / "furnace-daq"
    assert entry.exists(), "the package is installed in the test's environment"
    text = UNIT.read_text()
    assert INSTALLED in text
    path = tmp_path / "furnace-daq.service"
    path.write_text(text.replace(INSTALLED, str(entry)))
    return path


def directives(text: str) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for line in text.splitlines():
        m = re.match(r"^([A-Za-z]+)=(.*)$", line)
        if m:
            out.setdefault(m.group(1), []).append(m.group(2))
    return out


def test_unit_declares_notify_watchdog_restart_and_directories():
    d = directives(UNIT.read_text())
    assert d["Type"] == ["notify"] and d["Restart"] == ["on-failure"]
    assert d["WatchdogSec"] and d["StateDirectory"] and d["LogsDirectory"]
    assert "run --config" in d["ExecStart"][0]
    assert d["RestartPreventExitStatus"] == ["2"]  # config errors exit 2 (ConfigError)


def test_unit_keeps_state_and_logs_and_listens_only_for_the_live_view():
    d = directives(UNIT.read_text())
    assert d["StateDirectory"] == ["furnace-daq"]  # model.json of the refits and write-back
    assert d["LogsDirectory"] == ["furnace-daq"] and d["UMask"] == ["0027"]
    # the Debian package's system user (deb/furnace-daq.sysusers), not a dynamic one
    assert d["User"] == ["furnace-daq"] and d["Group"] == ["furnace-daq"]
    assert "DynamicUser" not in d and d["SocketBindDeny"] == ["any"]
    # The one port the daemon may bind: the live view's default (furnace_daq.liveview).
    assert d["SocketBindAllow"] == [f"tcp:{LiveViewConfig.port}"]
    assert "time-sync.target" in d["After"][0].split()


def test_verify(tmp_path):
    out = subprocess.run(["systemd-analyze", "verify", "--man=no", "--recursive-errors=yes",
                          str(local_copy(tmp_path))], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr


def test_security_exposure_at_most_2(tmp_path):
    out = subprocess.run(["systemd-analyze", "security", "--offline=true",
                          str(local_copy(tmp_path))], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    m = re.search(r"Overall exposure level for \S+: (\d+\.\d+) (\S+)", out.stdout)
    assert m, out.stdout
    assert float(m.group(1)) <= 2.0 and m.group(2) in ("OK", "SAFE"), m.group(0)
