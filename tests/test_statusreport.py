"""The status reporter alone, with a journal on a string and the messages it writes kept in
a list: connection changes as status messages, the end of a told trouble always told, point
qualities told on change, and skipped ticks counted at once but reported once per interval."""

from __future__ import annotations

import io
from dataclasses import replace

from daq_processes import config

from furnace_daq.devicelink import Link
from furnace_daq.journal import Journal
from furnace_daq.registers import OK
from furnace_daq.sdnotify import Notifier
from furnace_daq.sources import ModbusSource, Sample
from furnace_daq.statusreport import Reporter
from furnace_model.log.messages import AnyMessage, DaqEvent, DaqEventKind, DaqStatus


class Setup:
    def __init__(self, **changes) -> None:
        cfg = replace(config(1), **changes)
        self.link = Link(cfg.devices[0], ModbusSource(cfg), named=False)
        self.stderr = io.StringIO()
        self.written: list[AnyMessage] = []
        self.reporter = Reporter(cfg, [self.link], Journal(60.0, self.stderr), Notifier({}),
                                 write=lambda m, _log, _pub: self.written.append(m),
                                 wall_ns=lambda: 1, log_error=lambda: None)

    def lines(self) -> list[str]:
        return self.stderr.getvalue().splitlines()


def test_a_connection_and_its_loss_are_status_messages_and_journal_lines():
    s = Setup()
    s.link.connects = 1
    s.reporter.connected(s.link, attempt=2)
    status = s.written[-1]
    assert isinstance(status, DaqStatus) and status.state == "connected"
    assert status.detail == "connected after 3 attempt(s)" and status.connects == 1
    s.reporter.lost(s.link, "2 failed polls in a row")
    assert s.reporter.state == "disconnected" and s.reporter.counters.disconnects == 1
    assert s.lines() == ["<5>PLC 127.0.0.1:1: connected after 3 attempt(s)",
                         "<3>PLC 127.0.0.1:1: connection lost: 2 failed polls in a row"]


def test_the_end_of_a_told_trouble_is_told_even_within_the_repeat_interval():
    s = Setup()
    s.reporter.bad_news(4, "a: broken", "a")
    s.reporter.good_news(5, "a: ok again", "a")
    for _ in range(3):  # repeats within the interval: held back, and so are their ends
        s.reporter.bad_news(4, "a: broken", "a")
        s.reporter.good_news(5, "a: ok again", "a")
    # the first end of an untold trouble is said once, rate-limited under a kind of its own
    assert s.lines() == ["<4>a: broken", "<5>a: ok again", "<5>a: ok again"]


def test_a_point_quality_is_told_when_it_changes_and_staleness_when_it_starts_and_ends():
    s = Setup()
    sample = Sample({"soak_1": 2000.0}, {"soak_1": "over_range"})
    s.reporter.tell_sample(s.link, sample)
    s.reporter.tell_sample(s.link, sample)
    s.reporter.tell_sample(s.link, Sample({"soak_1": 900.0}, {"soak_1": OK}))
    s.link.last_stale = True
    s.reporter.tell_sample(s.link, Sample())
    s.link.last_stale = False
    s.reporter.tell_sample(s.link, Sample())
    lines = s.lines()
    assert lines[0] == "<4>thermocouples.soak_1: over_range"
    assert lines[1] == "<5>thermocouples.soak_1: ok again"
    assert lines[2].startswith("<4>PLC 127.0.0.1:1: values stale, heartbeat unchanged")
    assert lines[3] == "<5>PLC 127.0.0.1:1: values moving again" and len(lines) == 4


def test_skipped_ticks_are_counted_at_once_and_reported_once_per_interval():
    s = Setup(status_interval_s=3600.0)
    s.reporter.missed(2)
    s.reporter.missed(3)
    events = [m for m in s.written if isinstance(m, DaqEvent)]
    assert s.reporter.counters.skipped_ticks == 5
    assert [(e.kind, e.to_json()["skipped"]) for e in events] == [(DaqEventKind.MISSED_TICK, 2)]


def test_a_failed_poll_and_a_tick_away_are_counted_by_kind():
    s = Setup()
    s.reporter.poll_failed(s.link, "no answer in 0.2 s", "poll timeout")
    s.link.down_kind = "connection refused"
    s.reporter.away(s.link)
    c = s.reporter.counters
    assert c.comm_errors == 1
    assert c.failures == {"poll timeout": 1, "connection refused": 1}
    assert s.lines() == ["<4>PLC 127.0.0.1:1: poll failed (poll timeout): no answer in 0.2 s"]
