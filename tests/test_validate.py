"""`furnace-model validate`: the paper's Table VI, fitted parameters on another experiment."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from furnace_model.simulation.furnace import PAPER

ROOT = Path(__file__).resolve().parent.parent


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "furnace_model.cli", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp("val")
    for name, seed in (("paper_exp1", 11), ("paper_exp2", 12)):
        r = cli("simulate", "--scenario", f"config/scenarios/{name}.yaml",
                "--out", str(d / f"{name}.csv"), "--seed", str(seed))
        assert r.returncode == 0, r.stderr
    r = cli("fit", str(d / "paper_exp1.csv"), "--json", str(d / "fit.json"))
    assert r.returncode == 0, r.stderr
    return d


def test_validate_scores_the_other_experiment(fitted, tmp_path):
    out = tmp_path / "val.json"
    r = cli("validate", "--params", str(fitted / "fit.json"), str(fitted / "paper_exp2.csv"),
            "--json", str(out), "--plot", str(tmp_path / "png"))
    assert r.returncode == 0, r.stderr
    assert "| paper_exp2 | soak |" in r.stdout and "warning" not in r.stderr
    doc = json.loads(out.read_text())
    for zone in ("soak", "heat", "preheat"):
        m = doc["per_zone"][zone]
        # The plant is the model (plus thermocouple biases of sd 0.5): held-out errors stay
        # a few tenths of a degree above the noise floor of 1.5/sqrt(2).
        assert 0.9 < m["rmse_c"] < 2.5, (zone, m)
        assert m["fit_pct"] > 95
        assert (tmp_path / "png" / f"paper_exp2_{zone}.png").exists()


def test_wrong_parameters_score_worse(fitted, tmp_path):
    doc = json.loads((fitted / "fit.json").read_text())
    doc["params"]["f"] *= 1.2
    worse = tmp_path / "worse.json"
    worse.write_text(json.dumps(doc))
    good = cli("validate", "--params", str(fitted / "fit.json"), str(fitted / "paper_exp2.csv"),
               "--json", str(tmp_path / "g.json"))
    bad = cli("validate", "--params", str(worse), str(fitted / "paper_exp2.csv"),
              "--json", str(tmp_path / "b.json"))
    assert good.returncode == 0 and bad.returncode == 0
    g = json.loads((tmp_path / "g.json").read_text())["per_zone"]
    b = json.loads((tmp_path / "b.json").read_text())["per_zone"]
    assert b["soak"]["rmse_c"] > 5 * g["soak"]["rmse_c"]


@pytest.mark.parametrize("content, expect", [
    (None, "file not found"),
    ("{not json", "not a readable JSON file"),
    ('{"model": "paper-3zone"}', "no 'params' object"),
    ('{"params": {"a": 0.02}}', "params.b: expected a number"),
    ('{"params": {"a": 1, "b": 1, "c": 1, "d": 1, "e": 1, "f": 1}, '
     '"effects": [{"name": "warp_drive"}]}', "unknown effect 'warp_drive'"),
])
def test_bad_params_file(fitted, tmp_path, content, expect):
    path = tmp_path / "p.json"
    if content is not None:
        path.write_text(content)
    r = cli("validate", "--params", str(path), str(fitted / "paper_exp2.csv"))
    assert r.returncode != 0
    assert expect in r.stderr and str(path) in r.stderr
    assert "Traceback" not in r.stderr


def test_params_of_an_extended_structure_round_trip(tmp_path):
    from furnace_model.cli.validate import load_params
    from furnace_model.effects import ZoneLosses
    from furnace_model.identification.result import FitResult
    from furnace_model.simulation.structure import ModelStructure

    structure = ModelStructure([ZoneLosses(zones=("heat",), furnace=PAPER)], furnace=PAPER)
    values = structure.defaults()
    res = FitResult(structure, values, [], {k: (v, v) for k, v in values.items()},
                    np.eye(len(values)), [], [],
                    [], {}, 0.0, 0, 0.0, [])
    doc = res.to_json(["x.csv"])
    path = tmp_path / "fit.json"
    path.write_text(json.dumps(doc))
    params, back = load_params(path)
    assert back.names == structure.names
    assert back.effects[0].options == structure.effects[0].options
    assert params == values


def test_zone_offsets_take_the_bias_out_of_the_score(fitted, tmp_path):
    args = ["validate", "--params", str(fitted / "fit.json"), str(fitted / "paper_exp2.csv")]
    plain = cli(*args, "--no-zone-offsets", "--json", str(tmp_path / "plain.json"))
    offset = cli(*args, "--zone-offsets", "--json", str(tmp_path / "off.json"))
    assert plain.returncode == 0 and offset.returncode == 0, offset.stderr
    p = json.loads((tmp_path / "plain.json").read_text())["per_zone"]
    o = json.loads((tmp_path / "off.json").read_text())["per_zone"]
    for zone in ("soak", "heat", "preheat"):
        assert o[zone]["rmse_c"] <= p[zone]["rmse_c"] + 1e-9
        assert abs(o[zone]["rmse_c"] / (1.5 / 2 ** 0.5) - 1) < 0.15, (zone, o[zone])


def test_horizon_scores_the_k_step_prediction_beside_the_simulation(fitted, tmp_path):
    """f 10% high: the simulation drifts off, the prediction from readings a few samples
    back does not; the further ahead, the closer to the simulation (compare(data, model, K))."""
    doc = json.loads((fitted / "fit.json").read_text())
    doc["params"]["f"] *= 1.1
    wrong = tmp_path / "wrong.json"
    wrong.write_text(json.dumps(doc))
    data = [str(fitted / "paper_exp1.csv"), str(fitted / "paper_exp2.csv")]
    got = {}
    for k in (1, 30):
        out = tmp_path / f"k{k}.json"
        r = cli("validate", "--params", str(wrong), *data, "--horizon", str(k),
                "--json", str(out))
        assert r.returncode == 0, r.stderr
        assert f"| {k}-step RMSE (°C) | {k}-step fit % |" in r.stdout
        assert "| all | soak |" in r.stdout and "degC" not in r.stdout
        got[k] = json.loads(out.read_text())
        assert got[k]["horizon"] == k
        assert set(got[k]["prediction"]["per_experiment"]) == {"paper_exp1", "paper_exp2"}
    for zone in ("soak", "heat", "preheat"):
        sim = got[1]["per_zone"][zone]["fit_pct"]
        one = got[1]["prediction"]["per_zone"][zone]["fit_pct"]
        thirty = got[30]["prediction"]["per_zone"][zone]["fit_pct"]
        assert one > thirty > sim, (zone, one, thirty, sim)
        assert got[30]["per_zone"][zone] == got[1]["per_zone"][zone]  # the simulation's own
    plain = cli("validate", "--params", str(wrong), data[0], "--json", str(tmp_path / "p.json"))
    assert plain.returncode == 0 and "-step" not in plain.stdout
    assert json.loads((tmp_path / "p.json").read_text())["prediction"] is None


def test_a_horizon_of_no_samples_is_refused(fitted):
    r = cli("validate", "--params", str(fitted / "fit.json"), str(fitted / "paper_exp2.csv"),
            "--horizon", "0")
    assert r.returncode != 0
    assert "--horizon: must be at least 1, got 0" in r.stderr and "Traceback" not in r.stderr


def test_validate_scores_a_record_with_an_outage_as_its_two_parts(fitted, tmp_path):
    """100 minutes without a row, whose inputs are unknown: said, with the span, and each
    part is scored from its own start, as a record of its own, as near the noise as the
    whole record is (the model holding the inputs across would miss after it)."""
    lines = (fitted / "paper_exp2.csv").read_text().splitlines(keepends=True)
    holed = tmp_path / "holed.csv"
    holed.write_text("".join(lines[:1201] + lines[1301:]))  # header, then minutes 0-1199
    r = cli("validate", "--params", str(fitted / "fit.json"), str(holed))
    assert r.returncode == 0, r.stderr
    assert ("furnace-model validate: warning: holed: no rows for 1.7 h from " in r.stderr
            and "taken as 2 records (holed-1, holed-2)" in r.stderr), r.stderr
    whole = cli("validate", "--params", str(fitted / "fit.json"), str(fitted / "paper_exp2.csv"))
    worst = {}
    for name, out in (("holed-1", r.stdout), ("holed-2", r.stdout), ("paper_exp2", whole.stdout)):
        rows = [line.split("|") for line in out.splitlines() if line.startswith(f"| {name} |")]
        assert len(rows) == 3, out  # a row per zone
        worst[name] = max(float(row[4]) for row in rows)  # RMSE
    assert max(worst["holed-1"], worst["holed-2"]) < 1.5 * worst["paper_exp2"], worst
