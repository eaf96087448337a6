"""Host clock steps, forwards and backwards, mid-run. The host clock cannot be set here, so
the daemon's wall clock is injected and stepped; the poll schedule (monotonic) must not
notice, the log must stay in acquisition order, and each step is a clock_step event."""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest
from daq_processes import config, sim, start_daemon

from furnace_daq.logclock import LogClock
from furnace_model.log.read import read_messages
from furnace_model.log.schema import DAQ_EVENTS, THERMOCOUPLES

PERIOD, SPEED, DURATION = 0.05, 600, 2.4
HOUR = 3600 * 10**9


class SteppedClock:
    """time.time_ns plus an offset the test changes."""

    def __init__(self) -> None:
        self.offset_ns = 0

    def __call__(self) -> int:
        return time.time_ns() + self.offset_ns


def test_steps_forward_and_back_keep_schedule_and_order(tmp_path):
    wall = SteppedClock()

    async def scenario():
        plc = await sim(0)
        daemon, task = start_daemon(config(plc.port), tmp_path, DURATION, wall_ns=wall)
        await asyncio.sleep(0.7)
        wall.offset_ns = HOUR                      # forward one hour
        await asyncio.sleep(0.7)
        wall.offset_ns = -5 * 10**9                # back 1 h 5 s: 5 s behind where it started
        counters = await task
        await plc.stop()
        return counters

    counters = asyncio.run(scenario())
    # the schedule keeps to its grid: every tick polled, or skipped and counted (a busy host
    # skips some; a schedule on the stepped clock would lose or add an hour of them)
    expected = DURATION / PERIOD
    assert abs(counters.polls + counters.skipped_ticks - expected) <= 0.1 * expected, counters

    files = sorted(tmp_path.glob("*.mcap"))
    tc = [(m, lt, pub) for t, m, lt, pub in read_messages(files, [THERMOCOUPLES])]
    # merged in log-time order, the samples are still in acquisition (PLC clock) order
    seconds = np.array([m["plc_seconds"] for m, _, _ in tc])
    assert np.all(np.diff(seconds) >= 0), seconds
    # and ticked on the period: 30 PLC seconds per 50 ms poll at 600x (give or take a PLC
    # scan); a busy host may starve the simulated PLC's scan now and then, which shows as one
    # long step between two polls, never as many
    steps = np.diff(seconds)
    assert np.mean(steps >= 3 * PERIOD * SPEED) < 0.05, steps
    assert 0.9 < np.median(steps) / (PERIOD * SPEED) < 1.1, steps
    # publish time is the PLC clock: untouched by the host's steps
    pubs = np.array([p for _, _, p in tc], dtype=np.int64)
    np.testing.assert_array_equal(pubs - pubs[0], ((seconds - seconds[0]) * 1e9).astype(np.int64))

    lts = np.array([lt for _, lt, _ in tc], dtype=np.int64)
    gaps = np.diff(lts) / 1e9
    jump = int(np.argmax(gaps))
    assert 3599 < gaps[jump] < 3601, "log time follows the step forward"

    events = [(m, lt) for t, m, lt, _ in read_messages(files, [DAQ_EVENTS])
              if m["kind"] == "clock_step"]
    assert [round(m["step_s"]) for m, _ in events] == [3600, -3605], events
    assert "forward" in events[0][0]["detail"] and "catches up" in events[1][0]["detail"]
    # after the step back (logged with the poll that saw it): log time runs at half the
    # speed of real time, here the PLC clock's, so it never goes back; taken over all those
    # polls, whatever ticks a busy host skipped between them
    after = lts >= events[1][1]
    assert np.all(np.diff(lts[after]) > 0)
    log_s = (lts[after][-1] - lts[after][0]) / 1e9
    plc_s = (seconds[after][-1] - seconds[after][0]) / SPEED
    assert 0.3 < log_s / plc_s < 0.7, (log_s, plc_s)


class FakeClocks:
    def __init__(self) -> None:
        self.wall, self.mono = 1_000 * 10**9, 0

    def advance(self, seconds: float, wall_step_s: float = 0.0) -> None:
        self.mono += int(seconds * 1e9)
        self.wall += int((seconds + wall_step_s) * 1e9)


def test_log_clock_absorbs_a_step_back_then_meets_the_host_clock():
    c = FakeClocks()
    clock = LogClock(lambda: c.wall, monotonic_ns=lambda: c.mono)
    t0 = clock()
    c.advance(1.0, wall_step_s=-10.0)              # host clock back 10 s
    out, host = [clock()], [c.wall]
    assert out[0] == t0 + 5 * 10**8 and clock.take_step() == -10 * 10**9  # half speed
    for _ in range(25):
        c.advance(1.0)
        out.append(clock())
        host.append(c.wall)
    assert np.all(np.diff(out) > 0)
    # 10 s absorbed at half speed in 20 s, then exactly the host clock again
    ahead = np.array(out) - np.array(host)
    assert np.all(ahead[:19] > 0) and np.all(ahead[19:] == 0), ahead
    assert clock.take_step() is None


@pytest.mark.parametrize("step_s", [-2 * 86400.0, 30.0])
def test_log_clock_follows_a_step_forward_and_a_huge_step_back(step_s):
    c = FakeClocks()
    clock = LogClock(lambda: c.wall, monotonic_ns=lambda: c.mono)
    clock()
    c.advance(0.5, wall_step_s=step_s)
    assert clock() == c.wall and clock.take_step() == int(step_s * 1e9)


def test_log_clock_ignores_jitter_below_the_step_threshold():
    c = FakeClocks()
    clock = LogClock(lambda: c.wall, monotonic_ns=lambda: c.mono)
    clock()
    c.advance(1.0, wall_step_s=0.2)
    clock()
    c.advance(1.0, wall_step_s=-0.1)
    assert clock() == c.wall  # absorbed within one call: small corrections leave no trace
    assert clock.take_step() is None
