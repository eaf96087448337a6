"""Samples as typed log messages, and the burner comparison, on plain samples: a missing
reading is left out (never null) with its quality saying why, the PLC clock is written
into each message, and a disagreement is an event only once it has held for its polls."""

from __future__ import annotations

from daq_processes import config

from furnace_daq.messagebuild import FlameComparison, MessageBuilder
from furnace_daq.registers import COMM_ERROR, OK
from furnace_daq.sources import Sample
from furnace_model.log.messages import Ambient, Burners, DaqEventKind, Thermocouples

ZONES = ("soak", "heat")


def test_a_sample_becomes_thermocouples_ambient_and_burners_with_the_plc_time():
    cfg = config(1)
    sensors = cfg.furnace.sensors
    values = {s: 100.0 + i for i, s in enumerate(sensors[1:])} | {"t_air": 25.0}
    sample = Sample(values, {k: OK for k in values}, plc_seconds=42.0,
                    burners={z: [True, False] for z in cfg.furnace.zones},
                    errors=["input 0+1 refused"])
    tc, amb, burners = MessageBuilder(cfg).readings(sample, pub_ns=7)
    assert isinstance(tc, Thermocouples) and isinstance(amb, Ambient)
    assert isinstance(burners, Burners) and burners.source == "modbus"
    data = tc.to_json()
    assert sensors[0] not in data and data["quality"][sensors[0]] == COMM_ERROR
    assert data[sensors[1]] == 100.0
    assert data["plc_seconds"] == 42.0 and tc.plc_time == 7
    assert data["error"] == "input 0+1 refused"
    assert amb.plc_time == 7 and burners.plc_time == 7


def test_no_reading_is_every_sensor_comm_error_with_the_reasons():
    cfg = config(1)
    data = MessageBuilder(cfg).no_reading(["a: poll timeout", "b: refused"]).to_json()
    assert set(data["quality"].values()) == {COMM_ERROR}
    assert not set(cfg.furnace.sensors) & set(data)
    assert data["error"] == "a: poll timeout; b: refused"


def burners(soak: list[bool], heat: list[bool]) -> Sample:
    return Sample(burners={"soak": soak, "heat": heat})


def test_a_disagreement_is_told_once_it_held_and_again_when_it_ends():
    cmp = FlameComparison(ZONES, polls=2)
    plc, flame = burners([True, True], [False]), burners([True, False], [False])
    assert cmp.compare(plc, flame) is None  # one poll: a burner switching between reads
    event = cmp.compare(plc, flame)
    assert event is not None and event.kind == DaqEventKind.BURNER_DISAGREEMENT
    assert event.to_json()["burners"] == ["soak[1]"]
    assert cmp.compare(plc, flame) is None  # told already
    assert cmp.compare(plc, plc) is None
    event = cmp.compare(plc, plc)
    assert event is not None and event.kind == DaqEventKind.BURNER_AGREEMENT


def test_burners_of_doubtful_quality_are_not_compared():
    cmp = FlameComparison(ZONES, polls=1)
    plc, flame = burners([True], [True]), burners([False], [True])
    flame.burner_quality = COMM_ERROR
    assert cmp.compare(plc, flame) is None
