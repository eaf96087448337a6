"""The MCAP topics and their JSON schemas (CONTRACTS.md section 2), defined once for the
daemon's writer and every reader: `logs info`, `logs export`, the refit, and the model's
commands reading logs. Here, in the package both sides may import (docs/logs.md).

The schemas are written for Foxglove as much as for validation: Foxglove turns a
`jsonschema` channel into plottable fields only when every object lists its `properties` and
every field has exactly one of boolean/string/number/integer/object/array (no `$ref`, no
`["number", "null"]` unions, no `"null"`: its schema parser refuses the whole channel on one
of them). A value that can be missing is therefore declared with its one type and left out of
the message when missing (`absent()` drops it); Foxglove leaves a gap in the plot, which is
what an engineer should see, and a strict JSON Schema validator accepts the message.

Every field a message carries is declared here, so a message validates against its channel's
schema with `"additionalProperties": false` added to every object that lists its properties
(tests/logcheck.py). Maps whose keys are open (failures by kind, combinations by name) say so
with `additionalProperties`. The contract grows by adding fields, never by renaming.

Time in Foxglove's shape, {sec, nsec}: `plc_time` on the furnace topics is the PLC's clock
(the message's publish time) when the register map has one; the /log topic is
`foxglove.Log`, one line per status change and event, so Foxglove's log panel shows them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the furnace loads numpy: not for a command's --help (test_cli_surface)
    from ..simulation.furnace import Furnace

SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"

QUALITIES: tuple[str, ...] = ("ok", "stale", "comm_error", "out_of_range", "sensor_open")
"""Quality of one reading; only `ok` readings enter averages and fits."""

DAQ_STATES: tuple[str, ...] = ("connected", "disconnected")
BURNER_SOURCES: tuple[str, ...] = ("modbus", "can")
MODEL_STATUSES: tuple[str, ...] = ("ok", "insufficient_excitation", "failed")
DIAGNOSIS_STATUSES: tuple[str, ...] = ("explained", "explained_in_part", "unexplained", "no_gap",
                                       "failed")
"""A diagnosis's verdict (CONTRACTS.md section 6), or failed: it raised or ran out of time."""
PARAM_NAMES: tuple[str, ...] = ("a", "b", "c", "d", "e", "f")
"""The paper's furnace's parameters; another furnace's are `param_names(furnace)`."""


def param_names(furnace: Furnace) -> tuple[str, ...]:
    """The names /model/parameters carries for `furnace`: a..f for eq. 11's network."""
    if furnace.paper_structure:
        return PARAM_NAMES
    from ..simulation.network import parameter_names

    return tuple(parameter_names(furnace))

THERMOCOUPLES = "/furnace/thermocouples"
BURNERS = "/furnace/burners"
AMBIENT = "/furnace/ambient"
HEAT = "/furnace/heat"
DISTURBANCES = "/furnace/disturbances"
SIGNALS = "/furnace/signals"
DAQ_STATUS = "/daq/status"
DAQ_EVENTS = "/daq/events"
MODEL_PARAMETERS = "/model/parameters"
MODEL_EVENTS = "/model/events"
MODEL_DIAGNOSIS = "/model/diagnosis"
LOG = "/log"
FURNACE_TOPICS: tuple[str, ...] = (THERMOCOUPLES, BURNERS, AMBIENT, HEAT, DISTURBANCES,
                                   SIGNALS)
"""The topics of the furnace's readings: what the resampler and the refit read. The last
three are in a log only when its furnace or register map has what they carry."""
READING_FIELDS: tuple[str, ...] = ("quality", "unit", "plc_time")
"""The fields of /furnace/heat, /furnace/disturbances and /furnace/signals beside the values
they carry by name."""


@dataclass(frozen=True)
class SignalField:
    """An extra named point of a register map as /furnace/signals carries it: a number in
    its unit, a bit (a boolean), or text (a string register: a recipe, a product code)."""

    name: str
    unit: str
    bit: bool = False
    text: bool = False

JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
"""The draft every top-level schema declares (`$schema`); validators pick it from there."""

LOG_LEVELS: dict[str, int] = {"unknown": 0, "debug": 1, "info": 2, "warning": 3, "error": 4,
                              "fatal": 5}
"""foxglove.LogLevel: the `level` of a /log message."""


def plc_time(ns: int) -> dict[str, int]:
    """A time in Foxglove's shape ({sec, nsec}, nsec in 0..999999999) from ns since the epoch;
    floor division keeps nsec positive for times before 1970 as Foxglove expects."""
    sec, nsec = divmod(int(ns), 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def time_ns(stamp: dict) -> int:
    """ns since the epoch from a {sec, nsec} field: the inverse of `plc_time`."""
    return int(stamp["sec"]) * 1_000_000_000 + int(stamp["nsec"])


def absent(message: dict) -> dict:
    """`message` without its None values, in nested objects too (never inside arrays): a
    missing value is left out, which every schema here accepts and Foxglove plots as a gap."""
    return {k: absent(v) if isinstance(v, dict) else v
            for k, v in message.items() if v is not None}


def _number(description: str) -> dict:
    return {"type": "number", "description": description}


def _integer(description: str, minimum: int | None = 0) -> dict:
    s: dict = {"type": "integer", "description": description}
    if minimum is not None:
        s["minimum"] = minimum
    return s


def _numbers(description: str, n: int | None = None) -> dict:
    s: dict = {"type": "array", "items": {"type": "number"}, "description": description}
    if n is not None:
        s["minItems"] = s["maxItems"] = n
    return s


def _strings(description: str) -> dict:
    return {"type": "array", "items": {"type": "string"}, "description": description}


def _time(description: str) -> dict:
    """Foxglove's time: {sec, nsec}, as its own schemas (foxglove.Log's timestamp) write it."""
    return {"type": "object", "title": "time", "description": description,
            "properties": {"sec": {"type": "integer", "minimum": 0},
                           "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}},
            "required": ["sec", "nsec"]}


def _open_map(values: dict, description: str) -> dict:
    """An object whose keys are not known in advance (counts by kind, ...): every value has
    the schema `values`. Foxglove shows it as an object without fields."""
    return {"type": "object", "properties": {}, "additionalProperties": values,
            "description": description}


def _string(description: str, choices: tuple[str, ...] | None = None) -> dict:
    s: dict = {"type": "string", "description": description}
    if choices:
        s["enum"] = list(choices)
    return s


def _object(properties: dict, description: str = "", required: tuple[str, ...] = ()) -> dict:
    s: dict = {"type": "object", "properties": properties}
    if description:
        s["description"] = description
    if required:
        s["required"] = list(required)
    return s


def _param_doc(furnace: Furnace, p: str) -> str:
    return (f"parameter {p} of the paper's eq. 11" if furnace.paper_structure
            else f"parameter {p} of the furnace's thermal network")


def _params_object(furnace: Furnace, description: str) -> dict:
    return _object({p: _number(_param_doc(furnace, p)) for p in param_names(furnace)},
                   description)


@dataclass(frozen=True)
class Topic:
    """One channel of the log: its topic name, schema name and JSON schema."""

    name: str
    schema_name: str
    schema: dict = field(hash=False, compare=False)

    def schema_bytes(self) -> bytes:
        return json.dumps({"$schema": JSON_SCHEMA_DIALECT, **self.schema}, sort_keys=True,
                          separators=(",", ":")).encode()


_PLC_TIME = _time("the PLC's clock at the reading (the message's publish time); absent when "
                  "the register map has no PLC clock or the poll failed")


def _thermocouples(furnace: Furnace) -> dict:
    sensors = furnace.sensors
    return _object(
        {
            **{s: _number(f"thermocouple {s} in °C; absent when the reading is not usable "
                          "(logs written before the schema declared every field carry null)")
               for s in sensors},
            "quality": _object({s: _string(f"quality of {s}", QUALITIES) for s in sensors},
                               "quality per thermocouple; only 'ok' readings are averaged",
                               sensors),
            "plc_seconds": _number("the PLC clock register, s since the PLC's own start"),
            "plc_time": _PLC_TIME,
            "error": _string("why some or all readings are comm_error: the failed poll, or the "
                             "blocks the PLC refused"),
        },
        f"the {'six' if len(sensors) == 6 else len(sensors)} zone thermocouples of one poll",
        ("quality",),
    )


def _burners(furnace: Furnace) -> dict:
    zones = furnace.switched_zones
    counts = tuple(furnace.burners[i] for i in furnace.switched)
    return _object(
        {
            **{z: {"type": "array", "items": {"type": "boolean"}, "minItems": n, "maxItems": n,
                   "description": f"flame-on state of each of the {n} burners of the {z} zone"}
               for z, n in zip(zones, counts, strict=True)},
            **{f"count_{z}": {"type": "integer", "minimum": 0, "maximum": n,
                              "description": f"burners firing in the {z} zone"}
               for z, n in zip(zones, counts, strict=True)},
            "source": _string("where the states were read", BURNER_SOURCES),
            "quality": _string("quality of the states: stale when the PLC's heartbeat stopped",
                               QUALITIES),
            "plc_time": _PLC_TIME,
        },
        "burner flame-on states",
        (*zones, *(f"count_{z}" for z in zones), "source"),
    )


def _named_readings(fields: dict[str, dict], units: dict[str, str], what: str,
                    description: str) -> dict:
    """A topic of values carried by name (rate-fired zones, disturbances, signals), each with
    its quality and its unit, as /furnace/thermocouples carries its readings."""
    names = tuple(fields)
    return _object(
        {
            **fields,
            "quality": _object({n: _string(f"quality of {n}", QUALITIES) for n in names},
                               f"quality per {what}; only 'ok' readings are averaged", names),
            "unit": _object({n: _string(f"the unit of {n}", (u,)) for n, u in units.items()},
                            f"the unit of each {what}", names),
            "plc_time": _PLC_TIME,
        },
        description,
        ("quality", "unit"),
    )


def _heat(furnace: Furnace) -> dict:
    zones = {furnace.zones[i]: furnace.heat_inputs[i] for i in furnace.rated}
    return _named_readings(
        {z: _number(f"heat input of the {z} zone in {h.unit} (0 to {h.max:g}); absent when "
                    "the reading is not usable") for z, h in zones.items()},
        {z: h.unit for z, h in zones.items()}, "zone",
        "the heat input of each zone fired at a modulated rate (firing rate, fuel flow), one "
        "poll; zones fired by burners switched on and off are on /furnace/burners")


def _disturbances(furnace: Furnace) -> dict:
    return _named_readings(
        {d.name: _number(f"measured disturbance {d.name} in {d.unit}; absent when the reading "
                         "is not usable") for d in furnace.disturbances},
        {d.name: d.unit for d in furnace.disturbances}, "disturbance",
        "the measured disturbances the furnace description declares, one poll")


def _signals(signals: tuple[SignalField, ...]) -> dict:
    return _named_readings(
        {s.name: {"type": "boolean", "description": f"signal {s.name}, a bit; absent when "
                  "the reading is not usable"} if s.bit else
         {"type": "string", "description": f"signal {s.name}, text; absent when the reading "
                  "is not usable"} if s.text else
         _number(f"signal {s.name}" + (f" in {s.unit}" if s.unit else "") + "; absent when "
                 "the reading is not usable") for s in signals},
        {s.name: s.unit for s in signals}, "signal",
        "the register map's extra named points (O2, pressure, fuel flow, a door switch), one "
        "poll")


_AMBIENT = _object(
    {"t_air": _number("ambient air temperature in °C; absent when the reading is not usable"),
     "quality": _string("quality of t_air (absent means ok)", QUALITIES),
     "from_config": {"type": "boolean", "description": "t_air is the config's "
                     "ambient_default_c: the register map has no ambient point"},
     "plc_time": _PLC_TIME},
    "ambient temperature",
)

_DAQ_STATUS = _object(
    {"state": _string("connection to the PLC", DAQ_STATES),
     "detail": _string("why the state changed, in words"),
     "polls": _integer("poll ticks since start"),
     "ok_polls": _integer("polls that returned data"),
     "comm_errors": _integer("polls that failed"),
     "skipped_ticks": _integer("ticks skipped because a poll or the host was late"),
     "connects": _integer("connections made"),
     "disconnects": _integer("connections lost"),
     "connect_attempts": _integer("dials"),
     "can_frames": _integer("CAN frames read from the flame scanners"),
     "disagreements": _integer("times PLC and flame scanners began to disagree"),
     "failures": _open_map(_integer("polls"), "polls that gave no data, by kind of failure"),
     "incomplete": _open_map(_integer("polls"), "polls logged with a block the PLC refused, "
                             "by block and exception"),
     "period_s": _number("poll period in s"),
     "log_error": _string("why the log cannot be written right now"),
     "device": _string("the device whose connection changed (several devices)"),
     "devices": _open_map(_string("connection state", DAQ_STATES),
                          "each device's connection state, by device name")},
    "one message on every change of connection state, plus any counters of the poller",
    ("state", "detail"),
)


def _daq_events(furnace: Furnace) -> dict:
    zones = furnace.switched_zones
    return _object(
        {"kind": _string("what happened, e.g. burner_disagreement, missed_tick, log_gap"),
         "detail": _string("the event in words"),
         "skipped": _integer("missed_tick: ticks skipped since the last such event"),
         "step_s": _number("clock_step: the host clock's step in s"),
         "error": _string("log_gap: why the log could not be written"),
         "dropped": _integer("log_gap: messages dropped from the full buffer"),
         "burners": _strings("burner_disagreement: the burners that disagree, e.g. heat[3]"),
         "plc": _object({z: {"type": "array", "items": {"type": "boolean"},
                             "description": f"PLC states of the {z} burners"} for z in zones},
                        "burner_disagreement: the PLC's states"),
         "flame": _object({z: {"type": "array", "items": {"type": "boolean"},
                               "description": f"flame scanner states of the {z} burners"}
                           for z in zones}, "burner_disagreement: the flame scanners' states")},
        "acquisition events: PLC and flame signals disagree, a poll tick was missed, the log "
        "could not be written for a while",
        ("kind", "detail"),
    )


def _ci95(names: tuple[str, ...]) -> dict:
    return _object({p: {"type": "array", "items": {"type": "number"}, "minItems": 2,
                        "maxItems": 2, "description": f"95% interval of {p}: [lo, hi]"}
                    for p in names}, "95% confidence intervals")


def _combination(name: str) -> dict:
    return _object({"value": _number(f"value of {name}"),
                    "ci95": _numbers(f"95% interval of {name}")}, name)


def _combinations(furnace: Furnace) -> dict:
    names = param_names(furnace)
    extra = ("b/c", "d/e") if furnace.paper_structure else ()
    out = _object(
        {name: _combination(name) for name in (*names, *extra)},
        "what the window's data determine, {name: {value, ci95}}; other names may appear")
    out["additionalProperties"] = _combination("another combination")
    return out


def _model_parameters(furnace: Furnace) -> dict:
    names, zones = param_names(furnace), furnace.zones
    return _object(
        {
            **{p: _number(f"{_param_doc(furnace, p)} in force after this window; "
                          "absent before the first model (null in older logs)") for p in names},
            "ci95": _ci95(names),
            "window_start": _string("start of the data window of the fit, ISO 8601 UTC (PLC clock)"),
            "window_end": _string("end of the data window of the fit, ISO 8601 UTC (PLC clock)"),
            "rmse_c": _object({z: _number(f"fit RMSE of the {z} zone in °C") for z in zones},
                              "fit RMSE per zone"),
            "status": _string("outcome of the refit; unless ok, the previous model is kept",
                              MODEL_STATUSES),
            "detail": _string("why a window was not fitted, or the fit's warnings"),
            "model_window_start": _string("start of the window the model in force was fitted on"),
            "model_window_end": _string("end of the window the model in force was fitted on"),
            "n_samples": {"type": "integer", "description": "resampled rows in the window"},
            "gap_fraction": _number("share of the window's rows missing or without every zone"),
            "burner_steps": {"type": "integer", "description": "burner pattern changes in the window"},
            "elapsed_s": _number("wall time of the fit in s"),
            "sigma_c": _number("residual standard deviation of the fit in °C"),
            "determined_combinations": {"type": "array", "items": {"type": "string"},
                                        "description": "what the window's data determine"},
            "undetermined": {"type": "array", "items": {"type": "string"},
                             "description": "parameters with a 95% interval wider than +-5%"},
            "combinations": _combinations(furnace),
            "zone_offsets_c": _object({z: _number(f"fitted thermocouple offset of the {z} zone")
                                       for z in zones}, "fitted thermocouple bias per zone"),
            "flags": {"type": "array", "description":
                      "the window's zone offsets and initial temperatures that ended on their "
                      "physical bound (a thermocouple's bias, what the first readings allow): "
                      "the model's error, not a sensor's",
                      "items": _object({
                          "kind": _string("what ended on its bound",
                                          ("offset", "initial_state")),
                          "record": _string("the window"),
                          "zone": _string("the zone", zones),
                          "value_c": _number("the fitted value in °C"),
                          "low_c": _number("lowest plausible value in °C (absent: none)"),
                          "high_c": _number("highest plausible value in °C (absent: none)"),
                      }, "one flagged value")},
            "recent_f": _object({
                "f": _number("f on the recent span alone, a..e of the window held"),
                "se": _number("standard error of that f"),
                "n_samples": _integer("rows of the recent span with a zone temperature"),
            }, "what the newest data say about the heat per burner (drift detection)"),
            "plc_time": _time("the window's end on the PLC's clock, when the register map has "
                              "one"),
            "noise_floor_c": _object({z: _number(f"noise floor of the {z} zone in °C: the RMSE "
                                                 "a perfect model would reach on the window")
                                      for z in zones}, "the window's noise floor per zone"),
            "misfit_limit_c": _object({z: _number(f"fit RMSE of the {z} zone above which the "
                                                  "model misses the window (°C)")
                                       for z in zones},
                                      "the noise floor widened by its uncertainty, as a "
                                      "diagnosis judges a gap (refit.diagnosis)"),
            "search": _object({
                "method": _string("refit.method: ga_polish (the GA seeded with the previous "
                                  "model, then the polish), ga (the paper's GA from scratch) "
                                  "or polish (from the previous model)",
                                  ("ga_polish", "ga", "polish")),
                "warm_start": {"type": "boolean",
                               "description": "started from the previous window's model"},
                "population": {"type": "integer",
                               "description": "GA population (ga and ga_polish)"},
                "generations": {"type": "integer",
                                "description": "GA generations run (ga and ga_polish)"},
                "seed": {"type": "integer",
                         "description": "the GA's random seed (ga_polish: the window's end, "
                                        "seconds of the data clock)"},
            }, "how this window was fitted"),
        },
        "an online refit of the three-zone model over one window of the data clock"
        if furnace.paper_structure else
        f"an online refit of the thermal network of furnace {furnace.name} over one window of "
        "the data clock",
        ("ci95", "window_start", "window_end", "rmse_c", "status"),
    )


def _model_events(furnace: Furnace) -> dict:
    return _object(
        {"kind": _string("what happened: drift, window_dropped, diagnosis, diagnosis_failed"),
         "detail": _string("the event in words"),
         "parameter": _string("drift: the parameter that moved"),
         "old": _number("drift: its reference value"),
         "old_ci95": {"type": "array", "items": {"type": "number"}, "description": "drift: the "
                      "reference's 95% interval"},
         "new": _number("drift: its value now"),
         "new_ci95": {"type": "array", "items": {"type": "number"}, "description": "drift: the new "
                      "95% interval"},
         "relative_change": _number("drift: new / old - 1"),
         "windows": {"type": "integer", "description": "drift: windows in a row that moved"},
         "window_start": _string("the window that raised the event"),
         "window_end": _string("the window that raised the event"),
         "parameters": _params_object(furnace, "the parameters involved and their new values"),
         "old_window_end": _string("drift: the window the reference value was fitted on"),
         "basis": _string("drift: recent when judged on the recent span's f, else absent"),
         "recent_start": _string("drift on the recent span: where that span starts"),
         "plc_time": _time("the window's end on the PLC's clock, when the register map has one")},
        "model events such as parameter drift",
        ("kind", "detail"),
    )


def _window(what: str) -> dict:
    return _object({"start": _string(f"start of the {what}, ISO 8601 UTC (PLC clock)"),
                    "end": _string(f"end of the {what}, ISO 8601 UTC (PLC clock)")},
                   f"the {what}")


def _model_diagnosis(furnace: Furnace) -> dict:
    zones = furnace.zones
    per_zone = lambda what: _object({z: _number(f"{what}, {z} zone (°C)") for z in zones},  # noqa: E731
                                    what)
    return _object(
        {"status": _string("the verdict: explained (by the effects), explained_in_part, "
                           "unexplained, no_gap, or failed (the diagnosis raised or ran past "
                           "its time)", DIAGNOSIS_STATUSES),
         "detail": _string("the verdict in a sentence; for a thermocouple drift, which one and "
                           "since when"),
         "trigger": _string("what started it: drift (a /model/events drift) or misfit (windows "
                            "in a row fitted above their noise floor)", ("drift", "misfit")),
         "trigger_detail": _string("the trigger in words"),
         "effects": {"type": "array", "description": "the effects the verdict keeps, with their "
                     "fitted parameters", "items": _object({
                         "effect": _string("the effect's name (CONTRACTS.md section 4)"),
                         "options": _open_map({}, "the effect's law (e.g. sensor: soak_1)"),
                         "params": _open_map({"type": "number"}, "its fitted parameters")},
                         "one effect kept")},
         "sensor": _object({"thermocouple": _string("the thermocouple that drifts"),
                            "onset": _string("when its drift began, ISO 8601 UTC"),
                            "rate_c_per_h": _number("how fast its error grows, °C per hour"),
                            "rate_c_per_h_ci95": _numbers("the rate's 95% interval", 2),
                            "onset_ci95": {"type": "array", "items": {"type": "string"},
                                           "minItems": 2, "maxItems": 2,
                                           "description": "the onset's 95% interval, ISO 8601 "
                                                          "UTC"},
                            "rate_pinned": {"type": "boolean", "description":
                                            "whether the record pins the rate down (its "
                                            "interval's half-width at most half the rate)"}},
                           "sensor_drift kept: the thermocouple, not the furnace, changed"),
         "where": {"type": "array", "description": "where the model's error lies, largest "
                   "share first", "items": _object({
                       "zone": _string("the zone"),
                       "sensor": _string("the thermocouple departing from its partner, if one"),
                       "start": _string("start of the span"), "end": _string("end of the span"),
                       "share_of_error": _number("share of the error above the floor"),
                       "regime": _string("what the furnace did then"),
                       "kind": _string("sensor, change, span or throughout")},
                       "one place")},
         "shrink_pct": _number("held-out RMSE reduction of the kept effects against the model"),
         "gap_closed_pct": _number("share of the held-out error above the floor they remove"),
         "rmse_holdout_c": per_zone("the model's held-out RMSE"),
         "noise_floor_c": per_zone("the held-out data's noise floor"),
         "fitted": {"type": "array", "items": _window("span fitted"),
                    "description": "the spans the candidates were fitted on"},
         "held_out": {"type": "array", "items": _window("span held out"),
                      "description": "the spans they were judged on"},
         "reference_window": _window("last refit window the model fitted to its floor"),
         "effects_tried": _strings("the candidate effects (refit.diagnosis.effects)"),
         "untried": _strings("what the time limit left unfitted: the verdict is judged "
                             "without it"),
         "cut": _strings("the same fits by batch and place: replay cuts these and no others, "
                         "in place of the clock"),
         "seed": _integer("the diagnosis's random seed: the held-out window's end in seconds"),
         "time_limit_s": _number("refit.diagnosis.time_limit_s"),
         "elapsed_s": _number("wall time of the diagnosis in s"),
         "plc_time": _time("the held-out window's end on the PLC's clock, when the register "
                           "map has one")},
        "an online diagnosis of what the refit's model misses (refit.diagnosis)",
        ("status", "detail", "trigger"),
    )


_LOG = {
    "title": "foxglove.Log",
    "description": "the status changes and events of the other topics as log lines, for "
                   "Foxglove's log panel (its foxglove.Log schema)",
    "type": "object",
    "properties": {
        "timestamp": _time("when it happened (host UTC, the message's log time)"),
        "level": {"title": "foxglove.LogLevel", "description": "log level",
                  "oneOf": [{"title": k.upper(), "const": v} for k, v in LOG_LEVELS.items()]},
        "message": _string("the line"),
        "name": _string("what logged it: furnace-daq"),
        "file": _string("the topic that carries the line's structured message"),
        "line": _integer("unused (0): the lines come from messages, not from source lines"),
    },
    "required": ["timestamp", "level", "message", "name", "file", "line"],
}


def topics(furnace: Furnace, signals: tuple[SignalField, ...] = ()) -> dict[str, Topic]:
    """Every topic of the contract for `furnace` and the extra `signals` of its register
    map, in the order the writer registers them: the furnace topics' fields are its
    thermocouples and zones, /model/parameters its network's parameters (CONTRACTS.md
    section 2). Same names and schema names for every furnace, so a reader finds the topics
    of any log. /furnace/heat, /furnace/disturbances and /furnace/signals are topics only
    of a furnace with rate-fired zones, with disturbances, and of a map with signals."""
    return _topics(furnace, tuple(signals))


@lru_cache(maxsize=16)
def _topics(furnace: Furnace, signals: tuple[SignalField, ...]) -> dict[str, Topic]:
    extra = []
    if furnace.rated:
        extra.append(Topic(HEAT, "furnace.Heat", _heat(furnace)))
    if furnace.disturbances:
        extra.append(Topic(DISTURBANCES, "furnace.Disturbances", _disturbances(furnace)))
    if signals:
        extra.append(Topic(SIGNALS, "furnace.Signals", _signals(signals)))
    return {t.name: t for t in (
        Topic(THERMOCOUPLES, "furnace.Thermocouples", _thermocouples(furnace)),
        Topic(BURNERS, "furnace.Burners", _burners(furnace)),
        Topic(AMBIENT, "furnace.Ambient", _AMBIENT),
        *extra,
        Topic(DAQ_STATUS, "daq.Status", _DAQ_STATUS),
        Topic(DAQ_EVENTS, "daq.Event", _daq_events(furnace)),
        Topic(MODEL_PARAMETERS, "model.Parameters", _model_parameters(furnace)),
        Topic(MODEL_EVENTS, "model.Event", _model_events(furnace)),
        Topic(MODEL_DIAGNOSIS, "model.Diagnosis", _model_diagnosis(furnace)),
        Topic(LOG, "foxglove.Log", _LOG),
    )}


def topic(name: str, furnace: Furnace, signals: tuple[SignalField, ...] = ()) -> Topic:
    """The contract's topic, or an open object schema for a topic the contract does not name
    yet (logged rather than lost; Foxglove shows its fields without autocompletion)."""
    known = topics(furnace, signals).get(name)
    if known is not None:
        return known
    schema_name = "extra." + name.strip("/").replace("/", ".")
    return Topic(name, schema_name, _object({}, f"messages on {name}"))
