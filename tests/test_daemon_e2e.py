"""End to end on loopback: `sim-plc` and `run` as separate processes, the MCAP file read back.

The test scenario has no sensor noise or bias, so every logged reading must equal the plant
recomputed at the PLC clock second the reading carries."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml
from daq_processes import ROOT, SCENARIO, start_simplc, stop

from furnace_model.log.read import read_messages
from furnace_model.log.schema import AMBIENT, BURNERS, DAQ_STATUS, THERMOCOUPLES
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

PERIOD, DURATION, SPEED = 0.05, 5.0, 600.0


def daemon_config(tmp_path: Path, **changes) -> Path:
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["poll_period_s"] = PERIOD
    doc["plc"]["timeout_s"] = 0.5
    doc["refit"]["enabled"] = False  # polling and logging only: no refit worker
    doc.update(changes)
    path = tmp_path / "daq.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


LAUNCH = ("import sys, furnace_daq.cli.run; from furnace_daq.cli import main; "
          "print('imported', flush=True); port = input(); "
          "sys.exit(main([*sys.argv[1:], '--plc', f'127.0.0.1:{port}']))")
"""`furnace-daq run` with its modules imported before it is told the PLC's port: the plant's
burner steps come 1.5-2 s apart at 600x, and a busy host takes longer than that to import
numpy and pandas."""


def test_sim_plc_to_mcap(tmp_path):
    daq = subprocess.Popen([sys.executable, "-c", LAUNCH, "run", "--config",
                            str(daemon_config(tmp_path)), "--log-dir", str(tmp_path / "logs"),
                            "--duration", str(DURATION)], cwd=ROOT, stdin=subprocess.PIPE,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    sim = None
    try:
        assert daq.stdout.readline() == "imported\n", daq.stderr.read()
        sim, port = start_simplc("--speed", str(SPEED))
        out, err = daq.communicate(f"{port}\n", timeout=60)
        assert daq.returncode == 0, err
    finally:
        stop(daq)
        if sim is not None:
            assert stop(sim) == 0
    files = sorted((tmp_path / "logs").glob("*.mcap*"))  # not the directory lock
    assert [f.suffix for f in files] == [".mcap"], files  # finished, with a footer
    msgs = list(read_messages(files))
    by_topic: dict[str, list] = {}
    for topic, m, log_ns, pub_ns in msgs:
        by_topic.setdefault(topic, []).append((m, log_ns, pub_ns))
    assert {THERMOCOUPLES, BURNERS, AMBIENT, DAQ_STATUS} <= set(by_topic)

    # Every tick of the run is either polled and logged, or skipped because the host or the
    # poll was late, and then counted on the final line: on a busy host the split between
    # the two varies, their sum does not. It spans every tick from the first poll to the
    # last (the first tick waits for the connection), and a last poll that ran late also
    # counts the ticks it overran past the end.
    tc = by_topic[THERMOCOUPLES]
    expected = DURATION / PERIOD
    skipped = int(re.search(r"(\d+) skipped ticks", err).group(1))
    logs = np.array([t for _, t, _ in tc], dtype=np.int64)
    spanned = (logs[-1] - logs[0]) / 1e9 / PERIOD + 1
    assert spanned - 1 <= len(tc) + skipped <= 1.1 * expected, (len(tc), skipped, spanned, err)
    ok_polls, polls = map(int, re.search(r"(\d+)/(\d+) polls ok", err).groups())
    assert len(tc) == ok_polls == polls, err  # every poll made was answered and logged
    assert len(by_topic[BURNERS]) == len(by_topic[AMBIENT]) == len(tc)

    # values: the plant at each reading's PLC second, rounded like the INT16 0.1 degC register
    scenario = load_scenario(SCENARIO)
    seconds = np.array([m["plc_seconds"] for m, _, _ in tc])
    assert np.all(np.diff(seconds) >= 0) and seconds[-1] - seconds[0] > 0.5 * DURATION * SPEED
    run = Plant.from_scenario(scenario).run(scenario.inputs(), seconds / 60.0, scenario.initial_c)
    logged = np.array([[m[s] for s in PAPER.sensors] for m, _, _ in tc], dtype=float)
    want = np.round(run.tc * 10) / 10
    assert np.max(np.abs(logged - want)) <= 0.1 + 1e-9
    assert np.mean(np.isclose(logged, want, atol=1e-6)) > 0.99
    assert all(q == "ok" for m, _, _ in tc for q in m["quality"].values())
    assert {m["t_air"] for m, _, _ in by_topic[AMBIENT]} == {scenario.t_air_c}

    # The burner bits are a second request after the registers that carry the clock, and a
    # PLC scan may fall between the two: each reading is the schedule at some second from its
    # clock's to the next reading's.
    counts = np.array([[m[f"count_{z}"] for z in PAPER.zones] for m, _, _ in by_topic[BURNERS]])
    ends = np.append(seconds[1:], seconds[-1] + SPEED * 1.0)
    for i, (got, start, end) in enumerate(zip(counts, seconds, ends, strict=True)):
        between = [scenario.burners_at(s / 60.0) for s in np.arange(start, end + 1)]
        assert any(np.array_equal(got, b) for b in between), (i, start, end, got)
    assert np.mean([np.array_equal(c, scenario.burners_at(s / 60.0))
                    for c, s in zip(counts, seconds, strict=True)]) > 0.9
    # half the run's PLC time (checked above) spans more than the 15-20 min between steps
    assert len({tuple(c) for c in counts}) >= 2, "the run crosses a burner step"

    # time base: publish_time follows the PLC clock, log_time the host
    pubs = np.array([p for _, _, p in tc], dtype=np.int64)
    np.testing.assert_array_equal(pubs - pubs[0], ((seconds - seconds[0]) * 1e9).astype(np.int64))
    assert (logs[-1] - logs[0]) / 1e9 < DURATION + 1

    states = [(m["state"], m["detail"]) for m, _, _ in by_topic[DAQ_STATUS]]
    assert states[0][0] == "disconnected" and states[1][0] == "connected"
    assert states[-1] == ("disconnected", "stopping")
    assert by_topic[DAQ_STATUS][-1][0]["ok_polls"] == len(tc)
