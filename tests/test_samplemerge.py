"""Merging devices' samples and judging a device stale, on plain samples: each device's
staleness marks its own points only, a device that gave nothing is named among the errors,
and the burner states count only when every zone is there."""

from __future__ import annotations

from dataclasses import dataclass

from furnace_daq.registers import COMM_ERROR, OK, STALE
from furnace_daq.samplemerge import Heartbeat, merge
from furnace_daq.sources import Sample

ZONES = ("z1", "z2")


@dataclass
class Device:
    name: str
    last_stale: bool = False

    def named(self, text: str) -> str:
        return f"{self.name}: {text}"


def sample(values: dict[str, float], burners: dict[str, list[bool]] | None = None,
           plc_seconds: float | None = None, errors: list[str] | None = None) -> Sample:
    return Sample(dict(values), {k: OK for k in values}, plc_seconds, burners=burners,
                  errors=list(errors or []))


def test_a_stale_device_marks_its_own_points_and_burners_only():
    a = Device("a", last_stale=True)
    b = Device("b")
    out = merge([(a, sample({"tc1": 100.0}, {"z1": [True]}, plc_seconds=5.0)),
                 (b, sample({"tc2": 200.0}, {"z2": [False]}))], [], ZONES, "modbus")
    assert out.values == {"tc1": 100.0, "tc2": 200.0}
    assert out.quality == {"tc1": STALE, "tc2": OK}
    assert out.plc_seconds == 5.0
    assert out.burners == {"z1": [True], "z2": [False]} and out.burner_quality == STALE


def test_a_device_missing_is_an_error_and_its_zones_leave_the_burners_comm_error():
    a = Device("a")
    out = merge([(a, sample({"tc1": 100.0}, {"z1": [True]}, errors=["input 0+2 refused"]))],
                ["b: not connected (connection refused)"], ZONES, "both")
    assert out.errors == ["a: input 0+2 refused", "b: not connected (connection refused)"]
    assert out.burners is None and out.burner_quality == COMM_ERROR


def test_burners_from_the_flame_scanners_alone_are_not_taken_from_the_devices():
    out = merge([(Device("a"), sample({}, {"z1": [True], "z2": [True]}))], [], ZONES, "can")
    assert out.burners is None and out.burner_quality == OK


def test_a_heartbeat_is_stale_once_it_stood_still_longer_than_the_limit():
    hb = Heartbeat()
    assert not hb.stale(7, now=0.0, after_s=1.0)
    assert not hb.stale(7, now=1.0, after_s=1.0)
    assert hb.stale(7, now=1.5, after_s=1.0)
    assert not hb.stale(8, now=2.0, after_s=1.0)  # it moved: fresh again
    assert not hb.stale(None, now=9.0, after_s=1.0)  # no heartbeat: never stale
    hb.reset()
    assert not hb.stale(8, now=9.0, after_s=1.0)  # a new connection starts afresh
