"""The messages of the log's topics as typed values, one class per topic.

A message is written in one place and read in many (the resampler, the log player, the
refit, replay, export, the fleet's tasks); a field read by its string key in each of them
let a misspelt key read as "absent" without a word. Here each topic's fields are named once:
producers build a message and write its `to_json()`, readers turn a decoded dict into one
with `from_json()` at the boundary, and both sides meet the schema of schema.py, which stays
the one place the schemas are built (`topic()` delegates to `schema.topics(furnace)`).

Reading is lenient: logs written before the schema declared every field carry null for a
missing reading, and a field of the wrong type reads as absent rather than stopping an
export. A value that is absent is None here and left out of the JSON (`schema.absent`),
which is what the schemas accept and Foxglove plots as a gap.

Light at import like schema.py: a command's --help imports the topics without numpy.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, fields
from enum import StrEnum
from typing import TYPE_CHECKING, Any, ClassVar

from .schema import (
    AMBIENT,
    BURNERS,
    DAQ_EVENTS,
    DAQ_STATUS,
    DISTURBANCES,
    HEAT,
    LOG,
    MODEL_DIAGNOSIS,
    MODEL_EVENTS,
    MODEL_PARAMETERS,
    READING_FIELDS,
    SIGNALS,
    THERMOCOUPLES,
    Topic,
    absent,
    plc_time,
    time_ns,
    topics,
)

if TYPE_CHECKING:  # the furnace loads numpy: not for a command's --help (test_cli_surface)
    from ..simulation.furnace import Furnace


def number(v: object) -> float:
    """A JSON value as a float, NaN when it is not a finite number (absent, null, a string,
    a boolean): what every reader averages or plots."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        return math.nan
    return float(v) if math.isfinite(v) else math.nan


def _is_number(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _stamp(message: dict, key: str = "plc_time") -> int | None:
    """A {sec, nsec} field as ns, None when it is absent or not a time."""
    value = message.get(key)
    if not isinstance(value, dict):
        return None
    try:
        return time_ns(value)
    except (KeyError, TypeError, ValueError):
        return None


def _time_json(ns: int | None) -> dict[str, int] | None:
    return None if ns is None else plc_time(ns)


def _dict(v: object) -> dict | None:
    return v if isinstance(v, dict) else None


def _list(v: object) -> list | None:
    return v if isinstance(v, list) else None


def _str(v: object) -> str | None:
    return v if isinstance(v, str) else None


def _int(v: object) -> int | None:
    return v if isinstance(v, int) and not isinstance(v, bool) else None


def _float(v: object) -> float | int | None:
    return v if _is_number(v) else None


def _bool(v: object) -> bool | None:
    return v if isinstance(v, bool) else None


class DaqEventKind(StrEnum):
    """What a /daq/events message reports; str-valued, so the JSON carries the plain name."""

    CAN_UNAVAILABLE = "can_unavailable"
    REFIT_ERROR = "refit_error"
    STATE_WRITE_FAILED = "state_write_failed"
    ON_MODEL_ERROR = "on_model_error"
    WRITE_BACK_FAILED = "write_back_failed"
    WRITE_BACK_OK = "write_back_ok"
    CLOCK_STEP = "clock_step"
    MISSED_TICK = "missed_tick"
    BURNER_DISAGREEMENT = "burner_disagreement"
    BURNER_AGREEMENT = "burner_agreement"
    STATE_UNUSABLE = "state_unusable"
    REFIT_ABANDONED = "refit_abandoned"
    REFIT_RESUMED = "refit_resumed"
    LOG_RECOVERED = "log_recovered"
    LOG_GAP = "log_gap"
    PLC_CLOCK_RESET = "plc_clock_reset"


class ModelEventKind(StrEnum):
    """What a /model/events message reports."""

    DRIFT = "drift"
    WINDOW_DROPPED = "window_dropped"
    DIAGNOSIS = "diagnosis"
    DIAGNOSIS_FAILED = "diagnosis_failed"
    SENSOR_SET_ASIDE = "sensor_set_aside"


def _kind(value: object, kinds: type[StrEnum]) -> StrEnum | str:
    """The kind as its enum member; a kind this version does not know (a newer writer's)
    stays a string, so its message is still read and shown."""
    text = str(value) if value is not None else "event"
    try:
        return kinds(text)
    except ValueError:
        return text


class Message:
    """What every message class has: its topic's name, its schema, its JSON."""

    TOPIC: ClassVar[str]

    @classmethod
    def topic(cls, furnace: Furnace) -> Topic:
        """The topic of this class for `furnace` (schema.topics builds every schema)."""
        return topics(furnace)[cls.TOPIC]

    def to_json(self) -> dict:
        """The message as written to the log: its fields by name, absent values left out."""
        return absent({f.name: getattr(self, f.name) for f in fields(self)})  # type: ignore[arg-type]


@dataclass
class Thermocouples(Message):
    """One poll of the zone thermocouples. `values` holds the readings present (a reading
    that is not usable is left out); `quality` says why one is missing or not averaged."""

    TOPIC: ClassVar[str] = THERMOCOUPLES

    values: dict[str, float]
    quality: dict[str, str]
    plc_seconds: float | None = None
    plc_time: int | None = None
    """The PLC's clock at the reading, ns since the epoch."""
    error: str | None = None

    def to_json(self) -> dict:
        out: dict[str, Any] = dict(self.values)
        out["quality"] = self.quality
        if self.plc_seconds is not None:
            out["plc_seconds"] = self.plc_seconds
        if self.plc_time is not None:
            out["plc_time"] = plc_time(self.plc_time)
        if self.error is not None:
            out["error"] = self.error
        return out

    @classmethod
    def from_json(cls, message: dict, furnace: Furnace) -> Thermocouples:
        """Readings of `furnace`'s thermocouples; a message without a quality map has no
        good reading."""
        values = {s: v for s in furnace.sensors if _is_number(v := message.get(s))}
        quality = message.get("quality")
        return cls(values, quality if isinstance(quality, dict) else {},
                   _float(message.get("plc_seconds")), _stamp(message),
                   _str(message.get("error")))

    def reading(self, sensor: str) -> float:
        """The sensor's reading when its quality is ok, else NaN."""
        return number(self.values.get(sensor)) if self.quality.get(sensor) == "ok" else math.nan


@dataclass
class Burners(Message):
    """The burners' flame-on states of one read, by zone, with the count firing per zone.
    Logs carry both; a reader takes whichever is there (`zone_counts`, `flame_states`)."""

    TOPIC: ClassVar[str] = BURNERS

    states: dict[str, list[bool]]
    counts: dict[str, int]
    source: str | None = None
    quality: str | None = None
    plc_time: int | None = None

    def to_json(self) -> dict:
        out: dict[str, Any] = dict(self.states)
        out.update({f"count_{z}": n for z, n in self.counts.items()})
        return {**out, **absent({"source": self.source, "quality": self.quality,
                                 "plc_time": _time_json(self.plc_time)})}

    @classmethod
    def from_json(cls, message: dict, furnace: Furnace) -> Burners:
        zones = furnace.switched_zones
        states = {z: [bool(b) for b in v] for z in zones if isinstance(v := message.get(z), list)}
        counts = {z: n for z in zones if _is_number(n := message.get(f"count_{z}"))}
        return cls(states, counts, _str(message.get("source")), _str(message.get("quality")),
                   _stamp(message))

    @classmethod
    def from_states(cls, states: dict[str, list[bool]], source: str, quality: str | None,
                    plc_time_ns: int | None = None) -> Burners:
        """A message of the states read, counted per zone as the log carries them."""
        return cls(dict(states), {z: sum(v) for z, v in states.items()}, source, quality,
                   plc_time_ns)

    def zone_counts(self, furnace: Furnace) -> list[float]:
        """Burners firing per zone fired by burners (`furnace.switched`): the logged count,
        else counted from the states; NaN for a zone with neither."""
        out = []
        for z in furnace.switched_zones:
            n = self.counts.get(z)
            if n is None and z in self.states:
                n = sum(self.states[z])
            out.append(number(n))
        return out

    def flame_states(self, furnace: Furnace) -> list[bool] | None:
        """Every burner's state, zone after zone, when each zone's list is there and of
        its length; None otherwise (then only the counts say what fired)."""
        lists = [self.states.get(z) for z in furnace.switched_zones]
        sizes = [furnace.burners[i] for i in furnace.switched]
        if all(v is not None and len(v) == n for v, n in zip(lists, sizes, strict=True)):
            return [b for v in lists for b in v]  # type: ignore[union-attr]
        return None

    def integer_counts(self, furnace: Furnace) -> list[int] | None:
        """The logged counts per zone fired by burners when every such zone has an integer
        one, else None."""
        counts = [self.counts.get(z) for z in furnace.switched_zones]
        if all(isinstance(n, int) for n in counts):
            return counts  # type: ignore[return-value]
        return None


@dataclass
class Ambient(Message):
    """The ambient air temperature, or the config's default when no point is mapped."""

    TOPIC: ClassVar[str] = AMBIENT

    t_air: float | None = None
    quality: str | None = None
    """Absent means ok (older logs)."""
    from_config: bool | None = None
    plc_time: int | None = None

    def to_json(self) -> dict:
        return absent({"t_air": self.t_air, "quality": self.quality,
                       "from_config": self.from_config, "plc_time": _time_json(self.plc_time)})

    @classmethod
    def from_json(cls, message: dict) -> Ambient:
        quality = message.get("quality")  # present but not a name (null): not ok
        return cls(_float(message.get("t_air")),
                   None if "quality" not in message else str(quality),
                   _bool(message.get("from_config")), _stamp(message))

    @property
    def usable(self) -> bool:
        return (self.quality or "ok") == "ok"


@dataclass
class NamedReadings(Message):
    """One poll of values carried by name, each with its quality and its unit, as
    /furnace/thermocouples carries its readings: `values` holds the readings present (one
    that is not usable is left out), `quality` says why one is missing."""

    values: dict[str, float | bool]
    quality: dict[str, str]
    unit: dict[str, str]
    plc_time: int | None = None
    """The PLC's clock at the reading, ns since the epoch."""

    def to_json(self) -> dict:
        out: dict[str, Any] = dict(self.values)
        out["quality"], out["unit"] = self.quality, self.unit
        if self.plc_time is not None:
            out["plc_time"] = plc_time(self.plc_time)
        return out

    @classmethod
    def _read(cls, message: dict, names: Iterable[str], bits: bool = False) -> NamedReadings:
        names = tuple(names)
        values = {n: v for n in names
                  if _is_number(v := message.get(n)) or (bits and isinstance(v, bool | str))}
        quality, unit = _dict(message.get("quality")) or {}, _dict(message.get("unit")) or {}
        return cls(values, {n: str(q) for n, q in quality.items() if n in names},
                   {n: str(u) for n, u in unit.items() if n in names}, _stamp(message))

    def reading(self, name: str) -> float:
        """The value when its quality is ok (a bit as 0 or 1), else NaN."""
        if self.quality.get(name) != "ok":
            return math.nan
        v = self.values.get(name)
        return float(v) if isinstance(v, bool) else number(v)


@dataclass
class Heat(NamedReadings):
    """The heat input of each rate-fired zone (firing rate, fuel flow), by zone."""

    TOPIC: ClassVar[str] = HEAT

    @classmethod
    def from_json(cls, message: dict, furnace: Furnace) -> Heat:
        return cls._read(message, (furnace.zones[i] for i in furnace.rated))  # type: ignore[return-value]


@dataclass
class Disturbances(NamedReadings):
    """The measured disturbances the furnace declares (throughput, charging, ...), by name."""

    TOPIC: ClassVar[str] = DISTURBANCES

    @classmethod
    def from_json(cls, message: dict, furnace: Furnace) -> Disturbances:
        return cls._read(message, (d.name for d in furnace.disturbances))  # type: ignore[return-value]


@dataclass
class Signals(NamedReadings):
    """The register map's extra named points, by name: a number, a bit as a boolean, or
    text.
    Which signals there are is the map's, not the furnace's: every message names them all
    in `unit` (and `quality`), present or not."""

    TOPIC: ClassVar[str] = SIGNALS

    @classmethod
    def from_json(cls, message: dict) -> Signals:
        named = [*(_dict(message.get("unit")) or {}), *(_dict(message.get("quality")) or {})]
        names = dict.fromkeys(n for n in named if n not in READING_FIELDS)
        return cls._read(message, names, bits=True)  # type: ignore[return-value]


@dataclass
class DaqStatus(Message):
    """The connection state and the poller's counters, on every change of state."""

    TOPIC: ClassVar[str] = DAQ_STATUS

    state: str
    detail: str
    polls: int | None = None
    ok_polls: int | None = None
    comm_errors: int | None = None
    skipped_ticks: int | None = None
    connects: int | None = None
    disconnects: int | None = None
    connect_attempts: int | None = None
    can_frames: int | None = None
    disagreements: int | None = None
    failures: dict[str, int] | None = None
    incomplete: dict[str, int] | None = None
    period_s: float | None = None
    devices: dict[str, str] | None = None
    device: str | None = None
    log_error: str | None = None

    @classmethod
    def from_json(cls, message: dict) -> DaqStatus:
        values: dict[str, Any] = {}
        for f in fields(cls):
            v = message.get(f.name)
            if f.name in ("state", "detail"):
                v = "" if v is None else str(v)
            elif f.name in ("failures", "incomplete", "devices"):
                v = _dict(v)
            elif f.name in ("device", "log_error"):
                v = _str(v)
            elif f.name == "period_s":
                v = _float(v)
            else:
                v = _int(v)
            values[f.name] = v
        return cls(**values)


@dataclass
class DaqEvent(Message):
    """Something the acquisition met: a missed tick, a clock step, a log gap, PLC and flame
    scanners disagreeing. The fields after `detail` belong to particular kinds."""

    TOPIC: ClassVar[str] = DAQ_EVENTS

    kind: DaqEventKind | str
    detail: str
    skipped: int | None = None
    step_s: float | None = None
    error: str | None = None
    dropped: int | None = None
    burners: list[str] | None = None
    plc: dict[str, list[bool]] | None = None
    flame: dict[str, list[bool]] | None = None

    def to_json(self) -> dict:
        return absent({"kind": str(self.kind), "detail": self.detail,
                       "skipped": self.skipped, "step_s": self.step_s, "error": self.error,
                       "dropped": self.dropped, "burners": self.burners, "plc": self.plc,
                       "flame": self.flame})

    @classmethod
    def from_json(cls, message: dict) -> DaqEvent:
        return cls(_kind(message.get("kind"), DaqEventKind), str(message.get("detail", "")),
                   _int(message.get("skipped")), _float(message.get("step_s")),
                   _str(message.get("error")), _int(message.get("dropped")),
                   _list(message.get("burners")), _dict(message.get("plc")),
                   _dict(message.get("flame")))


@dataclass
class ModelParameters(Message):
    """One window of the online refit: the model in force after it (`params`, the furnace's
    network's parameters) and how the window went. A window that did not change the model
    carries the model in force with its own status and detail."""

    TOPIC: ClassVar[str] = MODEL_PARAMETERS

    status: str
    detail: str
    window_start: str
    window_end: str
    n_samples: int | None = None
    gap_fraction: float | None = None
    burner_steps: int | None = None
    params: dict[str, float] = field(default_factory=dict)
    """Absent before the first model."""
    ci95: dict[str, list[float]] | None = None
    rmse_c: dict[str, float] | None = None
    combinations: dict[str, dict] | None = None
    determined_combinations: list[str] | None = None
    undetermined: list[str] | None = None
    zone_offsets_c: dict[str, float] | None = None
    flags: list[dict] | None = None
    sigma_c: float | None = None
    elapsed_s: float | None = None
    search: dict | None = None
    model_window_start: str | None = None
    model_window_end: str | None = None
    recent_f: dict | None = None
    plc_time: int | None = None
    """The window's end on the PLC's clock, ns, when the register map has one."""
    noise_floor_c: dict[str, float] | None = None
    misfit_limit_c: dict[str, float] | None = None
    """Per zone, the fit RMSE above which the model misses the window: its noise floor
    widened by the floor's uncertainty, as a diagnosis judges a gap."""

    _HEAD: ClassVar[tuple[str, ...]] = ("status", "detail", "window_start", "window_end",
                                        "n_samples", "gap_fraction", "burner_steps")

    def to_json(self) -> dict:
        out: dict[str, Any] = {name: getattr(self, name) for name in self._HEAD}
        out.update(self.params)
        for f in fields(self):
            if f.name not in self._HEAD and f.name not in ("params", "plc_time"):
                out[f.name] = getattr(self, f.name)
        out["plc_time"] = _time_json(self.plc_time)
        return absent(out)

    @classmethod
    def from_json(cls, message: dict) -> ModelParameters:
        """The parameters are the numbers at the top level that are no field of the
        message: a reader without the furnace's description (the write-back, a saved
        state) reads them too. A parameter logged as null is absent."""
        names = {f.name for f in fields(cls)}
        values: dict[str, Any] = {f.name: message.get(f.name) for f in fields(cls)
                                  if f.name not in ("params", "plc_time")}
        for name in ("status", "detail", "window_start", "window_end"):
            values[name] = "" if values[name] is None else str(values[name])
        for name in ("n_samples", "burner_steps"):
            values[name] = _int(values[name])
        for name in ("gap_fraction", "sigma_c", "elapsed_s"):
            values[name] = _float(values[name])
        for name in ("ci95", "rmse_c", "combinations", "zone_offsets_c", "search", "recent_f",
                     "noise_floor_c", "misfit_limit_c"):
            values[name] = _dict(values[name])
        for name in ("determined_combinations", "undetermined", "flags"):
            values[name] = _list(values[name])
        for name in ("model_window_start", "model_window_end"):
            values[name] = _str(values[name])
        params = {p: v for p, v in message.items() if p not in names and _is_number(v)}
        return cls(**values, params=params, plc_time=_stamp(message))

    @property
    def fitted(self) -> bool:
        return self.status == "ok"

    def misfit_zones(self) -> list[str]:
        """The zones whose fit RMSE lies above their misfit limit (none unless fitted)."""
        if not self.fitted or not self.rmse_c or not self.misfit_limit_c:
            return []
        return [z for z, v in self.rmse_c.items()
                if _is_number(v) and _is_number(self.misfit_limit_c.get(z))
                and v > self.misfit_limit_c[z]]


@dataclass
class ModelEvent(Message):
    """Something the refit met: a parameter drifted, a window was dropped unfitted. The
    fields after `detail` belong to particular kinds."""

    TOPIC: ClassVar[str] = MODEL_EVENTS

    kind: ModelEventKind | str
    detail: str
    parameter: str | None = None
    basis: str | None = None
    old: float | None = None
    old_ci95: list[float] | None = None
    old_window_end: str | None = None
    new: float | None = None
    new_ci95: list[float] | None = None
    relative_change: float | None = None
    windows: int | None = None
    recent_start: str | None = None
    window_start: str | None = None
    window_end: str | None = None
    parameters: dict[str, float] | None = None
    plc_time: int | None = None

    def to_json(self) -> dict:
        out = super().to_json()
        out["kind"] = str(self.kind)
        if self.plc_time is not None:
            out["plc_time"] = plc_time(self.plc_time)
        return out

    @classmethod
    def from_json(cls, message: dict) -> ModelEvent:
        values: dict[str, Any] = {f.name: message.get(f.name) for f in fields(cls)
                                  if f.name not in ("kind", "detail", "plc_time")}
        for name in ("parameter", "basis", "old_window_end", "recent_start", "window_start",
                     "window_end"):
            values[name] = _str(values[name])
        for name in ("old", "new", "relative_change"):
            values[name] = _float(values[name])
        for name in ("old_ci95", "new_ci95"):
            values[name] = _list(values[name])
        values["windows"] = _int(values["windows"])
        values["parameters"] = _dict(values["parameters"])
        return cls(_kind(message.get("kind"), ModelEventKind), str(message.get("detail", "")),
                   **values, plc_time=_stamp(message))


@dataclass
class ModelDiagnosis(Message):
    """An online diagnosis's verdict (refit.diagnosis): what the refit's model misses, judged
    on data the candidates were not fitted on. `fitted` and `held_out` are lists of
    {start, end}; `effects` of {effect, options, params}; `where` as the diagnosis locates
    its error; `cut` names what the time limit cut, so that replay repeats the verdict."""

    TOPIC: ClassVar[str] = MODEL_DIAGNOSIS

    status: str
    detail: str
    trigger: str
    trigger_detail: str = ""
    effects: list[dict] = field(default_factory=list)
    sensor: dict | None = None
    where: list[dict] = field(default_factory=list)
    shrink_pct: float | None = None
    gap_closed_pct: float | None = None
    rmse_holdout_c: dict[str, float] | None = None
    noise_floor_c: dict[str, float] | None = None
    fitted: list[dict] = field(default_factory=list)
    held_out: list[dict] = field(default_factory=list)
    reference_window: dict | None = None
    effects_tried: list[str] | None = None
    untried: list[str] = field(default_factory=list)
    cut: list[str] = field(default_factory=list)
    seed: int | None = None
    time_limit_s: float | None = None
    elapsed_s: float | None = None
    plc_time: int | None = None

    def to_json(self) -> dict:
        out = super().to_json()
        if self.plc_time is not None:
            out["plc_time"] = plc_time(self.plc_time)
        return out

    @classmethod
    def from_json(cls, message: dict) -> ModelDiagnosis:
        values: dict[str, Any] = {f.name: message.get(f.name) for f in fields(cls)
                                  if f.name != "plc_time"}
        for name in ("status", "detail", "trigger", "trigger_detail"):
            values[name] = "" if values[name] is None else str(values[name])
        for name in ("effects", "where", "fitted", "held_out", "untried", "cut"):
            values[name] = _list(values[name]) or []
        for name in ("sensor", "rmse_holdout_c", "noise_floor_c", "reference_window"):
            values[name] = _dict(values[name])
        for name in ("shrink_pct", "gap_closed_pct", "time_limit_s", "elapsed_s"):
            values[name] = _float(values[name])
        values["effects_tried"] = _list(values["effects_tried"])
        values["seed"] = _int(values["seed"])
        return cls(**values, plc_time=_stamp(message))


@dataclass
class LogLine(Message):
    """One line of /log (foxglove.Log), for Foxglove's log panel."""

    TOPIC: ClassVar[str] = LOG

    timestamp: int
    """ns since the epoch."""
    level: int
    message: str
    name: str
    file: str = ""
    line: int = 0

    def to_json(self) -> dict:
        return {"timestamp": plc_time(self.timestamp), "level": int(self.level),
                "message": self.message, "name": self.name, "file": self.file,
                "line": int(self.line)}

    @classmethod
    def from_json(cls, message: dict) -> LogLine:
        return cls(_stamp(message, "timestamp") or 0, int(message.get("level", 0)),
                   str(message.get("message", "")), str(message.get("name", "")),
                   str(message.get("file", "")), int(message.get("line", 0)))


Event = DaqEvent | ModelEvent
FurnaceMessage = Thermocouples | Burners | Ambient | Heat | Disturbances | Signals
AnyMessage = Thermocouples | Burners | Ambient | Heat | Disturbances | Signals | DaqStatus | \
    DaqEvent | ModelParameters | ModelEvent | ModelDiagnosis | LogLine

CLASSES: dict[str, type[Message]] = {c.TOPIC: c for c in (
    Thermocouples, Burners, Ambient, Heat, Disturbances, Signals, DaqStatus, DaqEvent,
    ModelParameters, ModelEvent, ModelDiagnosis, LogLine)}
"""The message class of each topic of the contract."""


def from_json(topic: str, message: dict, furnace: Furnace) -> AnyMessage:
    """A decoded message of a topic of the contract as its class (KeyError for another
    topic)."""
    cls = CLASSES[topic]
    if cls in (Thermocouples, Burners, Heat, Disturbances):
        return cls.from_json(message, furnace)  # type: ignore[attr-defined]
    return cls.from_json(message)  # type: ignore[attr-defined]


def as_message(topic: str, message: AnyMessage | dict, furnace: Furnace) -> AnyMessage:
    """`message` as its class: a decoded dict is converted, a message is taken as it is."""
    return from_json(topic, message, furnace) if isinstance(message, dict) else message


def typed(records: Iterable[tuple[str, dict, int, int]], furnace: Furnace
          ) -> Iterator[tuple[str, AnyMessage, int, int]]:
    """read_messages' (topic, message, log ns, publish ns) with each message as its class.
    A message handed over as the same dict as the one before (a repeat read_messages
    decoded once) is the same object here too, so a reader can skip it as cheaply."""
    last_raw: tuple[str, dict] | None = None
    last: AnyMessage | None = None
    for topic, raw, log_ns, pub_ns in records:
        if last is None or last_raw is None or raw is not last_raw[1] or topic != last_raw[0]:
            last_raw, last = (topic, raw), from_json(topic, raw, furnace)
        yield topic, last, log_ns, pub_ns
