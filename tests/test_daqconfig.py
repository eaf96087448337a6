"""The daemon's config: the shipped example loads, and each kind of mistake stops `run` with
exit code 2 and the key path, never a traceback."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from furnace_daq.daqconfig import DaqConfig, RefitConfig, load_config, parse_config
from furnace_daq.registers import ReadRequest, plan_reads
from furnace_model.config import Node
from furnace_model.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
GATEWAY = ROOT / "config" / "gateway.yaml"


def gateway() -> dict:
    return yaml.safe_load(GATEWAY.read_text())


def parse(doc: dict) -> DaqConfig:
    return parse_config(Node(doc, "daq.yaml"))


def write(tmp_path: Path, doc: dict) -> Path:
    path = tmp_path / "daq.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_example_is_the_default_map_in_two_requests():
    cfg = load_config(GATEWAY)
    assert [p.address for p in cfg.thermocouples] == [0, 1, 2, 3, 4, 5]
    assert cfg.thermocouples[3].scale == 0.1 and cfg.thermocouples[3].sentinels == (32767,)
    assert (cfg.clock.point.address, cfg.clock.point.dtype) == (7, "uint32")
    assert plan_reads(cfg.modbus_items()) == [ReadRequest("input", 0, 10),
                                              ReadRequest("discrete", 0, 26)]


@pytest.mark.parametrize("mutate, path, words", [
    (lambda d: d["plc"].update(hots="x"), "plc.hots", "unknown key"),
    (lambda d: d["thermocouples"]["heat_2"].update(scale="ten"), "thermocouples.heat_2.scale",
     "expected a number"),
    (lambda d: d["thermocouples"]["heat_2"].update(type="int128"), "thermocouples.heat_2.type",
     "must be one of"),
    (lambda d: d["thermocouples"]["preheat_1"].update(address=3), "thermocouples.preheat_1",
     "overlaps thermocouples.heat_2"),
    (lambda d: d["clock"].update(address=5), "clock", "overlaps thermocouples.preheat_2"),
    (lambda d: d["burners"]["modbus"]["heat"].update(address=5), "burners.modbus.heat",
     "overlaps burners.modbus.soak"),
    (lambda d: d["burners"]["can"]["soak"].update(id=0x900), "burners.can.soak.id",
     "at most 2047"),
    (lambda d: d["thermocouples"].pop("soak_2"), "thermocouples.soak_2", "required key"),
    (lambda d: d["ambient"].update(range=[10, 5]), "ambient.range", "low < high"),
    (lambda d: d.update(poll_period_s=0), "poll_period_s", "at least"),
])
def test_mistakes_name_the_key_path(tmp_path, mutate, path, words):
    doc = gateway()
    mutate(doc)
    with pytest.raises(ConfigError) as err:
        load_config(write(tmp_path, doc))
    assert err.value.path == path and words in str(err.value)


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "furnace_daq.cli", "run", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)


def test_cli_bad_configs_exit_2_with_one_line(tmp_path):
    unknown = gateway()
    unknown["plc"]["prot"] = 502
    wrong = gateway()
    wrong["thermocouples"]["soak_1"]["address"] = "zero"
    overlap = gateway()
    overlap["heartbeat"]["address"] = 8
    knob = gateway()
    knob["refit"].update(method="polish", generations=500)  # the polish has no generations
    cases = []
    for name, doc, words in [("a", unknown, "plc.prot: unknown key"),
                             ("b", wrong, "thermocouples.soak_1.address: expected a whole number"),
                             ("c", overlap, "heartbeat: overlaps clock"),
                             ("d", knob, "refit.generations: applies to methods ga_polish and ga only")]:
        (tmp_path / name).mkdir()
        cases.append((write(tmp_path / name, doc), words))
    cases.append((tmp_path / "missing.yaml", "file not found"))
    for path, words in cases:
        out = run_cli("--config", str(path), "--duration", "1", "--log-dir", str(tmp_path))
        assert out.returncode == 2, out.stderr
        assert words in out.stderr and str(path) in out.stderr
        assert "Traceback" not in out.stderr and len(out.stderr.strip().splitlines()) == 1
    out = run_cli("--config", str(GATEWAY), "--plc", "nohost", "--log-dir", str(tmp_path))
    assert out.returncode == 2 and "HOST:PORT" in out.stderr


def test_refit_method_and_its_ga_knobs():
    doc = gateway()
    assert load_config(GATEWAY).refit.method == "ga_polish"
    del doc["refit"]["method"]
    refit = parse(doc).refit
    assert refit.method == "ga_polish" and refit.ga_size() == (16, 30)  # the default
    doc["refit"].update(method="ga", population=12, generations=300)
    refit = parse(doc).refit
    assert (refit.method, refit.population, refit.generations) == ("ga", 12, 300)
    assert refit.ga_size() == (12, 300)
    doc["refit"].update(method="ga_polish", population=8, generations=5)
    assert parse(doc).refit.ga_size() == (8, 5)
    del doc["refit"]["population"], doc["refit"]["generations"]
    assert parse({**doc, "refit": {**doc["refit"], "method": "ga"}}).refit.ga_size() \
        == (20, 2000)  # the paper's


def test_ga_polish_generations_follow_the_budget_not_the_host():
    """Fixed by the settings alone (a replay elsewhere repeats them): fewer for a small
    budget or a long window, none when even one does not fit, never more than the cap."""
    base = RefitConfig(window_s=86400, step_s=60)
    assert base.ga_size() == (16, 30)
    small = replace(base, budget_s=0.3).ga_size()[1]
    assert 0 < small < 30 and replace(base, budget_s=0.3).ga_size() == (16, small)
    assert replace(base, budget_s=0.3, step_s=1).ga_size() == (16, 0)
    assert replace(base, budget_s=0.45).ga_size()[1] in (3 * small // 2, 3 * small // 2 + 1)
    assert replace(base, method="ga").ga_size() == (20, 2000)


@pytest.mark.parametrize("changes, path, words", [
    ({"method": "GA"}, "refit.method", "must be one of"),
    ({"method": "ga", "population": 2}, "refit.population", "at least 4"),
    ({"method": "ga", "generations": 0}, "refit.generations", "at least 1"),
    ({"method": "ga", "generations": 1.5}, "refit.generations", "expected a whole number"),
    ({"method": "polish", "population": 40}, "refit.population",
     "applies to methods ga_polish and ga only (method is polish)"),
    ({"method": "polish", "generations": 100}, "refit.generations", "applies to methods"),
    ({"method": "ga+polish"}, "refit.method", "must be one of ga_polish, ga, polish"),
    ({"method": "fast"}, "refit.method", "got 'fast'"),
    ({"method": 3}, "refit.method", "expected text"),
    ({"method": "ga_polish", "population": 3}, "refit.population", "at least 4"),
])
def test_refit_method_mistakes_name_the_key_path(changes, path, words):
    doc = gateway()
    doc["refit"].update(changes)
    with pytest.raises(ConfigError) as err:
        parse(doc)
    assert err.value.path == path and words in str(err.value), str(err.value)
