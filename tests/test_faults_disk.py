"""A full disk (ENOSPC) or an unwritable log directory (EACCES) while the daemon runs: it
says so on /daq/status, in systemd's STATUS and on stderr (the journal), keeps polling,
writes again when the disk is back, with nothing it buffered lost, and still exits 0."""

from __future__ import annotations

import asyncio
import errno
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest
import yaml
from daq_processes import (
    ROOT,
    config,
    free_port,
    furnace_daq,
    sim,
    start_daemon,
    start_simplc,
    stop,
    wait_for_line,
)

from furnace_daq import mcaplog
from furnace_daq.daemon import Daemon
from furnace_daq.daqconfig import parse_config
from furnace_daq.mcaplog import LogWriter
from furnace_daq.sdnotify import Notifier
from furnace_daq.simplc import SimPLC
from furnace_model.config import Node
from furnace_model.log.read import read_messages
from furnace_model.log.schema import DAQ_EVENTS, DAQ_STATUS, MODEL_PARAMETERS, THERMOCOUPLES
from furnace_model.simulation.scenario import load_scenario

WARM, BROKEN, AFTER = 0.6, 1.2, 1.0
RETRY_S = 5.0  # LogWriter's default retry interval after a failure


def all_messages(log_dir: Path) -> list[tuple[str, dict, int]]:
    """Every message once, from finished files and the ones abandoned during the outage."""
    seen, out = set(), []
    for t, m, lt, _ in read_messages(sorted(log_dir.glob("*.mcap*"))):
        key = (t, lt, repr(sorted(m.items())))
        if key not in seen:
            seen.add(key)
            out.append((t, m, lt))
    return out


@pytest.mark.parametrize("err", [errno.ENOSPC, errno.EACCES], ids=["ENOSPC", "EACCES"])
def test_log_outage_while_running(tmp_path, monkeypatch, capsys, err):
    log_dir = tmp_path / "logs"
    sock_path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(sock_path))
    sock.setblocking(False)
    broken = False
    real_open, real_fsync = os.open, os.fsync

    def failing_open(path, flags, mode=0o777, *a, **k):
        if broken and str(path).startswith(str(log_dir)):
            raise OSError(err, os.strerror(err), str(path))
        return real_open(path, flags, mode, *a, **k)

    def failing_fsync(fd):
        if broken:
            raise OSError(err, os.strerror(err))
        return real_fsync(fd)

    monkeypatch.setattr(mcaplog.os, "open", failing_open)
    monkeypatch.setattr(mcaplog.os, "fsync", failing_fsync)

    notes: list[str] = []

    async def listen():
        loop = asyncio.get_running_loop()
        while True:
            notes.append((await loop.sock_recv(sock, 4096)).decode())

    async def scenario():
        nonlocal broken
        listener = asyncio.create_task(listen())
        plc = await sim(0)
        cfg = config(plc.port, status_interval_s=0.3)
        log = LogWriter(log_dir, flush_interval_s=0.2, retry_s=0.2)
        daemon, task = start_daemon(cfg, log_dir, WARM + BROKEN + AFTER,
                                    notifier=Notifier({"NOTIFY_SOCKET": str(sock_path)}))
        daemon.log = log
        await asyncio.sleep(WARM)
        t_broken = time.time_ns()
        polls_broken = daemon.counters.polls
        broken = True
        await asyncio.sleep(BROKEN)
        error_while_broken = log.error
        broken = False
        t_fixed = time.time_ns()
        polls_during = daemon.counters.polls - polls_broken
        counters = await task
        await plc.stop()
        listener.cancel()
        return counters, error_while_broken, t_broken, t_fixed, polls_during

    try:
        counters, error_while_broken, t_broken, t_fixed, polls_during = asyncio.run(scenario())
    finally:
        sock.close()
    text = os.strerror(err)
    assert error_while_broken and text in error_while_broken
    # kept polling throughout
    assert counters.disconnects == 0 and counters.ok_polls >= 0.9 * counters.polls
    msgs = all_messages(log_dir)
    ok = [lt for t, m, lt in msgs if t == THERMOCOUPLES and m["quality"]["soak_1"] == "ok"]
    assert len(ok) == counters.ok_polls, "every sample polled during the outage was kept"
    # every poll made while the log was broken is in it (a poll counts and takes its log time
    # at the start of its tick, so the counters' split is the log times'), and they went on
    # through it, short of the ticks a busy host skips
    during = [lt for t, _, lt in msgs if t == THERMOCOUPLES and t_broken < lt < t_fixed]
    assert len(during) == polls_during >= 0.25 * BROKEN / 0.05, (len(during), polls_during)
    # said so on /daq/status while it lasted, and in the STATUS line systemd shows
    told = [m for t, m, lt in msgs if t == DAQ_STATUS and text in m.get("log_error", "")]
    assert told
    status_lines = [n for n in notes if n.startswith("STATUS=")]
    assert any("LOG:" in n and text in n for n in status_lines), status_lines
    assert "LOG:" not in status_lines[-1]
    gaps = [m for t, m, _ in msgs if t == DAQ_EVENTS and m["kind"] == "log_gap"]
    assert len(gaps) == 1 and text in gaps[0]["error"] and gaps[0]["dropped"] == 0
    # stderr (the journal under systemd): when it breaks (again if the error changes, not at
    # every retry), and once when it heals
    # with its journal priority: an error while broken, a notice when healed
    told = [line for line in capsys.readouterr().err.splitlines() if line[3:].startswith("log: ")]
    assert 2 <= len(told) <= 4 and all(text in line for line in told[:-1]), told
    assert all(line.startswith("<3>log: ") for line in told[:-1]), told
    assert told[-1] == "<5>log: writing again"


def unprivileged(cmd: list[str]) -> list[str]:
    """Root ignores directory permissions; without CAP_DAC_OVERRIDE (and friends) it obeys
    them like any user, which is how the service runs (DynamicUser)."""
    if os.geteuid() != 0:
        return cmd
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: cannot make a directory unwritable")
    return ["setpriv", "--bounding-set=-dac_override,-dac_read_search,-fowner",
            "--inh-caps=-all", *cmd]


def test_unwritable_log_dir_at_start_never_stops_the_service(tmp_path):
    """The log directory exists but is read-only when the service starts (EACCES): the
    daemon runs, polls, says why nothing is written, writes once the directory is fixed,
    and exits 0 on SIGTERM. A service that exited instead would be restarted by systemd
    into the same error, again and again."""
    log_dir = tmp_path / "logs"
    log_dir.mkdir()
    log_dir.chmod(0o500)
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["poll_period_s"] = 0.05
    doc["status_interval_s"] = 0.5
    doc["log"]["flush_interval_s"] = 0.2
    doc["refit"]["enabled"] = False  # polling and logging only: no refit worker
    cfg = tmp_path / "daq.yaml"
    cfg.write_text(yaml.safe_dump(doc))
    plc, port = start_simplc("--speed", "600")
    daq = None
    try:
        daq = subprocess.Popen(
            unprivileged([sys.executable, "-m", "furnace_daq.cli", "run", "--config", str(cfg),
                          "--plc", f"127.0.0.1:{port}", "--log-dir", str(log_dir)]),
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"})
        # connected: it polls while it cannot write
        early = "".join(wait_for_line(daq, r"^<6>polling ") + wait_for_line(daq, r"^<5>PLC "))
        time.sleep(1.0)
        assert daq.poll() is None, daq.communicate()
        assert not list(log_dir.iterdir())
        log_dir.chmod(0o750)
        t_writable = time.time_ns()
        time.sleep(RETRY_S + 1.0)             # the writer retries every 5 s
        daq.send_signal(signal.SIGTERM)
        _, err = daq.communicate(timeout=20)
        err = early + err
        assert daq.returncode == 0, err
    finally:
        log_dir.chmod(0o750)
        if daq is not None:
            stop(daq)
        stop(plc)
    assert "Permission denied" in err and "log: writing again" in err, err
    files = sorted(log_dir.glob("*.mcap"))
    assert files and not list(log_dir.glob("*.part")), sorted(log_dir.iterdir())
    msgs = [(t, m, lt) for t, m, lt, _ in read_messages(files)]
    (gap,) = [m for t, m, _ in msgs if t == DAQ_EVENTS and m["kind"] == "log_gap"]
    assert "Permission denied" in gap["error"] and gap["dropped"] == 0
    ok_polls = int(re.search(r"stopped: (\d+)/\d+ polls ok", err).group(1))
    logged = [lt for t, m, lt in msgs if t == THERMOCOUPLES and m["quality"]["soak_1"] == "ok"]
    assert len(logged) == ok_polls and min(logged) < t_writable, \
        "the samples of the outage were kept"


@pytest.mark.slow
def test_refits_go_on_while_the_disk_is_full(tmp_path, monkeypatch):
    """Nine simulated hours at 3000x with refits every 2 h over 6-h windows; the disk (log
    and state directory alike) is full for the middle of the run. Every window is still fitted
    and logged once the disk is back, and model.json holds the last one."""
    speed, hours = 3000.0, 9
    log_dir, state_dir = tmp_path / "logs", tmp_path / "state"
    broken = False
    real_open, real_fsync = os.open, os.fsync

    def failing_open(path, flags, mode=0o777, *a, **k):
        if broken and str(path).startswith(str(tmp_path)):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real_open(path, flags, mode, *a, **k)

    def failing_fsync(fd):
        if broken:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_fsync(fd)

    monkeypatch.setattr(mcaplog.os, "open", failing_open)
    monkeypatch.setattr(mcaplog.os, "fsync", failing_fsync)
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["poll_period_s"] = 0.04                  # one poll per 2 simulated minutes
    doc["plc"]["timeout_s"] = 0.2
    doc["clock"]["epoch"] = "2026-03-02T00:00:00Z"
    doc["refit"] = {"period_s": 7200, "window_s": 21600, "step_s": 120,
                    "max_gap_fraction": 0.5, "budget_s": 20, "state_dir": str(state_dir)}
    cfg = parse_config(Node(doc, "test.yaml"))
    seen: list[dict] = []

    async def scenario():
        nonlocal broken
        plc = SimPLC(load_scenario(ROOT / "config" / "scenarios" / "week_steps.yaml"),
                     speed=speed, port=0, seed=1, scan_s=0.04)
        await plc.start()
        cfg_port = replace(cfg, plc=replace(cfg.plc, port=plc.port))
        log = LogWriter(log_dir, flush_interval_s=0.2, retry_s=0.2)
        daemon = Daemon(cfg_port, log, on_model=seen.append)
        task = asyncio.create_task(daemon.run(hours * 3600 / speed))
        await asyncio.sleep(3 * 3600 / speed)      # from 3 h to 7 h of plant time: full
        broken = True
        t_broken = time.time_ns()
        await asyncio.sleep(4 * 3600 / speed)
        broken = False
        t_fixed = time.time_ns()
        counters = await task
        await plc.stop()
        return counters, t_broken, t_fixed

    counters, t_broken, t_fixed = asyncio.run(scenario())
    assert counters.ok_polls >= 0.9 * counters.polls
    msgs = all_messages(log_dir)
    models = [(m, lt) for t, m, lt in msgs if t == MODEL_PARAMETERS]
    assert [m["window_end"][11:16] for m, _ in models] == ["02:00", "04:00", "06:00", "08:00"]
    assert [m for m, _ in models] == seen
    assert any(t_broken < lt < t_fixed for _, lt in models), "a refit during the outage"
    assert sum(m["status"] == "ok" for m, _ in models) >= 2
    saved = json.loads((state_dir / "model.json").read_text())
    assert saved["window_end"] == models[-1][0]["window_end"]
    gaps = [m for t, m, _ in msgs if t == DAQ_EVENTS and m["kind"] == "log_gap"]
    assert len(gaps) == 1 and gaps[0]["dropped"] == 0


def test_log_dir_that_cannot_be_created_is_reported_not_fatal(tmp_path):
    """A log directory that cannot even be created (here: below a regular file, which stops
    root too) is an error on stderr and /daq/status, not an exit: under systemd an exit would
    be restarted into the same error every few seconds."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    proc = furnace_daq("run", "--config", str(ROOT / "config" / "gateway.yaml"), "--plc",
                       f"127.0.0.1:{free_port()}", "--log-dir", str(blocker / "logs"),
                       "--no-refit", "--duration", "1.5")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert f"log: {blocker / 'logs'}: Not a directory" in err and "Traceback" not in err


def mount_tmpfs(path: Path, size: str) -> bool:
    """A tiny tmpfs, to fill it for real; only root with CAP_SYS_ADMIN may mount."""
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    path.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size},mode=0755", "tmpfs",
                           str(path)], capture_output=True, timeout=10)
    return done.returncode == 0


def test_real_disk_full_on_a_tiny_tmpfs(tmp_path):
    """The real thing where the machine allows it: the log directory's filesystem fills up
    (a filler file takes every free block) while `furnace-daq run` writes, then space comes
    back. Same promises as above, with the kernel's ENOSPC rather than a simulated one."""
    log_dir = tmp_path / "disk"
    if not mount_tmpfs(log_dir, "2m"):
        pytest.skip("cannot mount a tmpfs here (needs root): the simulated ENOSPC test covers it")
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["poll_period_s"] = 0.05
    doc["log"]["flush_interval_s"] = 0.2
    doc["refit"]["enabled"] = False  # polling and logging only: no refit worker
    cfg = tmp_path / "daq.yaml"
    cfg.write_text(yaml.safe_dump(doc))
    plc, port = start_simplc("--speed", "600")
    daq = None
    filler = log_dir / "filler"
    try:
        daq = furnace_daq("run", "--config", str(cfg), "--plc", f"127.0.0.1:{port}",
                          "--log-dir", str(log_dir))
        early = "".join(wait_for_line(daq, r"^<6>polling "))
        time.sleep(1.0)
        # every free block, until the kernel says ENOSPC; unbuffered, or the bytes of a short
        # last write stay in the buffer and raise ENOSPC again when the file is closed
        with open(filler, "wb", buffering=0) as f:
            try:
                while True:
                    f.write(b"\0" * 65536)
            except OSError as exc:
                assert exc.errno == errno.ENOSPC
        t_full = time.time_ns()
        time.sleep(2.0)
        assert daq.poll() is None
        t_freed = time.time_ns()
        filler.unlink()
        time.sleep(RETRY_S + 1.0)
        daq.send_signal(signal.SIGTERM)
        _, err = daq.communicate(timeout=20)
        err = early + err
        assert daq.returncode == 0, err
        files = sorted(log_dir.glob("*.mcap*"))
        last = max(files, key=lambda f: f.stat().st_mtime_ns)
        msgs = all_messages(log_dir)
    finally:
        if daq is not None:
            stop(daq)
        stop(plc)
        subprocess.run(["umount", "-l", str(log_dir)], capture_output=True, timeout=10)
    assert "No space left on device" in err and "log: writing again" in err, err
    # the file written last was finished at SIGTERM (one broken by the full disk may stay a
    # .part, read up to its cut, and sorts after its successor `-1.mcap` by name)
    assert last.suffix == ".mcap", files
    (gap,) = [m for t, m, _ in msgs if t == DAQ_EVENTS and m["kind"] == "log_gap"]
    assert "No space left" in gap["error"] and gap["dropped"] == 0
    ok_polls = int(re.search(r"stopped: (\d+)/\d+ polls ok", err).group(1))
    logged = [lt for t, m, lt in msgs if t == THERMOCOUPLES and m["quality"]["soak_1"] == "ok"]
    assert len(logged) == ok_polls, (ok_polls, len(logged))
    assert any(t_full < lt < t_freed for lt in logged), "the samples of the full disk were kept"
