"""The typed messages of the log's topics (furnace_model.log.messages): each class writes
what its topic's schema accepts, reads back what it wrote, and leaves a missing value out."""

from __future__ import annotations

import json

import pytest
from logcheck import problems

from furnace_model.log.messages import (
    CLASSES,
    Ambient,
    Burners,
    DaqEvent,
    DaqEventKind,
    DaqStatus,
    LogLine,
    Message,
    ModelDiagnosis,
    ModelEvent,
    ModelEventKind,
    ModelParameters,
    Thermocouples,
    from_json,
    number,
)
from furnace_model.log.schema import LOG_LEVELS, param_names, topics
from furnace_model.simulation.furnace import PAPER, Furnace
from furnace_model.simulation.furnacefile import load_furnace

T0 = 1_772_409_600_123_456_789
SIX = load_furnace("config/furnaces/six-zone.yaml")


def examples(furnace: Furnace) -> list[Message]:
    sensors, zones = furnace.sensors, furnace.zones
    params = param_names(furnace)
    states = {z: [k % 2 == 0 for k in range(n)] for z, n in zip(zones, furnace.burners,
                                                                 strict=True)}
    return [
        Thermocouples({s: 800.0 + k for k, s in enumerate(sensors)},
                      {s: "ok" for s in sensors}, 12.5, T0, None),
        Burners.from_states(states, "modbus", "ok", T0),
        Ambient(31.5, "ok", None, T0),
        Ambient(30.0, "ok", True),
        DaqStatus("connected", "connected after 1 attempt(s)", 3, 3, 0, 0, 1, 0, 1, 0, 0,
                  {"poll timeout": 1}, {}, 1.0, {"plc": "connected"}, "plc", "disk full"),
        DaqEvent(DaqEventKind.MISSED_TICK, "2 poll tick(s) skipped", skipped=2),
        DaqEvent(DaqEventKind.BURNER_DISAGREEMENT, "PLC and flame scanners disagree",
                 burners=[f"{zones[0]}[0]"], plc=states, flame=states),
        DaqEvent(DaqEventKind.LOG_GAP, "log not written", error="disk full", dropped=4),
        DaqEvent(DaqEventKind.CLOCK_STEP, "host clock stepped", step_s=-2.5),
        ModelParameters("ok", "", "2026-03-02T00:00:00.000Z", "2026-03-03T00:00:00.000Z",
                        1440, 0.01, 12, {p: 0.5 + k for k, p in enumerate(params)},
                        {p: [0.4 + k, 0.6 + k] for k, p in enumerate(params)},
                        {z: 1.5 for z in zones}, {params[0]: {"value": 0.5, "ci95": [0.4, 0.6]}},
                        [params[0]], list(params[1:]), {z: 0.1 for z in zones},
                        [{"kind": "offset", "record": "w", "zone": zones[0], "value_c": 5.0,
                          "high_c": 5.0}],
                        0.3, 1.25, {"method": "polish", "warm_start": True},
                        "2026-03-02T00:00:00.000Z", "2026-03-03T00:00:00.000Z",
                        {"f": 1.0, "se": 0.01, "n_samples": 100}, T0,
                        {z: 1.0 for z in zones}, {z: 1.3 for z in zones}),
        ModelParameters("insufficient_excitation", "too short", "2026-03-02T00:00:00.000Z",
                        "2026-03-03T00:00:00.000Z", 0, 1.0, 0, ci95={}, rmse_c={}),
        ModelEvent(ModelEventKind.DRIFT, f"{params[-1]} rose", params[-1], "recent", 1.0,
                   [0.9, 1.1], "2026-03-02T00:00:00.000Z", 1.2, [1.1, 1.3], 0.2, 3,
                   "2026-03-02T20:00:00.000Z", "2026-03-02T00:00:00.000Z",
                   "2026-03-03T00:00:00.000Z", {params[-1]: 1.2}, T0),
        ModelEvent(ModelEventKind.WINDOW_DROPPED, "refits fall behind",
                   window_end="2026-03-03T00:00:00.000Z"),
        ModelDiagnosis("explained", "thermocouple x drifts", "misfit", "3 windows",
                       [{"effect": "sensor_drift", "options": {"sensor": sensors[0]},
                         "params": {"t_drift": 30.0, "drift_rate": 0.02}}],
                       {"thermocouple": sensors[0], "onset": "2026-03-02T00:30:00.000Z",
                        "rate_c_per_h": 1.2},
                       [{"zone": zones[0], "sensor": sensors[0], "kind": "sensor"}], 50.0, 80.0,
                       {z: 2.0 for z in zones}, {z: 1.0 for z in zones},
                       [{"start": "2026-03-02T00:00:00.000Z", "end": "2026-03-02T02:00:00.000Z"}],
                       [{"start": "2026-03-02T02:00:00.000Z", "end": "2026-03-02T03:00:00.000Z"}],
                       {"start": "2026-03-01T21:00:00.000Z", "end": "2026-03-02T00:00:00.000Z"},
                       ["sensor_drift"], ["dead_time"], ["1.0"], 7, 60.0, 12.5, T0),
        LogLine(T0, LOG_LEVELS["warning"], "missed_tick: 2 skipped", "furnace-daq",
                "/daq/events"),
    ]


@pytest.mark.parametrize("furnace", [PAPER, SIX], ids=["paper", "six-zone"])
def test_every_message_round_trips_and_validates_against_its_topic(furnace: Furnace) -> None:
    seen = set()
    for message in examples(furnace):
        topic = message.topic(furnace)
        seen.add(topic.name)
        data = json.loads(json.dumps(message.to_json()))  # as it goes through the log
        assert problems(topic.name, json.loads(topic.schema_bytes()), data) == []
        assert from_json(topic.name, data, furnace) == message, topic.name
        assert type(message).from_json(data, *(  # type: ignore[attr-defined]
            [furnace] if isinstance(message, Thermocouples | Burners) else [])) == message
        assert CLASSES[topic.name] is type(message)
    assert seen == set(topics(furnace))


def test_a_missing_value_is_left_out() -> None:
    tc = Thermocouples({"heat_1": 812.5}, {s: "comm_error" for s in PAPER.sensors} |
                       {"heat_1": "ok"}, error="soak_1 not read")
    data = tc.to_json()
    assert set(data) == {"heat_1", "quality", "error"}
    assert Ambient(None, "comm_error").to_json() == {"quality": "comm_error"}
    m = ModelParameters("failed", "fit raised", "a", "b", ci95={}, rmse_c={},
                        zone_offsets_c={"heat": None})  # type: ignore[dict-item]
    assert m.to_json() == {"status": "failed", "detail": "fit raised", "window_start": "a",
                           "window_end": "b", "ci95": {}, "rmse_c": {}, "zone_offsets_c": {}}
    assert "skipped" not in DaqEvent(DaqEventKind.MISSED_TICK, "x").to_json()


def test_kinds_are_plain_strings_in_json_and_an_unknown_kind_is_kept() -> None:
    assert DaqEvent(DaqEventKind.LOG_GAP, "x").to_json()["kind"] == "log_gap"
    assert json.dumps(ModelEvent(ModelEventKind.DRIFT, "x").to_json()) == \
        '{"kind": "drift", "detail": "x"}'
    event = DaqEvent.from_json({"kind": "something_new", "detail": "y"})
    assert event.kind == "something_new" and event.to_json()["kind"] == "something_new"
    assert DaqEvent.from_json({"kind": "log_gap", "detail": ""}).kind is DaqEventKind.LOG_GAP


def test_older_logs_read_leniently() -> None:
    """null for a missing reading, no quality map, a burner message with only its lists."""
    tc = Thermocouples.from_json({"heat_1": None, "soak_1": 700.0}, PAPER)
    assert tc.values == {"soak_1": 700.0} and tc.quality == {}
    assert number(tc.values.get("heat_1")) != number(tc.values.get("heat_1"))  # NaN
    burners = Burners.from_json({z: [True] * n for z, n in zip(PAPER.zones, PAPER.burners,
                                                                 strict=True)}, PAPER)
    assert burners.zone_counts(PAPER) == [float(n) for n in PAPER.burners]
    assert burners.flame_states(PAPER) == [True] * sum(PAPER.burners)
    assert burners.integer_counts(PAPER) is None
    assert Ambient.from_json({"t_air": 25.0}).usable
