"""The PLC's clock as publish time, on plain numbers: anchored at the first reading or at
the config's epoch, and re-anchored with an event only when no epoch is given."""

from __future__ import annotations

from furnace_daq.plcclock import PlcClock
from furnace_model.log.messages import DaqEventKind

S = 1_000_000_000


def test_the_first_reading_anchors_the_epoch_and_later_ones_follow_the_plc():
    clock = PlcClock()
    assert clock.publish_ns(None, 5 * S) == (5 * S, None) and not clock.seen
    assert clock.publish_ns(10.0, 100 * S) == (100 * S, None) and clock.seen
    assert clock.publish_ns(12.5, 101 * S) == (102 * S + S // 2, None)  # the PLC's time, not the host's


def test_a_plc_clock_going_back_re_anchors_with_an_event():
    clock = PlcClock()
    clock.publish_ns(10.0, 100 * S)
    pub, reset = clock.publish_ns(2.0, 110 * S)
    assert pub == 110 * S
    assert reset is not None and reset.kind == DaqEventKind.PLC_CLOCK_RESET
    assert reset.detail == "PLC clock went back from 10 s to 2 s; publish time re-anchored"


def test_an_epoch_from_the_config_is_kept_when_the_plc_clock_goes_back():
    clock = PlcClock(epoch_ns=1000 * S)
    assert clock.publish_ns(10.0, 5 * S) == (1010 * S, None)
    assert clock.publish_ns(2.0, 6 * S) == (1002 * S, None)
