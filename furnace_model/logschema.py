"""The MCAP topics and their JSON schemas (CONTRACTS.md section 2), defined once for the
daemon's writer and every reader: `logs info`, `logs export`, the refit, and the model's
commands reading logs. Here, in the package both sides may import (docs/logs.md).

The schemas are written for Foxglove as much as for validation: Foxglove turns a
`jsonschema` channel into plottable fields only when every object lists its `properties` and
every field has exactly one of boolean/string/number/integer/object/array (no `$ref`, no
`["number", "null"]` unions, no `"null"`). A reading that can be missing is therefore declared
`"number"` and says in its description that it is `null` when unusable; Foxglove then leaves a
gap in the plot, which is what an engineer should see.

Fields beyond the contract's minimum are welcome (JSON Schema allows additional properties by
default); the contract grows by adding fields, never by renaming.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

from . import BURNERS_PER_ZONE, SENSORS, ZONES

SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"

QUALITIES: tuple[str, ...] = ("ok", "stale", "comm_error", "out_of_range", "sensor_open")
"""Quality of one reading; only `ok` readings enter averages and fits."""

DAQ_STATES: tuple[str, ...] = ("connected", "disconnected")
BURNER_SOURCES: tuple[str, ...] = ("modbus", "can")
MODEL_STATUSES: tuple[str, ...] = ("ok", "insufficient_excitation", "failed")
PARAM_NAMES: tuple[str, ...] = ("a", "b", "c", "d", "e", "f")

THERMOCOUPLES = "/furnace/thermocouples"
BURNERS = "/furnace/burners"
AMBIENT = "/furnace/ambient"
DAQ_STATUS = "/daq/status"
DAQ_EVENTS = "/daq/events"
MODEL_PARAMETERS = "/model/parameters"
MODEL_EVENTS = "/model/events"


def _number(description: str) -> dict:
    return {"type": "number", "description": description}


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


def _params_object(description: str) -> dict:
    return _object({p: _number(f"parameter {p} of the paper's eq. 11") for p in PARAM_NAMES},
                   description)


@dataclass(frozen=True)
class Topic:
    """One channel of the log: its topic name, schema name and JSON schema."""

    name: str
    schema_name: str
    schema: dict = field(hash=False, compare=False)

    def schema_bytes(self) -> bytes:
        return json.dumps(self.schema, sort_keys=True, separators=(",", ":")).encode()


_THERMOCOUPLES = _object(
    {
        **{s: _number(f"thermocouple {s} in °C; null when the reading is not usable")
           for s in SENSORS},
        "quality": _object({s: _string(f"quality of {s}", QUALITIES) for s in SENSORS},
                           "quality per thermocouple; only 'ok' readings are averaged",
                           SENSORS),
    },
    "the six zone thermocouples of one poll",
    (*SENSORS, "quality"),
)

_BURNERS = _object(
    {
        **{z: {"type": "array", "items": {"type": "boolean"}, "minItems": n, "maxItems": n,
               "description": f"flame-on state of each of the {n} burners of the {z} zone"}
           for z, n in zip(ZONES, BURNERS_PER_ZONE, strict=True)},
        **{f"count_{z}": {"type": "integer", "minimum": 0, "maximum": n,
                          "description": f"burners firing in the {z} zone"}
           for z, n in zip(ZONES, BURNERS_PER_ZONE, strict=True)},
        "source": _string("where the states were read", BURNER_SOURCES),
    },
    "burner flame-on states",
    (*ZONES, *(f"count_{z}" for z in ZONES), "source"),
)

_AMBIENT = _object(
    {"t_air": _number("ambient air temperature in °C; null when the reading is not usable"),
     "quality": _string("quality of t_air (absent means ok)", QUALITIES)},
    "ambient temperature",
    ("t_air",),
)

_DAQ_STATUS = _object(
    {"state": _string("connection to the PLC", DAQ_STATES),
     "detail": _string("why the state changed, in words")},
    "one message on every change of connection state, plus any counters of the poller",
    ("state", "detail"),
)

_DAQ_EVENTS = _object(
    {"kind": _string("what happened, e.g. burner_disagreement, missed_tick, log_gap"),
     "detail": _string("the event in words")},
    "acquisition events: PLC and flame signals disagree, a poll tick was missed, the log "
    "could not be written for a while",
    ("kind", "detail"),
)

_CI95 = _object({p: {"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 2,
                     "description": f"95% interval of {p}: [lo, hi]"} for p in PARAM_NAMES},
                "95% confidence intervals")
_COMBINATIONS = _object(
    {name: _object({"value": _number(f"value of {name}"),
                    "ci95": {"type": "array", "items": {"type": "number"},
                             "description": f"95% interval of {name}"}}, f"{name}")
     for name in (*PARAM_NAMES, "b/c", "d/e")},
    "what the window's data determine, {name: {value, ci95}}; other names may appear")

_MODEL_PARAMETERS = _object(
    {
        **{p: _number(f"parameter {p} of the paper's eq. 11 in force after this window; null "
                      "before the first model") for p in PARAM_NAMES},
        "ci95": _CI95,
        "window_start": _string("start of the data window of the fit, ISO 8601 UTC (PLC clock)"),
        "window_end": _string("end of the data window of the fit, ISO 8601 UTC (PLC clock)"),
        "rmse_c": _object({z: _number(f"fit RMSE of the {z} zone in °C") for z in ZONES},
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
        "combinations": _COMBINATIONS,
        "zone_offsets_c": _object({z: _number(f"fitted thermocouple offset of the {z} zone")
                                   for z in ZONES}, "fitted thermocouple bias per zone"),
        "search": _object({
            "method": _string("refit.method: polish (from the previous model) or ga (the "
                              "paper's GA from scratch)", ("polish", "ga")),
            "warm_start": {"type": "boolean",
                           "description": "started from the previous window's model"},
            "population": {"type": "integer", "description": "GA population (ga only)"},
            "generations": {"type": "integer", "description": "GA generations run (ga only)"},
        }, "how this window was fitted"),
    },
    "an online refit of the three-zone model over one window of the data clock",
    (*PARAM_NAMES, "ci95", "window_start", "window_end", "rmse_c", "status"),
)

_MODEL_EVENTS = _object(
    {"kind": _string("what happened: drift, window_dropped"),
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
     "parameters": _params_object("the parameters involved and their new values")},
    "model events such as parameter drift",
    ("kind", "detail"),
)

TOPICS: dict[str, Topic] = {t.name: t for t in (
    Topic(THERMOCOUPLES, "furnace.Thermocouples", _THERMOCOUPLES),
    Topic(BURNERS, "furnace.Burners", _BURNERS),
    Topic(AMBIENT, "furnace.Ambient", _AMBIENT),
    Topic(DAQ_STATUS, "daq.Status", _DAQ_STATUS),
    Topic(DAQ_EVENTS, "daq.Event", _DAQ_EVENTS),
    Topic(MODEL_PARAMETERS, "model.Parameters", _MODEL_PARAMETERS),
    Topic(MODEL_EVENTS, "model.Event", _MODEL_EVENTS),
)}
"""Every topic of the contract, in the order the writer registers them."""


def topic(name: str) -> Topic:
    """The contract's topic, or an open object schema for a topic the contract does not name
    yet (logged rather than lost; Foxglove shows its fields without autocompletion)."""
    known = TOPICS.get(name)
    if known is not None:
        return known
    schema_name = "extra." + name.strip("/").replace("/", ".")
    return Topic(name, schema_name, _object({}, f"messages on {name}"))
