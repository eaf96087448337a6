"""A device link alone: its redial schedule, its read budget, and its dialling against a port
nobody listens on (a real ModbusSource on 127.0.0.1), with no daemon, log or journal."""

from __future__ import annotations

import asyncio
from dataclasses import replace

from daq_processes import config, free_port

from furnace_daq.deviceconfig import Backoff, Workarounds
from furnace_daq.devicelink import Link
from furnace_daq.sources import ModbusSource, SourceError

BACKOFF = Backoff(initial_s=0.5, max_s=4.0, factor=2.0, retry_s=0.25, fast_for_s=60.0)


def link(**device_changes) -> Link:
    cfg = config(free_port())
    device = replace(cfg.devices[0], **{"reconnect": BACKOFF, **device_changes})
    return Link(device, ModbusSource(cfg, device=device), named=False)


def test_a_refused_dial_is_retried_start_to_start_at_the_fixed_interval_while_the_outage_is_young():
    ln = link()
    ln.outage_since = 100.0
    wait, how = ln.retry_after("connection refused", started=110.0, now=110.1)
    assert abs(wait - 0.15) < 1e-9 and how == "every 0.25 s"
    assert ln.down_kind == "connection refused" and ln.slow_steps == 0
    wait, _ = ln.retry_after("connect timeout", started=111.0, now=111.4)  # the dial took longer
    assert wait == 0.0


def test_an_old_outage_or_another_failure_backs_off_exponentially_up_to_the_cap():
    ln = link()
    ln.outage_since = 0.0
    waits = [ln.retry_after("connection refused", started=t, now=t)[0] for t in (60.0, 61.0,
                                                                                 62.0, 63.0, 64.0)]
    assert waits == [0.5, 1.0, 2.0, 4.0, 4.0]
    young = link()
    young.outage_since = 10.0
    wait, how = young.retry_after("connection reset", started=11.0, now=11.0)
    assert wait == 0.5 and how == "in 0.5 s (backing off up to 4 s)"


def test_a_connection_lost_before_one_good_poll_is_a_hangup_and_after_one_an_outage():
    ln = link()
    ln.dials_since_ok = 1
    ln.connected.set()
    ln.need_dial.clear()
    ln.lose("connection lost")
    assert ln.hangups == 1 and ln.need_dial.is_set() and not ln.connected.is_set()
    ln.polled()
    assert (ln.hangups, ln.dials_since_ok, ln.slow_steps) == (0, 0, 0)
    before = ln.outage_since
    ln.lose("poll timeout")
    assert ln.hangups == 0 and ln.outage_since > before and ln.down_kind == "poll timeout"


def test_the_read_budget_adds_what_the_workarounds_ask_for():
    plain = link(timeout_s=0.5)
    assert plain.read_budget_s == 0.5
    n = len(plain.source.requests)
    slow = link(timeout_s=0.5, workarounds=Workarounds(pause_between_requests_s=0.1,
                                                       close_connection_after_gather=True,
                                                       pause_after_connect_s=0.2))
    assert abs(slow.read_budget_s - (0.5 + 0.1 * (n - 1) + 0.5 + 0.2)) < 1e-9


def test_failed_polls_drop_the_connection_after_the_configured_run():
    ln = link(max_consecutive_errors=2)
    ln.poll_failed()
    assert not ln.failing
    ln.poll_failed()
    assert ln.failing


def test_dialling_a_closed_port_fails_on_the_fast_schedule_until_stopped():
    ln = link(timeout_s=0.2, reconnect=replace(BACKOFF, retry_s=0.05))
    dials: list[None] = []
    failures: list[tuple[str, int, float]] = []

    def failed(_link: Link, exc: SourceError, attempt: int, wait: float, _how: str) -> None:
        failures.append((exc.kind, attempt, wait))

    async def run() -> None:
        stop = asyncio.Event()
        task = asyncio.create_task(ln.keep_dialled(
            stop, on_dial=lambda: dials.append(None), on_failure=failed,
            on_connected=lambda *_: None))
        await asyncio.sleep(0.3)
        stop.set()
        await asyncio.wait_for(task, 1.0)
        await ln.source.close()

    asyncio.run(run())
    assert len(failures) >= 2 and len(dials) == len(failures)
    assert [a for _, a, _ in failures] == list(range(len(failures)))
    assert all(kind == "connection refused" and wait <= 0.05 for kind, _, wait in failures)
    assert not ln.connected.is_set() and ln.slow_steps == 0
