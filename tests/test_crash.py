"""Crash and power cut: the real `furnace-daq run` process, polling `sim-plc` through a
counting proxy, killed with SIGKILL at random moments; stopped with SIGTERM; and the
recovery of dead writers' files when the daemon starts again."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest
from crash_runs import (
    FLUSH_S,
    ServedReads,
    daemon_config,
    good_readings,
    kill_runs,
    max_loss_polls,
    wait_polling,
)
from daq_processes import furnace_daq, start_simplc, stop
from faultproxy import ThreadedFaultProxy
from mcap.reader import make_reader

from furnace_daq.logrecover import lock_log_dir, recover_leftovers
from furnace_daq.mcaplog import LogWriter
from furnace_model.errors import DataError
from furnace_model.log.read import read_messages
from furnace_model.log.salvage import has_footer

T0 = 1_772_431_200 * 10**9


def _opens_whole(path: Path) -> int:
    """Messages of a file read through its footer and index (what every MCAP tool does)."""
    with path.open("rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages())


def _sigkill_series(tmp_path: Path, kills: int, seed: int) -> None:
    logs = tmp_path / "logs"
    logs.mkdir()
    config = daemon_config(tmp_path)
    sim, port = start_simplc("--speed", "600", "--scan-s", "0.05")
    try:
        with ThreadedFaultProxy(port) as proxy:
            served = ServedReads(proxy)
            runs = kill_runs(logs, proxy, served, config, kills, seed)
            # The last kill's .part: rescued by hand, as an operator would ...
            parts = list(logs.glob("*.mcap.part"))
            assert len(parts) <= 1, parts
            part = parts[0] if parts else None
            if part is not None:
                rec = furnace_daq("logs", "recover", str(part))
                out, err = rec.communicate(timeout=60)
                assert rec.returncode == 0, err
                assert "saved" in out and "Traceback" not in err
            # ... then a clean run, whose start finds every left-over file handled.
            daq = furnace_daq("run", "--config", str(config), "--plc", f"127.0.0.1:{proxy.port}",
                              "--log-dir", str(logs), "--duration", "1.0")
            _, err = daq.communicate(timeout=60)
            assert daq.returncode == 0, err
            last_served = served.take()
    finally:
        stop(sim)
    report = [(round(k.after_s, 2), k.served, k.logged) for k in runs]
    assert sum(k.served for k in runs) > 5 * kills, report  # the kills hit running daemons
    for k in runs:
        assert 0 <= k.lost <= max_loss_polls(), report
    if part is not None:
        assert "recovered earlier" in err and part.name in err
    assert not list(logs.glob("*.part")) and not list(logs.glob("*.tmp"))
    files = sorted(logs.glob("*.mcap"))
    for f in files:
        assert has_footer(f) and _opens_whole(f) > 0, f
    # Recovery kept every message that could be read from the files the kills left.
    assert good_readings(files) == sum(k.logged for k in runs) + last_served


def test_sigkill_at_random_moments_loses_at_most_the_flush_interval(tmp_path: Path) -> None:
    _sigkill_series(tmp_path, kills=3, seed=1)


@pytest.mark.slow
def test_sigkill_twenty_times(tmp_path: Path) -> None:
    _sigkill_series(tmp_path, kills=20, seed=20)


def test_sigterm_closes_the_file_with_nothing_lost(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    sim, port = start_simplc("--speed", "600", "--scan-s", "0.05")
    try:
        with ThreadedFaultProxy(port) as proxy:
            daq = furnace_daq("run", "--config", str(daemon_config(tmp_path)), "--plc",
                              f"127.0.0.1:{proxy.port}", "--log-dir", str(logs))
            wait_polling(daq)
            time.sleep(1.0 + FLUSH_S)
            deadline = time.monotonic() + 30  # and more than 10 reads, however busy the host
            while ServedReads(proxy).take() <= 10:
                assert daq.poll() is None and time.monotonic() < deadline, "too few polls"
                time.sleep(0.1)
            daq.send_signal(signal.SIGTERM)
            _, err = daq.communicate(timeout=30)
            time.sleep(0.05)
            served = ServedReads(proxy).take()
    finally:
        stop(sim)
    assert daq.returncode == 0, err
    (f,) = logs.glob("*mcap*")
    assert f.suffix == ".mcap" and has_footer(f)
    assert served > 10 and good_readings([f]) == served
    assert _opens_whole(f) > 3 * served  # thermocouples, burners, ambient, status


def _part(log_dir: Path, name: str, messages: int, flushed: bool = True) -> Path:
    """A writer's `.part` as a kill leaves it: `messages` on disk (or none if not flushed)."""
    w = LogWriter(log_dir, flush_interval_s=3600.0)
    for i in range(messages):
        w.write("/furnace/ambient", {"t_air": 20.0, "i": i}, T0 + i * 10**9)
    if flushed:
        w.maybe_flush(0.0)
    part = w.current_path
    w._file.fh.close()  # dies here: no footer, no rename
    return part.rename(log_dir / name)


def test_recovery_at_start_handles_every_kind_of_leftover(tmp_path: Path) -> None:
    good = _part(tmp_path, "furnace-20260302T060000Z.mcap.part", 30)
    empty = tmp_path / "furnace-20260302T070000Z.mcap.part"
    empty.write_bytes(b"")
    cut_header = tmp_path / "furnace-20260302T080000Z.mcap.part"
    cut_header.write_bytes(b"\x89MCA")
    alien = tmp_path / "furnace-20260302T090000Z.mcap.part"
    alien.write_bytes(b"PK\x03\x04 not a log")
    stale_tmp = tmp_path / "furnace-20260302T060000Z.recovered.mcap.tmp"
    stale_tmp.write_bytes(b"half a copy")
    other = _part(tmp_path, "other-20260302T060000Z.mcap.part", 3)

    notes = recover_leftovers(tmp_path, "furnace")

    assert len(notes) == 4, notes
    fixed = tmp_path / "furnace-20260302T060000Z.recovered.mcap"
    assert _opens_whole(fixed) == 30 and not good.exists()
    assert "recovered 30 messages" in notes[0]
    assert not empty.exists() and not cut_header.exists()
    assert alien.exists() and "NOT recovered" in notes[3] and "bad magic" in notes[3]
    assert not stale_tmp.exists()
    assert other.exists()  # another writer's prefix is not ours to touch
    assert recover_leftovers(tmp_path, "furnace") == [notes[3]]  # idempotent


def test_recovery_at_start_after_a_copy_that_was_not_followed_by_the_delete(tmp_path) -> None:
    part = _part(tmp_path, "furnace-20260302T060000Z.mcap.part", 5)
    (note,) = recover_leftovers(tmp_path, "furnace")
    part = _part(tmp_path, part.name, 5)  # as if the delete never happened
    (note,) = recover_leftovers(tmp_path, "furnace")
    assert "recovered earlier" in note and not part.exists()


def test_daemon_start_recovers_and_reports_a_dead_writers_file(tmp_path: Path) -> None:
    part = _part(tmp_path, "furnace-20260302T060000Z.mcap.part", 12)
    daq = furnace_daq("run", "--config", str(daemon_config(tmp_path)), "--plc",
                      "127.0.0.1:1", "--log-dir", str(tmp_path), "--duration", "0.3")
    _, err = daq.communicate(timeout=60)
    assert daq.returncode == 0, err
    assert f"log recovery: {part.name}: recovered 12 messages" in err
    assert not part.exists()
    new = [f for f in tmp_path.glob("furnace-*.mcap") if ".recovered." not in f.name]
    events = [m for t, m, _, _ in read_messages(new, ["/daq/events"])]
    assert any(m["kind"] == "log_recovered" and part.name in m["detail"] for m in events)


def test_a_second_daemon_on_the_same_log_directory_is_refused(tmp_path: Path) -> None:
    fd = lock_log_dir(tmp_path, "furnace")
    try:
        with pytest.raises(DataError, match="another furnace-daq run"):
            lock_log_dir(tmp_path, "furnace")
        daq = furnace_daq("run", "--config", str(daemon_config(tmp_path)), "--plc",
                          "127.0.0.1:1", "--log-dir", str(tmp_path), "--duration", "0.3")
        _, err = daq.communicate(timeout=60)
        assert daq.returncode == 1 and "another furnace-daq run" in err
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1
        lock_log_dir(tmp_path, "other")  # another prefix is another writer
    finally:
        os.close(fd)
