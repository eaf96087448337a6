"""A time window given backwards is an argument error: exit 2 with argparse's message naming
both options, before any file is opened (the files named here do not exist)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from furnace_daq.cli import build_parser as daq_parser
from furnace_daq.cli import main as daq_main
from furnace_model.cli import build_parser as model_parser
from furnace_model.cli import main as model_main

LATE, EARLY = "2026-03-03T06:00:00Z", "2026-03-02T06:00:00Z"
SAME_AS_LATE = "2026-03-03T07:00:00+01:00"


@pytest.mark.parametrize("argv", [
    ["fit", "missing.csv"],
    ["validate", "missing.csv", "--params", "missing.json"],
    ["diagnose", "missing.csv", "--holdout", "missing2.csv"],
])
@pytest.mark.parametrize("end", [EARLY, SAME_AS_LATE])
def test_a_backwards_window_is_an_argument_error(argv, end, capsys):
    with pytest.raises(SystemExit) as stop:
        model_main([*argv, "--from", LATE, "--to", end])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert f"furnace-model {argv[0]}: error: argument --to: --to " in err
    assert "is not later than --from 2026-03-03T06:00:00+00:00" in err
    assert "missing" not in err.split("error:")[1]  # no file was looked at


@pytest.mark.parametrize("end", [EARLY, SAME_AS_LATE])
def test_a_backwards_export_window_is_an_argument_error(end, capsys, tmp_path):
    with pytest.raises(SystemExit) as stop:
        daq_main(["logs", "export", "missing.mcap", "--out", str(tmp_path / "a.csv"),
                  "--start", LATE, "--end", end])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "furnace-daq logs export: error: argument --end: --end " in err
    assert "is not later than --start 2026-03-03T06:00:00+00:00" in err


def test_a_window_in_order_or_half_given_parses():
    for window in (["--from", EARLY, "--to", LATE], ["--from", LATE], ["--to", EARLY]):
        args = model_parser().parse_args(["diagnose", "a.csv", *window])
        assert args.command == "diagnose"
    args = daq_parser().parse_args(["logs", "export", "a.mcap", "--out", "a.csv", "--start",
                                    EARLY, "--end", LATE])
    assert args.start == EARLY
    # a text that is no time is left to the export's own reading, which names the option
    daq_parser().parse_args(["logs", "export", "a.mcap", "--out", "a.csv", "--start", "soon",
                             "--end", EARLY])


def test_the_command_in_its_own_process_exits_2():
    proc = subprocess.run([sys.executable, "-m", "furnace_model.cli", "validate", "missing.csv",
                           "--params", "missing.json", "--to", EARLY, "--from", LATE],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert "argument --to:" in proc.stderr and "--from" in proc.stderr
    assert "Traceback" not in proc.stderr
