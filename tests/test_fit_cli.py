"""`furnace-model fit` as a user runs it: a real process on real files."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from furnace_model.simulation.furnace import PAPER

ROOT = Path(__file__).resolve().parent.parent


def cli(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "furnace_model.cli", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def exp_files(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("data")
    out = {}
    for name, seed in (("paper_exp1", 1), ("paper_exp2", 2)):
        path = d / f"{name}.csv"
        r = cli("simulate", "--scenario", f"config/scenarios/{name}.yaml", "--out", str(path),
                "--seed", str(seed))
        assert r.returncode == 0, r.stderr
        out[name] = path
    return out


def test_fit_writes_tables_json_and_plots(exp_files, tmp_path):
    out_json, plots = tmp_path / "fit.json", tmp_path / "plots"
    r = cli("fit", str(exp_files["paper_exp1"]), "--runs", "2", "--seed", "7",
            "--json", str(out_json), "--plot", str(plots))
    assert r.returncode == 0, r.stderr
    assert "| run | seed | population | generations |" in r.stdout
    assert "| mean |" in r.stdout  # the genetic mean row, as Table V
    assert "d/e" in r.stdout
    assert "warning" in r.stderr and "do not determine" in r.stderr
    assert "\r" not in r.stderr  # no progress bar when stderr is not a terminal
    doc = json.loads(out_json.read_text())
    assert doc["model"] == "paper-3zone"
    assert [run["seed"] for run in doc["runs"]] == [7, 8]
    assert doc["data"] == [str(exp_files["paper_exp1"])]
    assert doc["params"]["f"] == pytest.approx(0.224131, rel=0.03)
    for zone in ("soak", "heat", "preheat"):
        png = plots / f"paper_exp1_{zone}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_two_files_fit_jointly(exp_files, tmp_path):
    out_json = tmp_path / "joint.json"
    r = cli("fit", str(exp_files["paper_exp1"]), str(exp_files["paper_exp2"]),
            "--json", str(out_json))
    assert r.returncode == 0, r.stderr
    doc = json.loads(out_json.read_text())
    assert len(doc["x0"]) == 2
    assert doc["n_obs"] == 3 * (3311 + 3801)


def test_paper_ga_method_from_the_command_line(exp_files, tmp_path):
    out_json = tmp_path / "ga.json"
    r = cli("fit", str(exp_files["paper_exp1"]), "--method", "ga", "--population", "20",
            "--generations", "15", "--json", str(out_json))
    assert r.returncode == 0, r.stderr
    doc = json.loads(out_json.read_text())
    assert doc["method"] == "ga"
    assert doc["runs"][0]["population"] == 20 and doc["runs"][0]["generations"] == 15


@pytest.mark.parametrize("args, expect", [
    (["fit", "missing.csv"], "missing.csv: file not found"),
    (["fit", "config/scenarios/paper_exp1.yaml"], "unsupported file type"),
    (["fit", "{bad}", "--runs", "0"], "must be at least 1"),
])
def test_bad_input_is_one_line_not_a_traceback(args, expect, tmp_path):
    args = [a.replace("{bad}", str(tmp_path / "x.csv")) for a in args]
    r = cli(*args)
    assert r.returncode != 0
    assert expect in r.stderr
    assert "Traceback" not in r.stderr


def test_broken_csv_names_file_column_and_line(tmp_path):
    bad = tmp_path / "broken.csv"
    bad.write_text("t_min,tc_soak_1,tc_heat_1,tc_preheat_1,burners_soak,burners_heat,"
                   "burners_preheat\n0,30,30,30,2,0,0\n1,31,abc,30,2,0,0\n")
    r = cli("fit", str(bad))
    assert r.returncode == 1
    assert "broken.csv" in r.stderr and "tc_heat_1" in r.stderr and "line 3" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_progress_bar_only_on_a_terminal():
    import io

    from furnace_model.cli.fit import ProgressBar

    class Tty(io.StringIO):
        def isatty(self):
            return True

    tty, pipe = Tty(), io.StringIO()
    for stream in (tty, pipe):
        bar = ProgressBar("fitting", stream)
        for f in (0.0, 0.5, 1.0):
            bar(f)
        bar.close()
    assert "100%" in tty.getvalue() and "\r" in tty.getvalue()
    assert pipe.getvalue() == ""


def test_a_zone_without_any_reading_is_refused(tmp_path):
    bad = tmp_path / "blind.csv"
    rows = "".join(f"{i},{30 + i},,{30 + i},2,0,0\n" for i in range(5))
    bad.write_text("t_min,tc_soak_1,tc_heat_1,tc_preheat_1,burners_soak,burners_heat,"
                   "burners_preheat\n" + rows)
    r = cli("fit", str(bad))
    assert r.returncode == 1
    assert "blind.csv" in r.stderr and "zone 'heat' has no readings" in r.stderr
    assert "Traceback" not in r.stderr


def test_a_record_with_fewer_readings_than_unknowns_is_refused(tmp_path):
    """Three rows of the paper's furnace: nine readings against six parameters and each
    zone's initial state and offset. Any parameter set fits them exactly, so nothing can be
    estimated; said so, not a traceback from a residual variance of zero."""
    short = tmp_path / "short.csv"
    rows = "".join(f"{i},{900 + i},{800 + 2 * i},{600 + 3 * i},{i},{i},{i}\n" for i in range(3))
    short.write_text("t_min,tc_soak_1,tc_heat_1,tc_preheat_1,burners_soak,burners_heat,"
                     "burners_preheat\n" + rows)
    r = cli("fit", str(short))
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    assert "too few readings to fit: 9 for 12 unknowns" in r.stderr, r.stderr


def test_zone_offsets_are_fitted_unless_switched_off(exp_files, tmp_path):
    data = str(exp_files["paper_exp1"])
    docs = {}
    for flag in ("", "--zone-offsets", "--no-zone-offsets"):
        out = tmp_path / f"fit{flag}.json"
        r = cli("fit", data, *([flag] if flag else []), "--json", str(out))
        assert r.returncode == 0, r.stderr
        docs[flag] = json.loads(out.read_text())
    assert docs[""]["zone_offsets_c"] == docs["--zone-offsets"]["zone_offsets_c"]
    assert set(docs[""]["zone_offsets_c"][0]) == {"soak", "heat", "preheat"}
    assert docs["--no-zone-offsets"]["zone_offsets_c"] is None
    # the offsets are free parameters: with them the sum of squares can only go down
    assert docs[""]["sse"] <= docs["--no-zone-offsets"]["sse"]


def test_fix_and_bounds_hold_and_narrow_the_parameters_and_are_recorded(exp_files, tmp_path):
    out = tmp_path / "fixed.json"
    r = cli("fit", str(exp_files["paper_exp1"]), "--fix", "d=0.8", "--bounds", "e=0.5:0.6",
            "--bounds", "f=0.1:0.2,a=0.01:0.05", "--json", str(out))
    assert r.returncode == 0, r.stderr
    doc = json.loads(out.read_text())
    assert doc["params"]["d"] == 0.8 and doc["ci95"]["d"] == [0.8, 0.8]
    assert 0.5 <= doc["params"]["e"] <= 0.6
    assert 0.1 <= doc["params"]["f"] <= 0.2  # a box without the truth, 0.224: f stays in it
    assert 0.01 <= doc["params"]["a"] <= 0.05
    assert doc["fixed"] == {"d": 0.8}
    assert {k: doc["bounds"][k] for k in "aef"} == {"e": [0.5, 0.6], "f": [0.1, 0.2],
                                                    "a": [0.01, 0.05]}
    assert "d" not in doc["bounds"]  # fixed, not searched
    r = cli("fit", str(exp_files["paper_exp1"]), "--json", str(out))
    assert r.returncode == 0, r.stderr
    doc = json.loads(out.read_text())
    assert doc["fixed"] == {} and doc["bounds"]["e"] == [0.001, 50.0]  # the parameter's own box


@pytest.mark.parametrize("args, expect", [
    (["--fix", "z=1"], "argument --fix: 'z=1': unknown parameter z; the model has a, b, c, d, e, f"),
    (["--fix", "d=abc"], "argument --fix: 'd=abc': not a number: 'abc'"),
    (["--fix", "d"], "argument --fix: 'd': expected NAME=VALUE"),
    (["--fix", "d=0.8,e=inf"], "argument --fix: 'e=inf': not a finite number: 'inf'"),
    (["--fix", "d=99"], "argument --fix: 'd=99': 99 is outside d's search box, 0.001 to 50"),
    (["--fix", "d=0.8", "--fix", "d=0.9"], "argument --fix: 'd=0.9': d is given twice"),
    (["--bounds", "d=2:0.1"],
     "argument --bounds: 'd=2:0.1': the lower bound 2 must be below the upper 0.1"),
    (["--bounds", "d=0.1"], "argument --bounds: 'd=0.1': expected NAME=LO:HI"),
    (["--bounds", "a=0:0.5"],
     "argument --bounds: 'a=0:0.5': 0 is outside a's search box, 0.0001 to 1"),
    (["--fix", "d=0.8", "--bounds", "d=0.1:2"],
     "argument --bounds: 'd=0.1:2': d is also fixed; a parameter is either fixed or bounded"),
    (["--bounds", "d=0.1:2", "--fix", "e=0.7,d=0.8"],
     "argument --fix: 'd=0.8': d is also bounded; a parameter is either fixed or bounded"),
])
def test_bad_fix_or_bounds_is_a_usage_error_before_any_fit(args, expect, tmp_path):
    """Checked when read: the data file does not even exist, and no JSON appears."""
    out = tmp_path / "never.json"
    r = cli("fit", str(tmp_path / "absent.csv"), *args, "--json", str(out))
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines()[-1] == f"furnace-model fit: error: {expect}"
    assert "Traceback" not in r.stderr and not out.exists()


def test_the_report_has_sd_covariance_criteria_and_why_the_search_stopped(exp_files, tmp_path):
    out_json = tmp_path / "fit.json"
    r = cli("fit", str(exp_files["paper_exp1"]), "--json", str(out_json))
    assert r.returncode == 0, r.stderr
    doc = json.loads(out_json.read_text())
    names = list("abcdef")
    assert list(doc["std"]) == names and doc["cov"]["names"] == names and doc["fixed"] == {}
    cov = doc["cov"]["matrix"]
    for i, k in enumerate(names):
        if k in doc["at_bound"]:  # no sd on the edge of the range (d may run there)
            assert doc["std"][k] is None and cov[i][i] is None
        else:
            assert doc["std"][k] > 0 and cov[i][i] == pytest.approx(doc["std"][k] ** 2)
    assert doc["stop_reason"] == "converged" and doc["iterations"] > 0
    assert doc["runs"][0]["stop_reason"] == "converged"
    assert doc["aic"] < doc["aicc"] and doc["bic"] > doc["aic"] and doc["fpe"] > 0
    n_est = 6 + 3 + (3 if doc["zone_offsets_c"] else 0)
    assert doc["n_estimated"] == n_est and doc["n_samples"] == 3311
    assert "| parameter | value | sd | 95% interval | determined |" in r.stdout
    assert f"AIC {doc['aic']:.1f}" in r.stdout and f"np = {n_est} estimated" in r.stdout
    assert "stopped: converged" in r.stdout
    assert "°C" in r.stdout and "degC" not in r.stdout


def test_a_parameter_beyond_its_range_is_flagged_on_the_bound(tmp_path):
    """The furnace's c is 3e-5, the search range of c starts at 1e-4: the fit ends on the
    edge, and says so instead of printing 1e-4 as c's value."""
    from furnace_model.experiment import write_table
    from furnace_model.simulation.parameters import PAPER_TABLE_V
    from furnace_model.simulation.plant import Plant
    from furnace_model.simulation.scenario import load_scenario
    from furnace_model.simulation.structure import ModelStructure

    scn = load_scenario(ROOT / "config/scenarios/paper_exp1.yaml")
    truth = {**PAPER_TABLE_V, "c": 3e-5, "f": 0.12}  # f lower: still a heat-up, not a melt
    plant = Plant(ModelStructure(furnace=PAPER), truth, scn.sensors, seed=1)
    data = tmp_path / "tight_preheat.csv"
    write_table(plant.run_scenario(scn).to_experiment("tight_preheat").to_frame(), data)
    out_json = tmp_path / "fit.json"
    r = cli("fit", str(data), "--json", str(out_json))
    assert r.returncode == 0, r.stderr
    doc = json.loads(out_json.read_text())
    assert doc["at_bound"]["c"] == "lower"
    assert doc["params"]["c"] == pytest.approx(1e-4, rel=0.012) and doc["std"]["c"] is None
    assert "| c | at lower bound 0.0001 | - | - |" in r.stdout
    assert "| c | 0.0001 |" not in r.stdout
    assert "c ended on the lower bound of its search range" in r.stderr
