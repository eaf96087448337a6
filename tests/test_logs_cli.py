"""`furnace-daq logs info|export|recover` on real log files."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from furnace_daq.cli import main
from furnace_daq.logmeta import build_metadata
from furnace_daq.mcaplog import LogWriter
from furnace_model.records import load_experiment
from furnace_model.simulation.furnace import PAPER

T0 = 1_772_431_200 * 10**9  # 2026-03-02T06:00:00Z, on a minute
H0 = T0 + 5 * 86400 * 10**9  # host clock: the simulated PLC runs 100x faster
S = 10**9


def _tc(i: int) -> dict:
    vals = {s: 400.0 for s in PAPER.sensors}
    quality = dict.fromkeys(PAPER.sensors, "ok")
    vals["soak_1"] = 100.0 + i
    if i % 2 == 0:
        vals["soak_2"], quality["soak_2"] = 1000.0, "stale"
    else:
        vals["soak_2"] = 200.0 + i
    if i // 6 == 2:
        vals["heat_1"], quality["heat_1"] = None, "comm_error"
    else:
        vals["heat_1"] = 300.0
    return vals | {"quality": quality}


def _burners(counts: tuple[int, int, int]) -> dict:
    return {z: [k < n for k in range(total)] for z, n, total in
            zip(("soak", "heat", "preheat"), counts, (10, 8, 8), strict=True)} | {
        f"count_{z}": n for z, n in zip(("soak", "heat", "preheat"), counts, strict=True)
    } | {"source": "modbus"}


@pytest.fixture
def series(tmp_path: Path) -> list[Path]:
    """A rotated series with known content. PLC time (publish) every 10 s; bins of 60 s:
    bin 4 has only a burner message, bin 6 nothing, bin -1 thermocouples but no burner state."""
    w = LogWriter(tmp_path / "logs", rotate_s=1.0)

    def put(topic: str, msg: dict, plc_s: float) -> None:
        w.write(topic, msg, H0 + int(plc_s * S / 100), T0 + int(plc_s * S))

    put("/furnace/thermocouples", _tc(0), -30)
    put("/furnace/burners", _burners((10, 0, 0)), 0)
    put("/furnace/ambient", {"t_air": 20.0}, 5)
    put("/furnace/ambient", {"t_air": 30.0}, 15)
    put("/furnace/ambient", {"t_air": 99.0, "quality": "stale"}, 25)
    for i in [*range(24), *range(30, 36), *range(42, 48)]:
        put("/furnace/thermocouples", _tc(i), 10 * i)
    put("/furnace/burners", _burners((5, 8, 0)), 125)
    put("/furnace/burners", _burners((6, 8, 1)), 170)
    put("/furnace/burners", _burners((6, 8, 2)), 250)
    # Flame scanners on CAN disagree with the PLC: the export keeps the PLC's states.
    put("/furnace/burners", _burners((0, 0, 0)) | {"source": "can"}, 251)
    w.close()
    files = sorted((tmp_path / "logs").glob("*.mcap"))
    assert len(files) >= 3  # rotated on the host clock
    return files


# Rows (seconds from 06:00, bin or None for a burner change, counts in force): a bin's row at
# the mean time of its readings (bin 4 has none: its centre), a change at its own instant.
ROWS = [(25, 0, (10, 0, 0)), (85, 1, (10, 0, 0)), (125, None, (5, 8, 0)), (145, 2, (5, 8, 0)),
        (170, None, (6, 8, 1)), (205, 3, (6, 8, 1)), (250, None, (6, 8, 2)),
        (270, 4, (6, 8, 2)), (325, 5, (6, 8, 2)), (445, 7, (6, 8, 2))]


def _expected(b: int | None) -> dict:
    if b is None or b == 4:
        return {c: np.nan for c in ("tc_soak_1", "tc_soak_2", "tc_heat_1", "tc_preheat_2")}
    return {"tc_soak_1": 100.0 + 6 * b + 2.5, "tc_soak_2": 200.0 + 6 * b + 3,
            "tc_heat_1": np.nan if b == 2 else 300.0, "tc_preheat_2": 400.0}


def test_export_resamples_exactly(series: list[Path], tmp_path: Path, capsys) -> None:
    out = tmp_path / "run.parquet"
    assert main(["logs", "export", *map(str, reversed(series)), "--out", str(out)]) == 0
    assert "10 rows of 60 s" in capsys.readouterr().out
    frame = pd.read_parquet(out)
    stamps = [f"2026-03-02T06:{t // 60:02d}:{t % 60:02d}.000Z" for t, _, _ in ROWS]
    assert frame["timestamp"].tolist() == stamps
    for row, (_, b, counts) in enumerate(ROWS):
        for col, value in _expected(b).items():
            got = frame[col].iloc[row]
            assert (np.isnan(got) and np.isnan(value)) or got == value, (b, col, got)
        assert tuple(frame[["burners_soak", "burners_heat", "burners_preheat"]].iloc[row]) \
            == counts
    assert frame["t_air"].iloc[0] == 25.0 and frame["t_air"].iloc[1:].isna().all()
    exp = load_experiment(out, furnace=PAPER)
    assert np.allclose(exp.t_min, [(t - 25) / 60 for t, _, _ in ROWS]) and exp.burner_steps == 3


def test_export_csv_loads_as_an_experiment(series: list[Path], tmp_path: Path) -> None:
    out = tmp_path / "run.csv"
    assert main(["logs", "export", *map(str, series), "--out", str(out), "--period", "120"]) == 0
    exp = load_experiment(out, furnace=PAPER)
    assert exp.start_time == pd.Timestamp("2026-03-02T06:00:55Z")
    assert np.allclose(exp.t_min * 60, [0, 70, 115, 120, 195, 270, 390])  # changes at 125, 170, 250 s
    # soak_1 over two minutes: the mean of 100+i over its 12 readings (minute 4 has none).
    nan = np.nan
    assert np.allclose(exp.tc[:, 0], [105.5, nan, nan, 117.5, nan, 132.5, 144.5], atol=1e-3,
                       equal_nan=True)
    assert np.allclose(exp.t_air, 25.0)  # one reading, held (the contract's rule for t_air)
    assert exp.burners.tolist() == [[10, 0, 0], [5, 8, 0], [6, 8, 1], [6, 8, 1], [6, 8, 2],
                                    [6, 8, 2], [6, 8, 2]]


def test_export_time_window(series: list[Path], tmp_path: Path, capsys) -> None:
    out = tmp_path / "w.csv"
    assert main(["logs", "export", *map(str, series), "--out", str(out),
                 "--start", "2026-03-02T07:01:00+01:00", "--end", "2026-03-02T06:03:00Z"]) == 0
    exp = load_experiment(out, furnace=PAPER)
    assert np.allclose(exp.t_min * 60, [0, 40, 60, 85]) and exp.start_time.minute == 1
    # the state in force from before, the changes at 125 and 170 s
    assert exp.burners.tolist() == [[10, 0, 0], [5, 8, 0], [5, 8, 0], [6, 8, 1]]
    assert main(["logs", "export", *map(str, series), "--out", str(out),
                 "--start", "2026-03-02T06:01:00"]) != 0
    assert "no UTC offset" in capsys.readouterr().err
    assert main(["logs", "export", *map(str, series), "--out", str(out), "--period", "0"]) != 0
    assert main(["logs", "export", *map(str, series), "--out", str(tmp_path / "x.txt")]) != 0
    assert "x.txt: unsupported file type" in capsys.readouterr().err
    assert main(["logs", "export", *map(str, series), "--out", str(out),
                 "--start", "2027-01-01T00:00:00Z"]) != 0
    assert "no furnace data" in capsys.readouterr().err


def test_info_gives_the_first_look(tmp_path: Path, capsys) -> None:
    w = LogWriter(tmp_path, rotate_s=3600.0,
                  metadata=build_metadata(None, furnace=PAPER, software_version="9.9.9",
                                                host="gw-1"))
    w.write("/daq/status", {"state": "connected", "detail": "PLC answered"}, T0)
    for i in range(100):
        if not 40 <= i < 50:
            w.write("/furnace/thermocouples", _tc(i), T0 + i * S)
    w.write("/daq/status", {"state": "disconnected", "detail": "timeout"}, T0 + 40 * S)
    w.write("/daq/status", {"state": "connected", "detail": "PLC answered"}, T0 + 50 * S)
    w.close()
    # A second file whose writer died after its first flush.
    w2 = LogWriter(tmp_path, rotate_s=3600.0, flush_interval_s=0.0)
    for i in range(100, 120):
        w2.write("/furnace/thermocouples", _tc(i), T0 + 3600 * S + i * S)
    w2.maybe_flush(0.0)
    w2.write("/furnace/thermocouples", _tc(0), T0 + 3600 * S + 200 * S)  # lost: never flushed
    files = sorted(tmp_path.iterdir())
    assert main(["logs", "info", *map(str, files)]) == 0
    out = capsys.readouterr().out
    assert f"{files[0]}: complete" in out
    assert f"{files[1]}: INCOMPLETE" in out and "20 messages readable" in out
    assert "/furnace/thermocouples        110 messages" in out
    assert "/daq/status                     3 messages" in out
    assert "span: 2026-03-02T06:00:00.000Z .. 2026-03-02T07:01:59.000Z" in out
    assert "gaps longer than 3 periods (1 s): 2" in out
    assert "2026-03-02T06:00:39.000Z .. 2026-03-02T06:00:50.000Z  (11 s)" in out
    assert "/daq/status changes: 3" in out
    assert "2026-03-02T06:00:40.000Z  disconnected  timeout" in out
    assert "written by: furnace-daq 9.9.9 on gw-1; furnace paper-3zone; refit off" in out


def _bad_inputs(tmp_path: Path) -> dict[str, Path]:
    good = tmp_path / "good.mcap"
    w = LogWriter(tmp_path / "w")
    w.write("/furnace/ambient", {"t_air": 1.0}, T0)
    w.close()
    next((tmp_path / "w").glob("*.mcap")).rename(good)
    files = {
        "missing": tmp_path / "nope.mcap",
        "text": tmp_path / "notes.mcap",
        "empty": tmp_path / "empty.mcap",
        "cut in magic": tmp_path / "magic.mcap",
        "cut in header": tmp_path / "header.mcap",
        "directory": tmp_path / "w",
    }
    files["text"].write_text("timestamp,tc_soak_1\n")
    files["empty"].write_bytes(b"")
    files["cut in magic"].write_bytes(good.read_bytes()[:5])
    files["cut in header"].write_bytes(good.read_bytes()[:14])
    return files


@pytest.mark.parametrize("action", ["info", "export", "recover"])
def test_bad_input_is_one_line_naming_the_file(tmp_path: Path, capsys, action: str) -> None:
    for what, path in _bad_inputs(tmp_path).items():
        extra = ["--out", str(tmp_path / "o.csv")] if action == "export" else []
        assert main(["logs", action, str(path), *extra]) != 0, what
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(path) in err, (what, err)
    assert not (tmp_path / "o.csv").exists()


def test_bad_input_from_the_command_line_has_no_traceback(tmp_path: Path) -> None:
    bad = _bad_inputs(tmp_path)
    proc = subprocess.run([sys.executable, "-m", "furnace_daq.cli", "logs", "info",
                           str(bad["cut in header"])], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.strip() == (f"furnace-daq logs: error: {bad['cut in header']}: "
                                   "truncated in the header: not a usable MCAP file")
