"""The tabular contract: good files load, each way of breaking it gets its own clear error."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from furnace_model.errors import DataError, DataWarning
from furnace_model.records import load_experiment
from furnace_model.simulation.furnace import PAPER

HEADER = ("t_min,tc_soak_1,tc_soak_2,tc_heat_1,tc_heat_2,tc_preheat_1,tc_preheat_2,"
          "burners_soak,burners_heat,burners_preheat,t_air")
ROWS = ["0,30,31,29,30,28,29,2,0,0,30", "1,35,36,31,32,29,30,2,0,0,30",
        "2,40,,33,34,30,31,4,0,0,30.5", "3,45,46,35,36,31,32,4,0,0,"]


def write(tmp_path: Path, lines: list[str], name: str = "run.csv") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def test_good_csv_loads(tmp_path):
    exp = load_experiment(write(tmp_path, [HEADER, *ROWS]), furnace=PAPER)
    assert len(exp) == 4
    np.testing.assert_allclose(exp.zone_temp[2], [40.0, 33.5, 30.5])  # missing cell skipped
    assert np.isnan(exp.tc[2, 1])
    assert exp.burners[:, 0].tolist() == [2, 2, 4, 4]
    assert exp.burner_steps == 1
    assert exp.t_air[-1] == 30.5  # an empty ambient cell holds the last reading


def test_timestamps_and_parquet_round_trip(tmp_path):
    lines = [HEADER.replace("t_min", "timestamp")]
    for i, row in enumerate(ROWS):
        lines.append(f"2026-03-04T10:0{i}:00+01:00" + row[row.index(","):])
    exp = load_experiment(write(tmp_path, lines), furnace=PAPER)
    assert exp.start_time == pd.Timestamp("2026-03-04T09:00:00Z")
    np.testing.assert_allclose(exp.t_min, [0, 1, 2, 3])
    pq = tmp_path / "run.parquet"
    exp.to_frame().to_parquet(pq)
    again = load_experiment(pq, furnace=PAPER)
    np.testing.assert_allclose(again.t_min, exp.t_min)
    np.testing.assert_array_equal(again.tc, exp.tc)


@pytest.mark.parametrize("mutate, match", [
    (lambda h, r: (h.replace(",burners_heat", ""), [x.rsplit(",", 3)[0] + ",0," + x.rsplit(",", 1)[1]
                                                    for x in r]),
     r"missing required column\(s\): burners_heat"),
    (lambda h, r: (h, [r[0], r[1].replace("35,", "hot,", 1), *r[2:]]),
     r"column 'tc_soak_1', line 3: not a number: 'hot'"),
    (lambda h, r: (h, [r[0], r[2], r[1], r[3]]),
     r"column 't_min', line 4: time goes backwards"),
    (lambda h, r: (h, [r[0], r[1], r[1], r[3]]),
     r"column 't_min', line 4: duplicate time"),
    (lambda h, r: (h, [r[0], r[1].replace(",2,0,0,", ",-1,0,0,"), *r[2:]]),
     r"column 'burners_soak', line 3: burner count cannot be negative"),
    (lambda h, r: (h, [r[0], r[1].replace(",2,0,0,", ",2.5,0,0,"), *r[2:]]),
     r"column 'burners_soak', line 3: burner count must be a whole number"),
    (lambda h, r: (h, [r[0], r[1].replace(",2,0,0,", ",2,9,0,"), *r[2:]]),
     r"column 'burners_heat', line 3: the heat zone has 8 burners"),
    (lambda h, r: (h, [r[0], r[1].replace(",2,0,0,", ",,0,0,"), *r[2:]]),
     r"column 'burners_soak', line 3: empty cell"),
    (lambda h, r: (h, []), r"no data rows"),
    (lambda h, r: (h.replace("tc_preheat_1,tc_preheat_2", "x1,x2"), r),
     r"zone 'preheat' has no thermocouple column"),
    (lambda h, r: ("timestamp," + h, ["2026-01-01T00:00:00Z," + x for x in r]),
     r"exactly one time column.*found both"),
])
def test_broken_files_get_their_own_error(tmp_path, mutate, match):
    header, rows = mutate(HEADER, list(ROWS))
    with pytest.raises(DataError, match=match) as info:
        load_experiment(write(tmp_path, [header, *rows]), furnace=PAPER)
    assert "run.csv" in str(info.value)


@pytest.mark.parametrize("sep, decimal", [(";", ","), ("\t", "."), (";", ".")])
def test_a_spreadsheets_separators_and_decimal_commas_read_alike(tmp_path, sep, decimal):
    """A spreadsheet in a language whose decimal mark is a comma saves ';' between fields
    and ',' in numbers (Excel with a byte-order mark), one saved as text uses tabs: the
    same record as the comma-separated file."""
    rows = [r.replace(",", sep) for r in ROWS]
    rows = [r.replace(".", decimal) for r in rows]
    path = tmp_path / "sheet.csv"
    path.write_text("\n".join([HEADER.replace(",", sep), *rows]) + "\n", encoding="utf-8-sig")
    exp = load_experiment(path, furnace=PAPER)
    ref = load_experiment(write(tmp_path, [HEADER, *ROWS]), furnace=PAPER)
    np.testing.assert_array_equal(exp.tc, ref.tc)
    np.testing.assert_array_equal(exp.t_air, ref.t_air)
    assert exp.t_air[2] == 30.5


def test_a_file_without_ambient_says_what_it_takes(tmp_path):
    header = HEADER.removesuffix(",t_air")
    rows = [r.rsplit(",", 1)[0] for r in ROWS]
    with pytest.warns(DataWarning, match=r"no 't_air' column: the ambient is taken as 30 °C"):
        exp = load_experiment(write(tmp_path, [header, *rows]), furnace=PAPER)
    assert exp.t_air.tolist() == [30.0] * 4


def test_a_column_named_in_another_case_is_pointed_at(tmp_path):
    header = HEADER.replace("tc_preheat_1,tc_preheat_2", "TC_PREHEAT_1,TC_PREHEAT_2")
    with pytest.raises(DataError, match=r"need tc_preheat_1 or tc_preheat_2\); the file has "
                                        r"TC_PREHEAT_1, TC_PREHEAT_2: column names are matched"):
        load_experiment(write(tmp_path, [header, *ROWS]), furnace=PAPER)


def test_timestamp_without_offset_is_refused(tmp_path):
    lines = [HEADER.replace("t_min", "timestamp"), "2026-03-04T10:00:00" + ROWS[0][1:]]
    with pytest.raises(DataError, match=r"line 2: timestamp has no UTC offset"):
        load_experiment(write(tmp_path, lines), furnace=PAPER)


def test_empty_and_foreign_files(tmp_path):
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(DataError, match="empty file"):
        load_experiment(empty, furnace=PAPER)
    with pytest.raises(DataError, match="file not found"):
        load_experiment(tmp_path / "nope.csv", furnace=PAPER)
    with pytest.raises(DataError, match="unsupported file type '.txt'"):
        load_experiment(tmp_path / "run.txt", furnace=PAPER)
    junk = tmp_path / "junk.parquet"
    junk.write_bytes(b"not parquet at all")
    with pytest.raises(DataError, match="not a readable parquet file"):
        load_experiment(junk, furnace=PAPER)


def test_parquet_errors_name_rows(tmp_path):
    frame = pd.DataFrame({"t_min": [0.0, 1.0, 2.0], "tc_soak_1": [1.0, 2, 3],
                          "tc_heat_1": [1.0, 2, 3], "tc_preheat_1": [1.0, 2, 3],
                          "burners_soak": [2, -3, 2], "burners_heat": [0, 0, 0],
                          "burners_preheat": [0, 0, 0]})
    path = tmp_path / "neg.parquet"
    frame.to_parquet(path)
    with pytest.raises(DataError, match=r"column 'burners_soak', row 2: burner count cannot be"):
        load_experiment(path, furnace=PAPER)


def test_simulate_cli_writes_a_loadable_file_and_reports_bad_input(tmp_path, scenarios):
    out = tmp_path / "exp1.csv"
    cmd = [sys.executable, "-m", "furnace_model.cli", "simulate",
           "--scenario", str(scenarios / "paper_exp1.yaml"), "--out", str(out), "--seed", "3"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    exp = load_experiment(out, furnace=PAPER)
    assert len(exp) == 3311 and exp.burner_steps == 3
    assert exp.burners[-1].tolist() == [10, 0, 0]
    bad = tmp_path / "bad.yaml"
    bad.write_text("duration_min: 100\nburners: {steps: [{at_min: 0, total: 2}]}\nefects: {}\n")
    cmd[cmd.index(str(scenarios / "paper_exp1.yaml"))] = str(bad)
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "bad.yaml: efects: unknown key" in done.stderr
    assert "Traceback" not in done.stderr
