"""What both command lines promise before any work starts: --help and --version without the
heavy libraries, output paths refused when read, options that do not swallow the files after
them, and the names they check equal to the library's."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import pytest

from furnace_model.cli import build_parser as model_parser
from furnace_model.cli.names import EFFECTS, METHODS, NOISE, OUT_OF_LIBRARY
from furnace_model.simulation.furnace import PAPER

ROOT = Path(__file__).resolve().parent.parent
HEAVY = ("numpy", "pandas", "scipy", "matplotlib", "pymodbus", "mcap", "can", "pyarrow", "yaml")

PROBE = """
import argparse, contextlib, io, json, sys
from furnace_model.cli import build_parser as model, main as model_main
from furnace_daq.cli import build_parser as daq, main as daq_main

def paths(parser, path=()):
    yield path
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from paths(sub, (*path, name))

answered = []
for build, main in ((model, model_main), (daq, daq_main)):
    for path in paths(build()):
        for flag in ("--help", "--version")[:2 if not path else 1]:
            out = io.StringIO()
            with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
                main([*path, flag])
            answered.append([build.__module__, *path, flag, out.getvalue()[:200]])
# every argparse type= and action the commands have, parsed as a user would give them
model().parse_args(["fit", "a.csv", "--fix", "d=0.87,e=0.7", "--bounds", "a=0.001:0.5",
                    "--no-zone-offsets", "--json", "f.json", "--plot", "plots"])
model().parse_args(["diagnose", "a.csv", "--holdout", "b.csv", "--effects", "sensor_lag",
                    "--json", "d.json", "--report", "d.html"])
model().parse_args(["selfcheck", "--effects", "none", "zone_burners+sensor_lag", "door_open",
                    "--candidates", "dead_time", "--json", "s.json"])
model().parse_args(["validate", "a.csv", "--params", "f.json", "--json", "v.json"])
model().parse_args(["fit", "logs", "--from", "2026-03-02T06:00:00Z", "--to",
                    "2026-03-03T06:00:00+01:00", "--period", "30"])
model().parse_args(["simulate", "--scenario", "s.yaml", "--out", "a.csv"])
daq().parse_args(["logs", "export", "a.mcap", "--out", "a.csv"])
daq().parse_args(["logs", "recover", "a.mcap", "--out", "b.mcap"])
daq().parse_args(["replay", "a.mcap", "--out", "m.mcap"])
print(json.dumps({"answered": answered,
                  "loaded": sorted({m.split(".")[0] for m in sys.modules} & set(HEAVY))}))
"""


def run(*argv: str, cwd: Path = ROOT, timeout: float = 60) -> subprocess.CompletedProcess:
    """This tree's commands in their own interpreter, from any working directory."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, *argv], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=env)


def test_help_version_and_argument_checks_load_no_heavy_library(tmp_path):
    """The structural side of the 0.3 s promise (bench/bench_cli.py measures the time): no
    heavy module is imported to build the parsers, answer --help at every level and
    --version, or to check every kind of argument."""
    probe = f"HEAVY = {HEAVY!r}\n" + PROBE
    r = run("-c", probe, cwd=tmp_path)  # tmp_path: the output paths above are relative to it
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout.strip().splitlines()[-1])
    assert doc["loaded"] == []
    answered = {tuple(a[1:-1]): a[-1] for a in doc["answered"]}
    # the walk reached every command and every `logs` action, and each answered
    for path in [("fit",), ("validate",), ("diagnose",), ("selfcheck",), ("simulate",),
                 ("sim-plc",), ("run",), ("replay",), ("logs", "export"), ("logs", "info"),
                 ("logs", "recover")]:
        assert answered[(*path, "--help")].startswith("usage:"), path
    assert answered[("--version",)].startswith("furnace-")


def test_the_probe_sees_a_heavy_import_when_there_is_one(tmp_path):
    """The check above can fail: the same probe after loading numpy reports it."""
    probe = f"HEAVY = {HEAVY!r}\nimport numpy\n" + PROBE
    r = run("-c", probe, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.strip().splitlines()[-1])["loaded"] == ["numpy"]


@pytest.mark.parametrize("module, prog", [("furnace_model.cli", "furnace-model"),
                                          ("furnace_daq.cli", "furnace-daq")])
def test_version_is_the_installed_distribution(module, prog):
    r = run("-m", module, "--version")
    assert r.returncode == 0, r.stderr
    assert r.stdout == f"{prog} {version('furnace-daq')}\n"


def test_version_from_a_tree_that_is_not_installed_says_so(tmp_path):
    """A copy of the source tree without site-packages (nor the egg-info an editable install
    leaves in the checkout): the distribution is not found; pyproject.toml's version is
    given, marked as not installed."""
    tree = tmp_path / "tree"
    shutil.copytree(ROOT / "furnace_model", tree / "furnace_model",
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tree / "pyproject.toml")
    r = run("-I", "-S", "-c", f"import sys; sys.path.insert(0, {str(tree)!r}); "
                        "from furnace_model.cli.arguments import version; print(version())",
            cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"{version('furnace-daq')} (not installed)"


OUTPUT_OPTIONS = [
    ("furnace_model.cli", ["fit", "{data}", "--json", "{out}"]),
    ("furnace_model.cli", ["validate", "{data}", "--params", "{data}", "--json", "{out}"]),
    ("furnace_model.cli", ["diagnose", "{data}", "--json", "{out}"]),
    ("furnace_model.cli", ["diagnose", "{data}", "--report", "{out}"]),
    ("furnace_model.cli", ["selfcheck", "--draws", "1", "--json", "{out}"]),
    ("furnace_model.cli", ["simulate", "--scenario", "{data}", "--out", "{out}"]),
    ("furnace_daq.cli", ["logs", "export", "{data}", "--out", "{out}"]),
    ("furnace_daq.cli", ["logs", "recover", "{data}", "--out", "{out}"]),
    ("furnace_daq.cli", ["replay", "{data}", "--out", "{out}"]),
    ("furnace_daq.cli", ["config", "--furnace", "{data}", "--out", "{out}"]),
]


@pytest.mark.parametrize("module, argv", OUTPUT_OPTIONS,
                         ids=[" ".join(a[:2 if a[0] == "logs" else 1]) + " " + a[-2]
                              for _, a in OUTPUT_OPTIONS])
def test_an_output_file_in_a_missing_directory_is_refused_before_any_work(module, argv,
                                                                          tmp_path):
    """Exit 2 naming the directory, and the directory not created. The input does not exist
    either: had the command started its work, it would have failed on that (exit 1) first."""
    missing = tmp_path / "no" / "such"
    args = [a.format(data=tmp_path / "absent.csv", out=missing / "out.x") for a in argv]
    r = run("-m", module, *args)
    assert r.returncode == 2, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last.endswith(f"argument {argv[-2]}: no such directory: {missing} "
                         f"(for {missing / 'out.x'})"), last
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "no").exists()


def test_an_output_file_that_is_a_directory_or_a_plot_dir_that_is_a_file_is_refused(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    r = run("-m", "furnace_model.cli", "fit", "x.csv", "--json", str(tmp_path))
    assert r.returncode == 2 and f"argument --json: {tmp_path} is a directory" in r.stderr
    r = run("-m", "furnace_model.cli", "fit", "x.csv", "--plot", str(a_file))
    assert r.returncode == 2 and f"argument --plot: {a_file} exists and is not a directory" \
        in r.stderr


def test_holdout_takes_one_file_and_leaves_the_rest_to_the_fit():
    parse = model_parser().parse_args
    args = parse(["diagnose", "a.csv", "--holdout", "b.csv", "c.csv"])
    assert args.data == [Path("a.csv"), Path("c.csv")] and args.holdout == [Path("b.csv")]
    args = parse(["diagnose", "a.csv", "--holdout", "b.csv", "--holdout", "c.csv"])
    assert args.data == [Path("a.csv")] and args.holdout == [Path("b.csv"), Path("c.csv")]
    assert parse(["diagnose", "a.csv", "b.csv"]).holdout is None


def test_no_option_that_takes_several_values_precedes_a_positional():
    """The flaw --holdout had, looked for in every command: an option of nargs '+' or '*'
    in a parser that also has positional arguments swallows the files after it."""
    from furnace_daq.cli import build_parser as daq_parser

    def parsers(p):
        yield p
        for a in p._actions:
            if a.choices and isinstance(a.choices, dict):
                for sub in a.choices.values():
                    yield from parsers(sub)

    for top in (model_parser(), daq_parser()):
        for p in parsers(top):
            acts = [a for a in p._actions if a.help != "==SUPPRESS=="]
            positional = [a for a in acts if not a.option_strings and not a.choices]
            greedy = [a.option_strings for a in acts if a.option_strings and a.nargs in ("+", "*")]
            assert not (positional and greedy), (p.prog, greedy)


def test_the_names_checked_before_loading_are_the_librarys():
    from furnace_model.cli.selfcheck import _label
    from furnace_model.diagnosis.cases import NOISE as LIBRARY_NOISE
    from furnace_model.diagnosis.cases import OUT_OF_LIBRARY as LIBRARY_OOL
    from furnace_model.diagnosis.cases import parse_label
    from furnace_model.effects import BUILT_IN as LIBRARY_EFFECTS
    from furnace_model.identification.fit import METHODS as LIBRARY_METHODS
    from furnace_model.simulation.parameters import BASELINE
    from furnace_model.simulation.structure import ModelStructure

    assert tuple(LIBRARY_EFFECTS) == EFFECTS
    assert OUT_OF_LIBRARY == LIBRARY_OOL
    assert METHODS == LIBRARY_METHODS
    assert NOISE == LIBRARY_NOISE
    # what fit --fix checks
    assert [p.name for p in BASELINE] == ModelStructure(furnace=PAPER).names
    for label in ("none", "sensor_lag", "zone_burners+sensor_lag", "door_open", "warp",
                  "sensor_lag+", "+", "none+sensor_lag", ""):
        try:
            parse_label(label)
            library_accepts = True
        except ValueError:
            library_accepts = False
        try:
            _label(label)
            cli_accepts = True
        except Exception:
            cli_accepts = False
        assert cli_accepts == library_accepts, label
