"""`make demo` end to end: simulated PLC -> daemon -> MCAP -> export -> fit, one process."""

from __future__ import annotations

import json
import subprocess
import sys

from mcap.reader import make_reader

from furnace_model.parameters import PAPER_TABLE_V


def test_demo_runs_the_whole_chain_and_recovers_the_plant(tmp_path):
    out = tmp_path / "demo"
    done = subprocess.run([sys.executable, "-m", "furnace_daq.demo", "--out", str(out),
                           "--speed", "20000"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    logs = list((out / "logs").glob("*.mcap"))
    assert len(logs) == 1
    with logs[0].open("rb") as f:
        topics = {ch.topic for ch in make_reader(f).get_summary().channels.values()}
    assert {"/furnace/thermocouples", "/furnace/burners", "/daq/status"} <= topics
    result = json.loads((out / "fit.json").read_text())
    # a and f are determined at 1-minute sampling (docs/identification.md)
    for name in ("a", "f"):
        assert abs(result["params"][name] / PAPER_TABLE_V[name] - 1) < 0.03, name
    assert all(m["rmse_c"] < 1.5 for m in result["per_zone"].values())
    assert len(list(out.glob("*.png"))) == 3
    assert "truth" in done.stdout
