"""MCAP logs as input of `furnace-model fit|validate|diagnose`: a log directory reads as the
table `furnace-daq logs export` makes of it, row for row, and fits to the same parameters; a
dead writer's .mcap.part is read up to its cut; --from/--to cut the PLC clock; a bad input is
one line naming it."""

from __future__ import annotations

import ast
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader
from refit_helpers import simulate

from furnace_daq.cli import main as daq_main
from furnace_daq.mcaplog import LogWriter
from furnace_daq.plantlog import write_run
from furnace_model.cli import main as model_main
from furnace_model.cli.arguments import LOG_PERIOD_S
from furnace_model.experiment import Experiment
from furnace_model.log.resample import DEFAULT_PERIOD_S
from furnace_model.records import load_experiment, load_experiments
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
START = pd.Timestamp("2026-03-02T06:00:00Z")
SHIFT = pd.Timedelta(seconds=20)  # samples 20 s into each minute: the bins' means matter


@pytest.fixture(scope="module")
def logged(tmp_path_factory) -> Path:
    """The quick demo's plant (five burner steps in 15 h) sampled every 20 s and logged as the
    daemon logs it, in files rotated every 4 h of the PLC clock."""
    s = load_scenario(ROOT / "tests" / "data" / "demo_quick.yaml")
    s.sample_min = 1 / 3
    run = simulate(s, seed=3)
    root = tmp_path_factory.mktemp("mcapin")
    # chunks of 128 kB: a file holds several, so a writer killed in one leaves the others
    log = LogWriter(root / "logs", flush_interval_s=3600.0, rotate_s=4 * 3600.0,
                    rotate_bytes=2**20)
    write_run(run, log, START + SHIFT)
    log.close()
    return root


def export(files: list[Path] | Path, out: Path, *options: str) -> Path:
    args = [str(files)] if isinstance(files, Path) else [str(f) for f in files]
    assert daq_main(["logs", "export", *args, "--out", str(out), *options]) == 0
    return out


def same_rows(a: Experiment, b: Experiment, tc_atol: float = 0.0) -> None:
    assert a.start_time == b.start_time
    np.testing.assert_array_equal(a.t_min, b.t_min)
    np.testing.assert_array_equal(a.burners, b.burners)
    np.testing.assert_allclose(a.tc, b.tc, rtol=0, atol=tc_atol, equal_nan=True)
    np.testing.assert_allclose(a.t_air, b.t_air, rtol=0, atol=tc_atol)


def test_a_log_directory_reads_as_its_export_row_for_row(logged: Path, tmp_path: Path) -> None:
    logs = logged / "logs"
    assert len(list(logs.glob("*.mcap"))) == 5  # 06:00:20-08:00, 08-12, ..., 20-21:10
    from_log = load_experiment(logs, furnace=PAPER)
    assert from_log.name == "logs" and len(from_log) > 15 * 60
    same_rows(from_log, load_experiment(export(logs, tmp_path / "e.parquet"), furnace=PAPER))
    # CSV keeps 0.001 °C
    same_rows(from_log, load_experiment(export(logs, tmp_path / "e.csv"),
                                        furnace=PAPER), tc_atol=5e-4)
    # another period, as logs export --period
    same_rows(load_experiment(logs, period_s=120.0, furnace=PAPER),
              load_experiment(export(logs, tmp_path / "p.parquet", "--period", "120"),
                              furnace=PAPER))


def test_fit_on_the_log_equals_fit_on_its_export(logged: Path, tmp_path: Path, capsys) -> None:
    logs = logged / "logs"
    csv = export(sorted(logs.glob("*.mcap")), tmp_path / "run.csv")
    parquet = export(sorted(logs.glob("*.mcap")), tmp_path / "run.parquet")
    docs = {}
    for name, data in (("log", logs), ("csv", csv), ("parquet", parquet)):
        assert model_main(["fit", str(data), "--json", str(tmp_path / f"{name}.json")]) == 0
        docs[name] = json.loads((tmp_path / f"{name}.json").read_text())
    capsys.readouterr()
    assert docs["log"]["data"] == [str(logs)]
    assert docs["log"]["params"] == docs["parquet"]["params"]  # the same rows, bit for bit
    # The CSV's 0.001 °C rounding moves the optimum by far less than what the data determine:
    # within the polish's stopping tolerance, well inside each parameter's 95% interval (d and
    # e alone are undetermined here, their ratio is) and with the same residual.
    log, csv = docs["log"], docs["csv"]
    for k, v in csv["params"].items():
        lo, hi = log["ci95"][k]
        assert abs(log["params"][k] - v) < 1e-3 * (hi - lo), k
    for x, y in (("b", "c"), ("d", "e")):
        assert log["params"][x] / log["params"][y] == pytest.approx(
            csv["params"][x] / csv["params"][y], rel=1e-6), (x, y)
    assert log["sigma_c"] == pytest.approx(csv["sigma_c"], rel=1e-4)
    truth = load_scenario(ROOT / "tests" / "data" / "demo_quick.yaml").params
    for k in ("a", "f"):
        assert docs["log"]["params"][k] == pytest.approx(truth[k], rel=0.03), k


def test_files_of_one_directory_join_as_the_directory(logged: Path, tmp_path: Path) -> None:
    logs = logged / "logs"
    files = sorted(logs.glob("*.mcap"))
    whole = load_experiment(logs, furnace=PAPER)
    (joined,) = load_experiments(reversed(files), furnace=PAPER)  # named in any order: one record
    same_rows(joined, whole)
    (again,) = load_experiments([logs, files[1]],
                                furnace=PAPER)  # a file and its directory: read once
    same_rows(again, whole)
    # logs kept in two directories are two records, each its own directory's rows
    other = tmp_path / "other"
    other.mkdir()
    shutil.copy(files[0], other / files[0].name)
    first, second, table = load_experiments(
        [logs, other, export(files[0], tmp_path / "t.parquet")], furnace=PAPER)
    same_rows(first, whole)
    same_rows(second, table)
    assert (first.name, second.name, table.name) == ("logs", "other", "t")


def test_a_dead_writers_part_file_is_read(logged: Path, tmp_path: Path, capsys) -> None:
    files = sorted((logged / "logs").glob("*.mcap"))
    logs = tmp_path / "logs"
    logs.mkdir()
    for f in files[:-1]:
        shutil.copy(f, logs / f.name)
    # the last file as its writer left it when killed inside its last chunk: the chunks
    # before, no footer, a record cut
    with files[-1].open("rb") as f:
        last = max(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    part = logs / (files[-1].name + ".part")
    part.write_bytes(files[-1].read_bytes()[: last.chunk_start_offset + last.chunk_length // 2])
    (logs / "furnace-20260303T000000Z.mcap.part").write_bytes(b"")  # died before writing
    got = load_experiment(logs, furnace=PAPER)
    cut_at = pd.Timestamp(last.message_start_time, tz="UTC")  # the first message lost
    end = got.start_time + pd.Timedelta(minutes=got.t_min[-1])
    assert cut_at - pd.Timedelta(minutes=2) < end < cut_at
    expected = export([*logs.glob("*.mcap"), part], tmp_path / "e.parquet")
    same_rows(got, load_experiment(expected, furnace=PAPER))
    # with its recovered copy beside it (the same messages), the rows stay the same
    assert daq_main(["logs", "recover", str(part)]) == 0
    assert (logs / files[-1].name.replace(".mcap", ".recovered.mcap")).exists()
    same_rows(load_experiment(logs, furnace=PAPER), got)
    # named on its own, a .part is read too; an empty one is refused by name
    assert len(load_experiment(part, furnace=PAPER)) > 0
    assert model_main(["fit", str(logs / "furnace-20260303T000000Z.mcap.part")]) == 1
    err = capsys.readouterr().err
    assert "furnace-20260303T000000Z.mcap.part: empty file" in err


def test_from_to_cut_the_plc_clock(logged: Path, tmp_path: Path) -> None:
    logs = logged / "logs"
    lo, hi = START + pd.Timedelta(hours=3), START + pd.Timedelta(hours=9, minutes=30)
    cut = load_experiment(logs, start=lo, end=hi, furnace=PAPER)
    exported = export(logs, tmp_path / "w.parquet", "--start", lo.isoformat(),
                      "--end", hi.isoformat())
    same_rows(cut, load_experiment(exported, furnace=PAPER))
    assert lo <= cut.start_time and cut.start_time + pd.Timedelta(minutes=cut.t_min[-1]) < hi
    assert len(cut) < len(load_experiment(logs, furnace=PAPER))
    # a timestamped table is cut the same way (window on whole minutes: the same bins)
    table = export(logs, tmp_path / "all.parquet")
    same_rows(load_experiment(table, start=lo, end=hi, furnace=PAPER), cut)
    # and the command line reads the window: validate scores the window's rows only
    fit_json = tmp_path / "fit.json"
    assert model_main(["fit", str(exported), "--json", str(fit_json)]) == 0
    for data, window in ((logs, ["--from", lo.isoformat(), "--to", hi.isoformat()]),
                         (exported, [])):
        out = tmp_path / f"v{len(window)}.json"
        assert model_main(["validate", str(data), "--params", str(fit_json), *window,
                           "--json", str(out)]) == 0
    a, b = (json.loads((tmp_path / f"v{n}.json").read_text()) for n in (4, 0))
    assert a["per_zone"] == b["per_zone"]


@pytest.mark.parametrize("case", ["not_mcap", "empty_dir", "no_data_in_window",
                                  "t_min_table_with_window", "cut_in_header"])
def test_bad_inputs_are_one_line_naming_the_file(case: str, logged: Path, tmp_path: Path,
                                                 capsys) -> None:
    logs = logged / "logs"
    if case == "not_mcap":
        bad = tmp_path / "notes.mcap"
        bad.write_text("timestamp,tc_soak_1\n")
        argv, named = ["fit", str(bad)], str(bad)
    elif case == "empty_dir":
        (tmp_path / "logs").mkdir()
        (tmp_path / "logs" / "readme.txt").write_text("no logs here")
        argv, named = ["diagnose", str(tmp_path / "logs")], str(tmp_path / "logs")
    elif case == "no_data_in_window":
        argv = ["fit", str(logs), "--from", "2027-01-01T00:00:00Z"]
        named = str(logs)
    elif case == "t_min_table_with_window":
        table = tmp_path / "minutes.csv"
        load_experiment(logs,
                        furnace=PAPER).to_frame().assign(t_min=lambda f: np.arange(len(f))).drop(
            columns="timestamp").to_csv(table, index=False)
        argv = ["validate", str(table), "--params", "x.json", "--to", "2026-03-02T09:00Z"]
        named = str(table)
        (tmp_path / "x.json").write_text(json.dumps({"params": {
            "a": 0.02, "b": 0.3, "c": 0.06, "d": 0.87, "e": 0.73, "f": 0.22}}))
        argv[3] = str(tmp_path / "x.json")
    else:
        bad = tmp_path / "furnace-20260302T060000Z.mcap"
        bad.write_bytes(next(logs.glob("*.mcap")).read_bytes()[:11])
        argv, named = ["fit", str(bad)], str(bad)
    assert model_main(argv) != 0
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert named in err and "Traceback" not in err


def test_a_time_without_its_zone_is_refused_when_read(capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        model_main(["fit", "a.mcap", "--from", "2026-03-02T08:00:00"])
    assert exc.value.code == 2
    assert "--from: '2026-03-02T08:00:00' has no UTC offset or Z" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:  # backwards: an argument error too
        model_main(["fit", "a.mcap", "--from", "2026-03-02T09:00Z", "--to", "2026-03-02T08:00Z"])
    assert exc.value.code == 2
    assert "is not later than --from" in capsys.readouterr().err


def test_the_model_package_never_imports_the_daq_package() -> None:
    """The package rule (ARCHITECTURE.md): the log's format and reader live in furnace_model
    so that both can use them."""
    for path in (ROOT / "furnace_model").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            assert not any(n.split(".")[0] == "furnace_daq" for n in names), path
    assert LOG_PERIOD_S == DEFAULT_PERIOD_S
