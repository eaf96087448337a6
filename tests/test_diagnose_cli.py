"""`furnace-model diagnose` as a user runs it: files in, summary and JSON out, and one clear
line (never a traceback) for data that cannot be diagnosed."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from proctree import alive, children

from furnace_model.diagnosis.cases import draw_case
from furnace_model.experiment import write_table
from furnace_model.simulation.furnace import PAPER

ROOT = Path(__file__).resolve().parent.parent


def cli(*args: str, timeout: float = 280) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "furnace_model.cli", "diagnose", *args],
                          cwd=ROOT, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def case_files(tmp_path_factory) -> tuple[Path, Path, dict]:
    case = draw_case("zone_burners", np.random.default_rng(21), furnace=PAPER)
    d = tmp_path_factory.mktemp("diag")
    fit, hold = d / "exp1.csv", d / "exp2.parquet"
    write_table(case.fit[0].to_frame(), fit)
    write_table(case.holdout[0].to_frame(), hold)
    return fit, hold, case.truth


def test_diagnose_names_the_effect_and_writes_the_contract_json(case_files, tmp_path):
    """Also: a progress line per stage on stderr, none with --quiet, which changes nothing
    else."""
    fit, hold, _truth = case_files
    out = tmp_path / "d.json"
    # a limit far beyond the diagnosis's time changes nothing and leaves nothing untried
    args = (str(fit), "--holdout", str(hold), "--effects", "zone_burners,sensor_lag,dead_time",
            "--time-limit", "3600")
    r = cli(*args, "--json", str(out))
    assert r.returncode == 0, r.stderr
    lines = [x for x in r.stderr.splitlines() if x.startswith("furnace-model diagnose: ")]
    assert lines[0].startswith("furnace-model diagnose: fitting the baseline (")
    assert all(any(f"{e} fitted in" in x for x in lines)
               for e in ("zone_burners", "sensor_lag", "dead_time"))
    # the first of the three says how long the others will take; the last, none
    counts = [x for x in lines if " fitted in " in x and " of 3" in x]
    assert "(1 of 3; about " in counts[0] and " left for the others)" in counts[0]
    assert "(3 of 3) (" in counts[-1] and "left" not in counts[-1]
    assert lines[-1].startswith("furnace-model diagnose: judging (")
    quiet = cli(*args, "--quiet")
    assert quiet.returncode == 0 and "furnace-model diagnose: " not in quiet.stderr
    assert quiet.stdout == r.stdout
    assert "Judged without" not in r.stdout
    # the verdict first, then the evidence: baseline, where, candidates
    assert r.stdout.startswith("Verdict: explained (zone_burners)\n")
    order = [r.stdout.index(h) for h in ("Baseline (the paper's model", "Where the error lies",
                                         "Candidates, best first")]
    assert order == sorted(order)
    assert ("| zone | RMSE fit (°C) | RMSE held out (°C) | noise floor (°C) | gap limit (°C) "
            "| gap |") in r.stdout
    assert "Noise floor per record" in r.stdout and "from the thermocouple pair's" in r.stdout
    assert "degC" not in r.stdout and " C;" not in r.stdout
    doc = json.loads(out.read_text())
    assert doc["untried"] == [] and doc["time_limit_s"] == 3600
    # each record's own floor, per zone, and the one the held-out RMSE is judged against
    assert [f["role"] for f in doc["noise_floors"]] == ["fit", "holdout"]
    held = doc["noise_floors"][1]["zones"]
    for z in ("soak", "heat", "preheat"):
        assert held[z]["how"] == "pair" and 0.9 < held[z]["floor_c"] < 1.25
        assert doc["baseline"]["noise_floor_c"][z] == pytest.approx(held[z]["floor_c"], abs=1e-6)
        assert doc["baseline"]["gap_limit_c"][z] >= 1.25 * held[z]["floor_c"] - 1e-6
    assert set(doc["baseline"]) >= {"rmse_fit_c", "rmse_holdout_c", "noise_floor_c"}
    assert set(doc["baseline"]["rmse_holdout_c"]) == {"soak", "heat", "preheat"}
    assert doc["verdict"]["status"] == "explained"
    assert doc["verdict"]["effects"] == ["zone_burners"]
    assert doc["verdict"]["shrink_pct"] >= 50
    assert [c["effect"] for c in doc["candidates"]][0] == "zone_burners"
    for c in doc["candidates"]:
        assert set(c) >= {"effect", "params", "rmse_fit_c", "rmse_holdout_c", "shrink_pct",
                          "delta_bic", "credit"}
        # the credit the summary prints is the JSON's
        row = next(line for line in r.stdout.splitlines() if line.startswith(f"| {c['effect']} |"))
        assert row.rstrip(" |").endswith("| yes") == c["credit"], row
    assert doc["candidates"][0]["credit"] is True
    for w in doc["where"]:
        assert set(w) >= {"zone", "sensor", "start", "end", "share_of_error", "regime"}
        assert w["start"].endswith("Z")
        assert w["kind"] in {"sensor", "change", "span", "throughout"}
    assert doc["holdout_how"] == "given"


def test_one_short_file_is_refused_with_what_is_missing(case_files, tmp_path):
    fit, _hold, _ = case_files
    import pandas as pd

    short = tmp_path / "short.csv"
    pd.read_csv(fit).iloc[:80].to_csv(short, index=False)
    r = cli(str(short))
    assert r.returncode == 1
    assert "too short to hold out" in r.stderr and "--holdout" in r.stderr
    assert "Traceback" not in r.stderr


def test_no_excitation_and_missing_zone_are_one_line_errors(case_files, tmp_path):
    fit, hold, _ = case_files
    import pandas as pd

    frame = pd.read_csv(fit)
    steady = tmp_path / "steady.csv"
    frame.assign(burners_soak=4, burners_heat=0, burners_preheat=0).to_csv(steady, index=False)
    r = cli(str(steady), "--holdout", str(hold))
    assert r.returncode == 1 and "no burner change" in r.stderr
    assert "Traceback" not in r.stderr
    blind = tmp_path / "blind.csv"
    frame.drop(columns=["tc_heat_1", "tc_heat_2"]).to_csv(blind, index=False)
    r = cli(str(fit), str(blind))
    assert r.returncode == 1 and "zone 'heat' has no thermocouple column" in r.stderr
    empty_zone = tmp_path / "empty_zone.csv"
    frame.assign(tc_heat_1="", tc_heat_2="").to_csv(empty_zone, index=False)
    r = cli(str(fit), str(empty_zone))
    assert r.returncode == 1 and "zone 'heat' has no thermocouple readings" in r.stderr


def test_unknown_effect_is_a_usage_error(case_files):
    fit, hold, _ = case_files
    r = cli(str(fit), "--holdout", str(hold), "--effects", "zone_burners,warp_drive")
    assert r.returncode == 2 and "warp_drive" in r.stderr


@contextlib.contextmanager
def fitting_candidates(case_files, workers_wanted: int = 1):
    """A `diagnose` command of the case, once it is fitting its candidates in worker
    processes: (the process, its workers). Whatever the test leaves of them ends after it."""
    fit, hold, _truth = case_files
    workers: set[int] = set()
    proc = subprocess.Popen([sys.executable, "-m", "furnace_model.cli", "diagnose", str(fit),
                             "--holdout", str(hold)], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True,
                            # Ctrl-C as at a terminal (see test_selfcheck's stopped check)
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 120
        for line in proc.stderr:
            if "fitting the candidate effects" in line:
                while len(workers) < workers_wanted and time.monotonic() < deadline:
                    workers = children(proc.pid)
                    time.sleep(0.05)
                break
        assert workers, "no worker process was started"
        yield proc, workers
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
        for w in workers:
            with contextlib.suppress(OSError):
                if b"furnace_model.cli" in Path(f"/proc/{w}/cmdline").read_bytes():
                    os.kill(w, signal.SIGKILL)


def outlived(workers: set[int]) -> set[int]:
    """Those of the workers still running 20 s on."""
    deadline = time.monotonic() + 20
    left = alive(workers)
    while left and time.monotonic() < deadline:
        time.sleep(0.1)
        left = alive(left)
    return left


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs Linux /proc")
def test_a_killed_diagnosis_leaves_no_worker_behind(case_files):
    """SIGKILL, as a batch runner's timeout sends it, while the candidates are fitted in
    their worker processes: the workers end with it."""
    with fitting_candidates(case_files) as (proc, workers):
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        left = outlived(workers)
        assert not left, f"workers {sorted(left)} outlived the killed diagnosis"


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs Linux /proc")
def test_an_interrupted_diagnosis_exits_at_once_and_ends_its_workers(case_files):
    """Ctrl-C while the candidates are fitted: the command exits with 130 without waiting for
    the candidates still to fit, and its workers end with it. The workers are stopped
    (SIGSTOP) before the interrupt, so a command that waited for them would never exit."""
    with fitting_candidates(case_files, workers_wanted=2) as (proc, workers):
        for w in workers:
            os.kill(w, signal.SIGSTOP)
        os.kill(proc.pid, signal.SIGINT)
        _out, err = proc.communicate(timeout=60)
        assert proc.returncode == 130 and "interrupted" in err, err
        assert "Traceback" not in err
        left = outlived(workers)
        assert not left, f"workers {sorted(left)} outlived the interrupted diagnosis"


def test_a_time_limit_answers_and_names_what_it_left(case_files, tmp_path):
    """A limit shorter than the candidates' fits: the baseline still completes, the verdict
    is judged on what was fitted, and every effect asked for is either a candidate or named
    as not tried, in the summary and the JSON."""
    fit, hold, _truth = case_files
    out = tmp_path / "d.json"
    effects = ("zone_burners", "sensor_lag", "wall_storage")
    r = cli(str(fit), "--holdout", str(hold), "--effects", ",".join(effects),
            "--time-limit", "0.001", "--json", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    d = json.loads(out.read_text())
    assert d["time_limit_s"] == 0.001
    assert set(d["untried"]) == set(effects)  # nothing could be fitted in a millisecond
    assert d["candidates"] == [] and d["verdict"]["status"] == "unexplained"
    assert d["baseline"]["gap_zones"]  # the baseline, fitted in full, still sees the gap
    assert "Judged without what the time limit of 0.001 s left unfitted" in r.stdout
    for name in effects:
        assert name in r.stdout.split("Judged without")[1].split("\n")[0]


@pytest.mark.parametrize("bad", ["0", "-3", "soon", "inf"])
def test_a_time_limit_must_be_seconds_above_zero(case_files, bad):
    fit, hold, _ = case_files
    r = cli(str(fit), "--holdout", str(hold), "--time-limit", bad)
    assert r.returncode == 2 and "--time-limit" in r.stderr and bad in r.stderr
