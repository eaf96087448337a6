"""Recovery of logs whose writer died: a real writer process killed with SIGKILL, and files
cut at known places."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from furnace_daq.cli import main
from furnace_daq.logrecover import default_output, recover
from furnace_daq.mcaplog import LogWriter
from furnace_model.errors import DataError
from furnace_model.log.salvage import has_footer, salvage

T0 = 1_772_431_200 * 10**9
S = 10**9

WRITER = textwrap.dedent("""
    import sys, time
    from furnace_daq.mcaplog import LogWriter
    w = LogWriter(sys.argv[1], flush_interval_s=float(sys.argv[2]))
    i = 0
    print("started", flush=True)
    while True:
        t = time.time_ns()
        w.write("/furnace/ambient", {"t_air": 20.0, "i": i}, t)
        w.maybe_flush(time.monotonic())
        print(i, t, flush=True)  # written and, if due, flushed
        i += 1
        time.sleep(0.02)
""")


def _killed_writer(tmp_path: Path, flush_s: float, run_s: float) -> tuple[Path, int]:
    """Run a writer process, SIGKILL it; the .part it left and the log time of the last
    message it reported as written."""
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(tmp_path), str(flush_s)],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "started"
        time.sleep(run_s)
        proc.send_signal(signal.SIGKILL)
        reported = proc.communicate(timeout=10)[0].split()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        proc.stdout.close()
    (part,) = tmp_path.glob("*.mcap.part")
    return part, int(reported[-1])


def _read(path: Path) -> list[tuple[int, dict]]:
    with path.open("rb") as f:
        return [(m.log_time, json.loads(m.data))
                for _, _, m in make_reader(f).iter_messages(log_time_order=True)]


def test_sigkilled_writer_loses_at_most_the_flush_interval(tmp_path: Path, capsys) -> None:
    flush_s = 0.5
    part, last_ns = _killed_writer(tmp_path, flush_s, run_s=3.0)
    assert not has_footer(part)
    assert main(["logs", "recover", str(part)]) == 0
    out = capsys.readouterr().out
    fixed = tmp_path / part.name.replace(".mcap.part", ".recovered.mcap")
    assert fixed.exists() and f"-> {fixed}" in out
    got = _read(fixed)
    assert [m["i"] for _, m in got] == list(range(len(got)))  # a prefix, nothing skipped
    # Every message one flush interval older than the last one the writer reported: a
    # maybe_flush ran after it, so its chunk was closed and fsynced before the kill.
    assert got[-1][0] >= last_ns - int(flush_s * S)
    assert f"saved {len(got)} messages" in out
    assert len(got) > 50
    assert part.exists()  # the input is never touched


def test_without_timed_flush_the_open_chunk_is_all_lost(tmp_path: Path) -> None:
    """The control: the same kill with no chunk closed on a timer saves only what the first
    maybe_flush wrote (the first message); the ~50 messages after it die with the writer."""
    part, _ = _killed_writer(tmp_path, flush_s=3600.0, run_s=1.0)
    assert [m["i"] for _, m in _read(recover(part).out)] == [0]


def _chunked_file(tmp_path: Path, chunks: int = 5, per_chunk: int = 10) -> tuple[Path, list[int]]:
    """A finished file with chunks closed after every `per_chunk` messages, and the byte
    offset at which each chunk's records end."""
    w = LogWriter(tmp_path, flush_interval_s=0.0)
    ends = []
    for c in range(chunks):
        for k in range(per_chunk):
            i = c * per_chunk + k
            w.write("/furnace/thermocouples", {"soak_1": float(i), "i": i}, T0 + i * S)
        w.maybe_flush(float(c))
        ends.append(w.current_path.stat().st_size)
    w.close()
    (path,) = tmp_path.glob("*.mcap")
    return path, ends


@pytest.mark.parametrize("cut_chunk", [1, 3, 5])
def test_recover_a_file_cut_inside_a_chunk(tmp_path: Path, cut_chunk: int) -> None:
    full, ends = _chunked_file(tmp_path)
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap.part"
    # Cut in the middle of chunk `cut_chunk` (after the last one: inside the summary).
    at = ends[cut_chunk - 1] + 40 if cut_chunk < len(ends) else len(data) - 30
    cut.write_bytes(data[:at])
    assert not has_footer(cut)
    r = recover(cut, tmp_path / "fixed.mcap")
    saved = [m["i"] for _, m in _read(r.out)]
    assert saved == list(range(10 * cut_chunk))
    assert r.messages == len(saved) and not r.was_complete
    assert r.start_ns == T0 and r.end_ns == T0 + (len(saved) - 1) * S
    assert "ends inside a record" in r.cut or "no footer" in r.cut


def test_salvage_of_a_complete_file_reads_everything(tmp_path: Path) -> None:
    full, _ = _chunked_file(tmp_path)
    got = salvage(full)
    assert got.complete and got.cut is None and len(got.messages) == 50


def test_recover_names_and_refuses_to_overwrite(tmp_path: Path) -> None:
    assert default_output(Path("/x/furnace-20260302T060000Z.mcap.part")) == \
        Path("/x/furnace-20260302T060000Z.recovered.mcap")
    assert default_output(Path("a.mcap")) == Path("a.recovered.mcap")
    full, _ = _chunked_file(tmp_path)
    with pytest.raises(DataError, match="must differ"):
        recover(full, full)
    recover(full)
    with pytest.raises(DataError, match="exists already"):
        recover(full)
