"""`furnace-daq check`: every configured point read once from a real (simulated) PLC and
reported by its key path, exit 0 only when all are ok; a map with wrong addresses, a
sentinel or an implausible value, and a PLC that is not there, each name what failed."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import uuid
from pathlib import Path

import yaml
from daq_processes import ROOT, config, free_port, sim, start_simplc, stop

from furnace_daq.check import check, format_report
from furnace_daq.simplc import SimPLC
from furnace_model.simulation.scenario import load_scenario

KEYS = ["thermocouples.soak_1", "thermocouples.soak_2", "thermocouples.heat_1",
        "thermocouples.heat_2", "thermocouples.preheat_1", "thermocouples.preheat_2", "ambient",
        "clock", "heartbeat", "burners.modbus.soak", "burners.modbus.heat",
        "burners.modbus.preheat"]


def gateway_config(tmp_path: Path, **changes) -> Path:
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["plc"]["timeout_s"] = 0.5
    doc.update(changes)
    path = tmp_path / "daq.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def run_check(cfg: Path, port: int) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "furnace_daq.cli", "check", "--config",
                           str(cfg), "--plc", f"127.0.0.1:{port}"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)


def rows(stdout: str) -> dict[str, list[str]]:
    """key path -> the row's other columns, split on runs of spaces."""
    out = {}
    for line in stdout.splitlines():
        first = line.split(" ", 1)[0]
        if first in KEYS or first.startswith("burners.can."):
            out[first] = line.split()[1:]
    return out


def test_check_against_the_simulated_plc_is_all_ok(tmp_path):
    proc, port = start_simplc("--speed", "60")
    try:
        r = run_check(gateway_config(tmp_path), port)
    finally:
        assert stop(proc) == 0
    assert r.returncode == 0, r.stdout + r.stderr
    got = rows(r.stdout)
    assert list(got) == KEYS, r.stdout
    assert all("ok" in cols for cols in got.values()), r.stdout
    # the soaking zone's first thermocouple: one register, raw tenths of a degree and degC
    raw, value = got["thermocouples.soak_1"][2:4]
    assert abs(int(raw) / 10 - float(value)) < 1e-9 and 0 < float(value) < 1600
    assert got["burners.modbus.soak"][2:4] == ["1100000000", "2"]  # 2 of 10 on at the start
    assert r.stdout.rstrip().splitlines()[-1].startswith("all 12 points ok")
    assert r.stderr == ""


def test_check_names_the_keys_of_a_wrong_map_and_fails(tmp_path):
    """heat_1/heat_2 point at input registers the PLC does not have (it answers exception
    2), preheat_1 at the ambient register with a range it is outside of, preheat_2 at the
    clock's high word, which is 0 for the first 18 hours, declared a sentinel."""
    tc = {s: {"table": "input", "address": i, "type": "int16", "scale": 0.1,
              "sentinels": [32767], "range": [-50, 1600]}
          for i, s in enumerate(["soak_1", "soak_2", "heat_1", "heat_2", "preheat_1",
                                 "preheat_2"])}
    tc["heat_1"]["address"], tc["heat_2"]["address"] = 200, 201
    tc["preheat_1"].update(address=6, range=[100, 1600])
    tc["preheat_2"].update(address=7, sentinels=[0])
    cfg = gateway_config(tmp_path, thermocouples=tc)
    doc = yaml.safe_load(cfg.read_text())
    for key in ("ambient", "clock"):  # their registers now belong to the thermocouples
        doc.pop(key)
    cfg.write_text(yaml.safe_dump(doc))
    proc, port = start_simplc("--speed", "60")
    try:
        r = run_check(cfg, port)
    finally:
        assert stop(proc) == 0
    assert r.returncode == 1, r.stdout + r.stderr
    got = rows(r.stdout)
    for key in ("thermocouples.heat_1", "thermocouples.heat_2"):
        assert "comm_error" in got[key], r.stdout
        assert "block refused: Modbus exception code 2 (illegal data address)" in \
            " ".join(got[key])
    assert "out_of_range" in got["thermocouples.preheat_1"]
    assert "sensor_open" in got["thermocouples.preheat_2"]
    for key in ("thermocouples.soak_1", "thermocouples.soak_2", "heartbeat"):
        assert "ok" in got[key], (key, r.stdout)
    # one line on stderr, naming every failing key and why
    (line,) = r.stderr.strip().splitlines()
    assert line.startswith("<3>furnace-daq check: error: 4 of ")
    for key in ("thermocouples.heat_1", "thermocouples.heat_2", "thermocouples.preheat_1",
                "thermocouples.preheat_2"):
        assert key in line, line
    assert "thermocouples.soak_1" not in line and "Traceback" not in r.stderr


def test_check_of_an_unreachable_plc_fails_at_once_naming_the_reason(tmp_path):
    r = run_check(gateway_config(tmp_path), free_port())  # nothing listens there
    assert r.returncode == 1, r.stdout + r.stderr
    assert "Connection refused" in r.stdout.splitlines()[0]
    got = rows(r.stdout)
    assert list(got) == KEYS and all("comm_error" in cols for cols in got.values())
    (line,) = r.stderr.strip().splitlines()
    assert "12 of 12 points failed" in line and "Connection refused" in line


def test_check_reads_the_flame_scanners_on_can_too():
    """With `burners.source: both` the CAN bus is listened to as well: a row per zone, from
    the frames the simulated PLC broadcasts, and the same burner counts as over Modbus."""
    channel = f"furnace-{uuid.uuid4().hex}"

    async def scenario():
        plc = SimPLC(load_scenario(ROOT / "tests" / "data" / "daq_steps.yaml"), speed=60,
                     port=0, scan_s=0.05, can_channel=channel)
        await plc.start()
        try:
            cfg = config(plc.port, burners={
                "source": "both", "modbus": {z: {"address": a} for z, a in
                                             (("soak", 0), ("heat", 10), ("preheat", 18))},
                "can": {"interface": "virtual", "channel": channel, "timeout_s": 2.0}})
            return await check(cfg)
        finally:
            await plc.stop()

    report = asyncio.run(scenario())
    assert report.ok, format_report(report)
    by_key = {p.key: p for p in report.points}
    for zone in ("soak", "heat", "preheat"):
        assert by_key[f"burners.can.{zone}"].value == by_key[f"burners.modbus.{zone}"].value
    assert by_key["burners.can.soak"].raw  # the payload, as it came


def test_check_of_a_can_bus_that_stays_silent_fails_within_its_timeout():
    async def scenario():
        plc = await sim(0)
        try:
            cfg = config(plc.port, burners={
                "source": "can", "can": {"interface": "virtual",
                                         "channel": f"silent-{uuid.uuid4().hex}",
                                         "timeout_s": 0.3}})
            return await check(cfg)
        finally:
            await plc.stop()

    report = asyncio.run(scenario())
    assert not report.ok
    assert [p.key for p in report.failed] == [f"burners.can.{z}" for z in ("soak", "heat",
                                                                          "preheat")]
    assert all(p.error == "no frame within 0.3 s" for p in report.failed)
