"""Malformed CSV, Parquet and MCAP files fed to every command that reads them: each is a
clear one-line error naming the file (exit 1), or, where the file is still usable, a normal
run; never a traceback, never a hang, never a damaged output file."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from bad_files import good_frame, mcap_cases, table_cases
from daq_processes import ROOT

from furnace_daq.cli import main as daq_main
from furnace_model.cli import main as model_main

# Still usable: NUL bytes after a number are read as the number, numbers stored as text in
# Parquet are numbers.
USABLE_TABLES = {"nul_bytes.csv", "wrong_types.parquet"}

# Not MCAP at all, or nothing of it readable: every log command refuses these.
UNREADABLE_LOGS = {"empty.mcap", "random.mcap", "magic_then_random.mcap", "cut_in_header.mcap",
                   "text.mcap", "csv_as_log.mcap"}
# MCAP with no furnace data in a readable message, or messages the table cannot take:
# export and replay refuse them too.
NO_DATA_LOGS = UNREADABLE_LOGS | {"cut_in_first_chunk.mcap", "zeros_after_header.mcap",
                                  "not_json.mcap", "json_array.mcap", "missing_fields.mcap",
                                  "huge_values.mcap", "status_only.mcap",
                                  "wrong_schema_encoding.mcap"}
NO_MESSAGE_LOGS = UNREADABLE_LOGS | {"cut_in_first_chunk.mcap", "zeros_after_header.mcap"}


@pytest.fixture(scope="module")
def tables(tmp_path_factory) -> dict[str, Path]:
    return table_cases(tmp_path_factory.mktemp("tables"))


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, Path]:
    return mcap_cases(tmp_path_factory.mktemp("logs"))


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("good")
    csv = d / "good.csv"
    good_frame().to_csv(csv, index=False)
    fit_json = d / "fit.json"
    assert model_main(["fit", str(csv), "--generations", "3", "--json", str(fit_json)]) == 0
    return {"csv": csv, "fit": fit_json}


def _run(main, argv: list[str], capsys) -> tuple[int, str]:
    """The command's exit code and stderr; any exception escaping main() fails the test."""
    rc = main(argv)
    err = capsys.readouterr().err
    return rc, err


def _one_line_naming(err: str, prog: str, path: Path) -> bool:
    lines = [ln for ln in err.strip().splitlines() if ": warning: " not in ln]
    return (len(lines) == 1 and lines[0].startswith(f"{prog}: error: ")
            and str(path) in lines[0] and "Traceback" not in err)


@pytest.mark.parametrize("command", ["fit", "validate", "diagnose"])
def test_bad_tables(tables, good, capsys, command: str) -> None:
    for name, path in tables.items():
        argv = {"fit": ["fit", str(path), "--generations", "2", "--population", "8"],
                "validate": ["validate", "--params", str(good["fit"]), str(path)],
                "diagnose": ["diagnose", str(path), "--holdout", str(good["csv"]),
                             "--effects", "sensor_lag"]}[command]
        rc, err = _run(model_main, argv, capsys)
        if name in USABLE_TABLES:
            assert rc == 0, (name, err)
        else:
            assert rc == 1, (name, rc, err)
            assert _one_line_naming(err, f"furnace-model {command}", path), (name, err)


def test_bad_holdout_for_diagnose(tables, good, capsys) -> None:
    for name in ("random.csv", "duplicated_times.parquet", "huge.csv"):
        rc, err = _run(model_main, ["diagnose", str(good["csv"]), "--holdout",
                                    str(tables[name]), "--effects", "sensor_lag"], capsys)
        assert rc == 1 and _one_line_naming(err, "furnace-model diagnose", tables[name]), err


def _log_argv(action: str, path: Path, out: Path) -> list[str]:
    return {"info": ["logs", "info", str(path)],
            "export": ["logs", "export", str(path), "--out", str(out / f"{path.name}.csv")],
            "recover": ["logs", "recover", str(path), "--out", str(out / f"{path.name}.rec.mcap")],
            "replay": ["replay", str(path), "--out", str(out / f"{path.name}.model.mcap")],
            }[action]


@pytest.mark.parametrize("action", ["info", "export", "recover", "replay"])
def test_bad_logs(logs, tmp_path, capsys, action: str) -> None:
    refused = {"info": UNREADABLE_LOGS, "recover": NO_MESSAGE_LOGS,
               "export": NO_DATA_LOGS, "replay": NO_DATA_LOGS}[action]
    prog = "furnace-daq replay" if action == "replay" else "furnace-daq logs"
    for name, path in logs.items():
        rc, err = _run(daq_main, _log_argv(action, path, tmp_path), capsys)
        if name in refused:
            assert rc == 1, (name, rc, err)
            assert _one_line_naming(err, prog, path), (name, err)
        else:
            assert rc == 0, (name, err)
    if action in ("export", "recover"):  # nothing half-written by the refusals
        made = {p.name for p in tmp_path.iterdir()}
        assert not {f"{n}.csv" for n in refused} & made
        assert not {f"{n}.rec.mcap" for n in refused} & made


def test_sim_plc_from_a_bad_log_does_not_start(logs, capsys) -> None:
    for name in sorted(NO_DATA_LOGS - {"huge_values.mcap"}):
        rc, err = _run(daq_main, ["sim-plc", "--from-log", str(logs[name]), "--port", "0",
                                  "--duration", "0.2"], capsys)
        assert rc != 0 and _one_line_naming(err, "furnace-daq sim-plc", logs[name]), (name, err)
    # Readings beyond the registers' range: refused at start, in one line (without the file).
    rc, err = _run(daq_main, ["sim-plc", "--from-log", str(logs["huge_values.mcap"]), "--port",
                              "0", "--duration", "0.2"], capsys)
    assert rc == 1 and err.startswith("furnace-daq sim-plc: error: ") and err.count("\n") == 1


def test_sim_plc_serves_a_log_with_odd_but_readable_messages(logs, capsys) -> None:
    for name in ("wrong_field_types.mcap", "nan_token.mcap", "duplicated_times.mcap"):
        rc, err = _run(daq_main, ["sim-plc", "--from-log", str(logs[name]), "--port", "0",
                                  "--duration", "0.2"], capsys)
        assert rc == 0 and "Traceback" not in err, (name, err)


def test_a_refused_export_leaves_the_previous_output_as_it_was(logs, tmp_path, capsys) -> None:
    out = tmp_path / "run.csv"
    good = logs["random.mcap"].parent / "good.mcap"
    assert daq_main(["logs", "export", str(good), "--out", str(out)]) == 0
    before = out.read_bytes()
    for name in ("random.mcap", "missing_fields.mcap", "huge_values.mcap"):
        assert daq_main(["logs", "export", str(logs[name]), "--out", str(out)]) == 1
    assert out.read_bytes() == before
    capsys.readouterr()


# One real process per command: the console entry point prints the same line, exits 1, and
# nothing hangs (the timeout fails the test).
PROCESSES = [
    ("furnace_model.cli", ["fit", "{tables}/random.csv"], "{tables}/random.csv"),
    ("furnace_model.cli", ["validate", "--params", "{fit}", "{tables}/truncated.parquet"],
     "{tables}/truncated.parquet"),
    ("furnace_model.cli", ["diagnose", "{tables}/non_utf8.csv"], "{tables}/non_utf8.csv"),
    ("furnace_daq.cli", ["logs", "info", "{logs}/magic_then_random.mcap"],
     "{logs}/magic_then_random.mcap"),
    ("furnace_daq.cli", ["logs", "export", "{logs}/wrong_schema_encoding.mcap", "--out",
                         "{tmp}/x.csv"], "{logs}/wrong_schema_encoding.mcap"),
    ("furnace_daq.cli", ["logs", "recover", "{logs}/zeros_after_header.mcap"],
     "{logs}/zeros_after_header.mcap"),
    ("furnace_daq.cli", ["replay", "{logs}/huge_values.mcap"], "{logs}/huge_values.mcap"),
    ("furnace_daq.cli", ["sim-plc", "--from-log", "{logs}/not_json.mcap", "--port", "0"],
     "{logs}/not_json.mcap"),
]


@pytest.mark.parametrize("module,args,named", PROCESSES, ids=[" ".join(a[:2]) for _, a, _ in
                                                              PROCESSES])
def test_bad_files_in_a_real_process(tables, logs, good, tmp_path, module, args, named) -> None:
    where = {"tables": next(iter(tables.values())).parent, "logs": next(iter(logs.values())).parent,
             "fit": good["fit"], "tmp": tmp_path}
    argv = [a.format(**where) for a in args]
    proc = subprocess.run([sys.executable, "-m", module, *argv], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.strip().splitlines() if ": warning: " not in ln]
    assert len(lines) == 1 and named.format(**where) in lines[0], proc.stderr
