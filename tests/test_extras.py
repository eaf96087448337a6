"""The extras (pyproject.toml, furnace_model/extras.py): the daemon runs without any of them,
and a command that needs one says which to install, before its work, never with an
ImportError's traceback."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from daq_processes import ROOT, furnace_daq, start_simplc, stop

from furnace_daq.cli import main as daq_main
from furnace_model.cli import main as model_main
from furnace_model.extras import EXTRAS, MissingExtra, missing, require

HEAVY = sorted({m for modules in EXTRAS.values() for m in modules})
"""Every module an extra brings (dask, distributed, matplotlib, pyarrow)."""


def refused(monkeypatch, *modules: str) -> None:
    """This process as an installation without `modules`: their import fails."""
    for name in modules:
        monkeypatch.setitem(sys.modules, name, None)


def test_require_names_the_extra_and_what_needs_it(monkeypatch):
    refused(monkeypatch, "matplotlib")
    assert missing("report") == ["matplotlib"]
    with pytest.raises(MissingExtra, match=r"^--plot needs matplotlib, .*install "
                                           r"furnace-daq\[report\]") as err:
        require("report", "--plot")
    assert err.value.extra == "report" and err.value.exit_code == 1


@pytest.mark.parametrize("main, argv, lacking, extra", [
    (model_main, ["fit", "nowhere.csv", "--plot", "plots"], "matplotlib", "report"),
    (model_main, ["diagnose", "nowhere.csv", "--report", "r.html"], "matplotlib", "report"),
    (model_main, ["simulate", "--scenario", "paper_exp1", "--out", "x.parquet"], "pyarrow",
     "parquet"),
    (daq_main, ["logs", "export", "nowhere.mcap", "--out", "x.parquet"], "pyarrow", "parquet"),
    (daq_main, ["fleet", "refit", "fleet.yaml", "--out", "fleet"], "distributed", "fleet"),
], ids=["fit-plot", "diagnose-report", "simulate-parquet", "export-parquet", "fleet"])
def test_a_command_needing_an_absent_extra_says_which(monkeypatch, tmp_path, capsys, main,
                                                      argv, lacking, extra):
    monkeypatch.chdir(tmp_path)
    refused(monkeypatch, lacking)
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert f"install furnace-daq[{extra}]" in err and lacking in err, err
    assert "Traceback" not in err
    # said before any work: nothing was written, and the input files were not even read
    assert list(tmp_path.iterdir()) == []


def poisoned(tmp_path: Path) -> dict[str, str]:
    """An environment in which every extra's module fails to import, in this process and
    in every child (the refit worker is spawned), as where they are not installed."""
    poison = tmp_path / "poison"
    for name in HEAVY:
        (poison / name).mkdir(parents=True)
        (poison / name / "__init__.py").write_text(
            f"raise ImportError('{name} is not installed (test_extras)')\n")
    return {"PYTHONPATH": os.pathsep.join([str(poison), str(ROOT)])}


def test_the_daemon_and_its_refit_worker_import_no_extra(tmp_path):
    env = {**os.environ, **poisoned(tmp_path)}
    code = ("import sys\n"
            "import furnace_daq.cli.run, furnace_daq.daemon, furnace_daq.refitworker\n"
            "import furnace_daq.liveview, furnace_daq.check, furnace_daq.simplc\n"
            "from furnace_daq.cli import main\n"
            f"heavy = [m for m in {HEAVY!r} if m in sys.modules]\n"
            "assert not heavy, heavy\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr


def test_the_daemon_polls_and_logs_without_extras(tmp_path):
    env = poisoned(tmp_path)
    plc, port = start_simplc("--speed", "600")
    try:
        proc = furnace_daq("run", "--config", str(ROOT / "config" / "gateway.yaml"),
                           "--plc", f"127.0.0.1:{port}", "--log-dir", str(tmp_path / "logs"),
                           "--state-dir", str(tmp_path / "state"), "--duration", "4", env=env)
        out, err = proc.communicate(timeout=90)
    finally:
        stop(plc)
    assert proc.returncode == 0, err
    assert "ImportError" not in err and "Traceback" not in err, err
    assert " polls ok" in err and list((tmp_path / "logs").glob("*.mcap"))
