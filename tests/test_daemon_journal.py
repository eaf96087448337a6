"""What the daemon tells the journal: stderr lines with sd-daemon priority prefixes, each kind
at most once per `stderr_interval_s` with a count of the repeats, and a last line that counts
the failed polls by kind, so `journalctl -p err` says why there is no data."""

from __future__ import annotations

import asyncio
import io
import re
import subprocess
import sys

import yaml
from daq_processes import ROOT, config, free_port, sim, start_daemon, until

from furnace_daq.daemon import Counters, summary
from furnace_daq.journal import ERR, INFO, WARNING, Journal
from furnace_model.log.read import read_messages
from furnace_model.log.schema import DAQ_STATUS


def test_journal_rate_limits_each_kind_and_counts_what_it_held_back():
    now = [0.0]
    out = io.StringIO()
    journal = Journal(repeat_s=10.0, stream=out, clock=lambda: now[0])
    for t in range(25):  # one failure a second, for 25 s
        now[0] = float(t)
        journal.say(ERR, "cannot connect: Connection refused", "dial:refused")
    journal.say(WARNING, "poll failed", "poll:timeout")  # another kind is not held back
    journal.say(INFO, "two\nlines")                      # no kind: never held back
    now[0] = 27.0
    journal.flush()                                       # at stop: what is still held
    now[0] = 40.0
    journal.say(ERR, "cannot connect: No route to host", "dial:refused")
    now[0] = 41.0
    journal.say(ERR, "cannot connect: Connection refused", "dial:refused")
    now[0] = 49.0
    journal.pump()                                        # not a whole interval yet
    now[0] = 50.0
    journal.pump()                                        # held for 10 s: said, counted
    assert out.getvalue().splitlines() == [
        "<3>cannot connect: Connection refused",
        "<3>cannot connect: Connection refused [9 more like this in the last 10 s]",
        "<3>cannot connect: Connection refused [9 more like this in the last 10 s]",
        "<4>poll failed",
        "<6>two lines",
        "<3>cannot connect: Connection refused [4 more like this in the last 7 s]",
        "<3>cannot connect: No route to host",
        "<3>cannot connect: Connection refused [1 more like this in the last 10 s]",
    ]


def test_the_final_line_counts_failures_by_kind_and_carries_a_priority():
    c = Counters(polls=26, failures={"connection refused": 26})
    assert summary(c) == (ERR, "stopped: 0/26 polls ok, 0 errors, 0 skipped ticks, 0 drops; "
                               "26 failed: 26 connection refused")
    c = Counters(polls=30, ok_polls=20, comm_errors=4, disconnects=1,
                 failures={"poll timeout": 4, "connection refused": 6})
    assert summary(c) == (WARNING, "stopped: 20/30 polls ok, 4 errors, 0 skipped ticks, "
                                   "1 drops; 10 failed: 6 connection refused, 4 poll timeout")
    assert summary(Counters(polls=5, ok_polls=5))[0] == INFO


def test_daemon_against_an_unreachable_plc_says_why_rate_limited(tmp_path):
    """Nothing listens on the port: the journal gets `<3>` lines naming the refusal, at most
    one per second (stderr_interval_s) although it redials every 0.1 s, the repeats counted,
    and the last line counts every poll as failed by connection refused."""
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["poll_period_s"] = 0.1
    doc["stderr_interval_s"] = 1.0
    doc["plc"]["reconnect"] = {"retry_s": 0.1, "initial_s": 0.1, "max_s": 0.4}
    cfg = tmp_path / "daq.yaml"
    cfg.write_text(yaml.safe_dump(doc))
    r = subprocess.run([sys.executable, "-m", "furnace_daq.cli", "run", "--config", str(cfg),
                        "--plc", f"127.0.0.1:{free_port()}", "--log-dir", str(tmp_path / "logs"),
                        "--no-refit", "--duration", "3"], cwd=ROOT, capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.strip().splitlines()
    assert all(re.match(r"<[3-6]>", line) for line in lines), lines
    refused = [line for line in lines if line.startswith("<3>PLC: cannot connect")]
    assert refused and all("Connection refused" in line for line in refused), lines
    # dialled ~30 times in 3 s, said at most once a second (plus the flush at stop); every
    # refused dial said or counted in a line's repeats (the last dial may be cut by the stop)
    assert 2 <= len(refused) <= 5, lines
    held = [int(m.group(1)) for line in refused
            if (m := re.search(r"\[(\d+) more like this", line))]
    status = [m for t, m, _, _ in read_messages(sorted((tmp_path / "logs").glob("*.mcap")))
              if t == DAQ_STATUS]
    assert held and sum(held) + len(refused) >= status[-1]["connect_attempts"] - 1, lines
    last = lines[-1]
    m = re.fullmatch(r"<3>stopped: 0/(\d+) polls ok, 0 errors, (\d+) skipped ticks, 0 drops; "
                     r"(\d+) failed: (\d+) connection refused", last)
    # every poll failed by the refusal; every tick of the run polled or (a busy host) skipped
    assert m and m.group(1) == m.group(3) == m.group(4), last
    assert int(m.group(1)) + int(m.group(2)) >= 10, last


def test_connection_changes_and_a_refused_block_reach_the_journal(tmp_path, capsys):
    """A PLC that goes away and comes back: `<3>` when the connection is lost, `<5>` when it
    is back; a map naming registers the PLC refuses: one `<3>` line naming the keys."""
    tc_map = {s: {"table": "input", "address": i, "type": "int16", "scale": 0.1}
              for i, s in enumerate(["soak_1", "soak_2", "heat_1", "heat_2", "preheat_1",
                                     "preheat_2"])}
    tc_map["heat_2"]["address"] = 100

    async def scenario():
        port = free_port()
        plc = await sim(port)
        daemon, task = start_daemon(config(port, thermocouples=tc_map, stderr_interval_s=30),
                                    tmp_path, None)
        c = daemon.counters
        await until(lambda: c.ok_polls >= 10)
        await plc.stop()
        await asyncio.sleep(0.5)
        plc = await sim(port)
        polled = c.ok_polls
        await until(lambda: c.connects >= 2 and c.ok_polls >= polled + 5)
        daemon.stop()
        counters = await task
        await plc.stop()
        return counters

    counters = asyncio.run(scenario())
    err = capsys.readouterr().err.splitlines()
    assert counters.disconnects == 1 and counters.connects == 2
    lost = [line for line in err if line.startswith("<3>PLC 127.0.0.1:") and "lost" in line]
    back = [line for line in err if line.startswith("<5>PLC 127.0.0.1:") and "connected" in line]
    assert len(lost) == 1 and len(back) == 2, err  # start, and again after the outage
    assert "after it went away" in back[1] and "more like this" not in back[1]
    assert err.index(lost[0]) < err.index(back[1])
    # every poll: said once, and the repeats counted once at stop (30 s not yet over)
    refused = [line for line in err if "refused with Modbus exception code 2" in line]
    assert len(refused) == 2 and "more like this" in refused[1], err
    assert refused[0].startswith("<3>") and "thermocouples.heat_2" in refused[0]
    assert "thermocouples.heat_1" not in refused[0] and "more like this" not in refused[0]
    assert sum(counters.incomplete.values()) == counters.ok_polls
    assert counters.failures and sum(counters.failures.values()) == \
        counters.polls - counters.ok_polls
    assert any(line.startswith("<3>PLC: cannot connect") for line in err), err
