"""Hostile YAML for the daemon's config and for scenarios: unknown keys, wrong types, huge
numbers, 1e400, deep nesting, billion-laughs anchors, Python object tags, binary. Each is one
line naming the file and the key (exit 2); nothing is ever evaluated."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
import yaml
from daq_processes import ROOT

from furnace_daq.cli import main as daq_main
from furnace_model.cli import main as model_main

GATEWAY = (ROOT / "config" / "gateway.yaml").read_text()
SCENARIO = (ROOT / "config" / "scenarios" / "paper_exp1.yaml").read_text()
PWNED = str(Path(tempfile.gettempdir()) / f"furnace-yaml-was-evaluated-{os.getpid()}")
"""What a YAML tag that ran would create: one per process, so that runs side by side do not
share it."""

LAUGHS = "lol: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]\n" + "".join(
    f"l{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]\n" for i in range(1, 10))
# The same, as one value: ten nested lists standing for 9**10 strings once expanded.
LAUGH_VALUE = "[&b0 [lol, lol, lol, lol, lol, lol, lol, lol, lol], " + ", ".join(
    f"&b{i} [{', '.join([f'*b{i - 1}'] * 9)}]" for i in range(1, 10)) + "]"


def _generic(base: str) -> dict[str, tuple[str | bytes, str]]:
    """name -> (file content, text the error must contain)."""
    tag = f"!!python/object/apply:os.system ['touch {PWNED}']"
    return {
        "unknown_key": (base + "\nbogus_key: 1\n", "bogus_key: unknown key"),
        "top_list": ("- 1\n- 2\n", "expected a mapping of keys, got a list"),
        "top_scalar": ("hello\n", "expected a mapping of keys"),
        "empty": ("", "required key is missing"),
        "binary": (bytes(range(256)) * 4, "cannot read"),
        "nul_byte": (base.replace("\n", "\x00\n", 1), "not valid YAML"),
        "python_tag": (tag + "\n", "the tag '!!python/object/apply:os.system' is not allowed"),
        "python_tag_in_value": (base + f"\nx: {tag}\n", "column 4: the tag '!!python/object/apply:os.system'"),
        "python_name_tag": (base + "\nx: !!python/name:os.system\n",
                            "the tag '!!python/name:os.system' is not allowed"),
        "two_documents": (base + "\n---\nfoo: 1\n", "not valid YAML"),
        "deep_list": ("x: " + "[" * 20000 + "]" * 20000 + "\n", "nested too deeply"),
        "deep_map": ("x: " + "{a: " * 5000 + "1" + "}" * 5000 + "\n", "nested too deeply"),
        "billion_laughs": (LAUGHS + base, "lol: unknown key"),
        "int_key": (base + "\n123: x\n", "keys must be text"),
        "merge_scalar": ("a: &x 5\nb:\n  <<: *x\n", "not valid YAML"),
    }


def config_cases() -> dict[str, tuple[str | bytes, str]]:
    doc = yaml.safe_load(GATEWAY)
    laughs_in_map = GATEWAY.replace("  soak_2:    {<<: *tc, address: 1}",
                                    f"  soak_2:    {LAUGH_VALUE}")
    cases = _generic(GATEWAY)
    cases.update({
        "laughs_in_thermocouples": (laughs_in_map, "thermocouples.soak_2: expected a mapping"),
        "wrong_type": (yaml.safe_dump({**doc, "poll_period_s": "fast"}),
                       "poll_period_s: expected a number, got text 'fast'"),
        "huge_float": (yaml.safe_dump({**doc, "poll_period_s": 1e300}),
                       "poll_period_s: must be at most"),
        "1e400": (GATEWAY.replace("poll_period_s: 1.0", "poll_period_s: 1.0e+400"),
                  "poll_period_s: expected a finite number, got inf"),
        "huge_int": (yaml.safe_dump({**doc, "poll_period_s": 10**400}),
                     "poll_period_s: expected a finite number, got 100000000000...(401 digits)"),
        "huge_port": (GATEWAY.replace("port: 5020", "port: " + "9" * 400),
                      "plc.port: must be at most 65535, got 999999999999...(400 digits)"),
        "huge_address": (GATEWAY.replace("address: 0, type", "address: 99999999999999999999, type"),
                         "thermocouples.soak_1.address: must be at most 65535"),
        "nan_scale": (GATEWAY.replace("scale: 0.1, sentinels", "scale: .nan, sentinels"),
                      "thermocouples.soak_1.scale: expected a finite number, got nan"),
        "bool_number": (yaml.safe_dump({**doc, "stale_after_s": True}),
                        "stale_after_s: expected a number, got a boolean"),
        "world_writable_logs": (GATEWAY.replace('file_mode: "0640"', 'file_mode: "0666"'),
                                "log.file_mode: 0666 is not allowed"),
        "unwritable_logs": (GATEWAY.replace('file_mode: "0640"', 'file_mode: "0440"'),
                            "log.file_mode: 0440 is not allowed"),
        "binary_tag": (GATEWAY.replace("host: 127.0.0.1", "host: !!binary aGVsbG8="),
                       "plc.host: expected text, got bytes"),
        "unknown_type": (GATEWAY.replace("type: int16", "type: int128"),
                         "thermocouples.soak_1.type: must be one of"),
        "date_epoch": (GATEWAY.replace(
            "clock: {table: input, address: 7, type: uint32, word_order: big}",
            "clock: {table: input, address: 7, type: uint32, word_order: big, epoch: 2026-03-02}"),
            "clock.epoch: give a UTC offset or Z"),
    })
    return cases


def scenario_cases() -> dict[str, tuple[str | bytes, str]]:
    doc = yaml.safe_load(SCENARIO)
    cases = _generic(SCENARIO)
    cases.update({
        "wrong_type": (yaml.safe_dump({**doc, "duration_min": "long"}),
                       "duration_min: expected a number, got text 'long'"),
        "huge_float": (yaml.safe_dump({**doc, "duration_min": 1e300}),
                       "duration_min: must be at most"),
        "1e400": (SCENARIO.replace("t_air_c: 30.0", "t_air_c: 1.0e+400"),
                  "t_air_c: expected a finite number, got inf"),
        "huge_int": (yaml.safe_dump({**doc, "burners": {"steps": [{"at_min": 0,
                                                                   "total": 10**400}]}}),
                     "burners.steps[0].total: must be at most 26"),
        "unknown_effect": (yaml.safe_dump({**doc, "effects": {"nope": {}}}),
                           "effects.nope: unknown effect"),
        "naive_start": (yaml.safe_dump({**doc, "start_time": "2026-03-02T06:00:00"}),
                        "start_time: give a UTC offset or Z"),
        "laughs_in_initial": (SCENARIO.replace("initial_c: 30.0", f"initial_c: {LAUGH_VALUE}"),
                              "initial_c: expected at most 3 entries"),
    })
    return cases


def _write(d: Path, name: str, content: str | bytes) -> Path:
    path = d / f"{name}.yaml"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    return path


def _check(main, argv: list[str], prog: str, path: Path, expected: str, capsys) -> None:
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == 2, (path.name, rc, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: {path}: "), (path.name, err)
    assert expected in lines[0], (path.name, err)


@pytest.fixture(autouse=True)
def never_evaluated():
    Path(PWNED).unlink(missing_ok=True)
    yield
    assert not Path(PWNED).exists(), "a YAML tag ran a command"


@pytest.mark.parametrize("name", sorted(config_cases()))
def test_hostile_daemon_config(tmp_path: Path, capsys, name: str) -> None:
    content, expected = config_cases()[name]
    path = _write(tmp_path, name, content)
    _check(daq_main, ["run", "--config", str(path), "--plc", "127.0.0.1:1", "--log-dir",
                      str(tmp_path / "logs"), "--duration", "0.2"],
           "furnace-daq run", path, expected, capsys)
    assert not (tmp_path / "logs").exists(), "the daemon started on a bad config"


@pytest.mark.parametrize("name", sorted(scenario_cases()))
def test_hostile_scenario(tmp_path: Path, capsys, name: str) -> None:
    content, expected = scenario_cases()[name]
    path = _write(tmp_path, name, content)
    out = tmp_path / "out.csv"
    _check(model_main, ["simulate", "--scenario", str(path), "--out", str(out)],
           "furnace-model simulate", path, expected, capsys)
    _check(daq_main, ["sim-plc", "--scenario", str(path), "--port", "0", "--duration", "0.2"],
           "furnace-daq sim-plc", path, expected, capsys)
    assert not out.exists()


def test_replay_config_is_checked_too(tmp_path: Path, capsys) -> None:
    content, expected = config_cases()["python_tag_in_value"]
    path = _write(tmp_path, "tagged", content)
    log = tmp_path / "x.mcap"
    log.write_bytes(b"")
    rc = daq_main(["replay", str(log), "--config", str(path)])
    err = capsys.readouterr().err
    assert rc != 0 and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_a_sampling_too_fine_for_memory_is_refused(tmp_path: Path, capsys) -> None:
    text = SCENARIO.replace("duration_min: 3310", "duration_min: 9000000").replace(
        "sample_min: 1.0 ", "sample_min: 0.001 ")
    path = _write(tmp_path, "fine", text)
    _check(model_main, ["simulate", "--scenario", str(path), "--out", str(tmp_path / "o.csv")],
           "furnace-model simulate", path, "sample_min: ", capsys)


@pytest.mark.parametrize("which", ["config", "scenario"])
def test_hostile_yaml_in_a_real_process(tmp_path: Path, which: str) -> None:
    """The entry point as systemd starts it: one line, exit 2, no traceback, bounded."""
    for name in ("deep_list", "python_tag"):
        content, expected = (config_cases() if which == "config" else scenario_cases())[name]
        path = _write(tmp_path, name, content)
        args = (["-m", "furnace_daq.cli", "run", "--config", str(path), "--log-dir",
                 str(tmp_path / "logs")] if which == "config" else
                ["-m", "furnace_model.cli", "simulate", "--scenario", str(path), "--out",
                 str(tmp_path / "o.csv")])
        proc = subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True,
                              timeout=120)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1 and expected in proc.stderr
