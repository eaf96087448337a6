"""Recorded furnace data as the simulated PLC's value source: a daemon polling
`sim-plc --from-log` sees the plant of the log again, on the same wire map.

Time base: the publish time (the PLC clock when the recording PLC had one), counted from the
log's first furnace message; the served PLC clock is that count in whole seconds. Values are
held from the instant they were recorded until the next recorded value (sample and hold), so
polling at the recorded PLC seconds returns exactly the recorded values.

What is served: each thermocouple's recorded number (a `stale` reading keeps its number); a
reading logged as null (open circuit, out of range) as the open-circuit sentinel. Polls that
failed in the recording (every quality `comm_error`) carry no PLC values and are skipped: the
values before them hold. The heat inputs of rate-fired zones, the disturbances and the
signals are served as recorded, each `ok` value held until the next. Burner states are the PLC's (`source: modbus`) when the log has them,
else the flame scanners' (`source: can`, time-stamped by the gateway clock and moved onto the
PLC clock with the offset of the nearest thermocouple reading).

Which furnace: the one the log's metadata record describes (the paper's for a log without
one), so its thermocouples and burners are served in that furnace's order.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from furnace_model.errors import DataError
from furnace_model.log.messages import (
    Ambient,
    Burners,
    Disturbances,
    Heat,
    NamedReadings,
    Thermocouples,
    number,
    typed,
)
from furnace_model.log.read import (
    iso_time,
    log_furnace,
    read_messages,
    read_metadata,
    recorded_signals,
)
from furnace_model.log.schema import FURNACE_TOPICS, THERMOCOUPLES
from furnace_model.simulation.furnace import Furnace

from .registers import COMM_ERROR
from .simplc import PlcValues, n_states, states_from_counts

_NS = 1_000_000_000


class LogPlayer:
    """Values of one or more log files (a rotated series is merged in time) at any PLC
    second. With `loop`, the recording repeats: second s shows second s mod `cycle_s`."""

    def __init__(self, paths: Sequence[str | Path] | str | Path, *, loop: bool = False):
        self.paths = [Path(paths)] if isinstance(paths, str | Path) else [Path(p) for p in paths]
        self.loop = loop
        names = ", ".join(map(str, self.paths))
        files = sorted(f for p in self.paths for f in ([p] if not p.is_dir() else p.glob("*.mcap*")))
        self.furnace = log_furnace(files, names)
        """The furnace of the log, from its metadata record."""
        self.signals = recorded_signals(read_metadata(files))
        """The extra signals of the recording's map, from its metadata record."""
        tc, air, burners, named = _read(self.paths, names, self.furnace)
        if not tc:
            raise DataError(names, f"no thermocouple readings on {THERMOCOUPLES}: "
                                   "not a furnace acquisition log")
        tc_t = np.array([r[0] for r in tc], dtype=np.int64)
        self.origin_ns = int(min([tc_t.min()] + [r[0] for r in air] + [r[0] for r in burners]))
        self._tc_t = tc_t - self.origin_ns
        self._tc = np.array([r[1] for r in tc], dtype=float)
        order = np.argsort(self._tc_t, kind="stable")
        self._tc_t, self._tc = self._tc_t[order], self._tc[order]
        self._air_t, self._air = _series(air, self.origin_ns)
        self._burner_t, self._burners = _series(burners, self.origin_ns)
        self._named = {key: {n: _series(r, self.origin_ns) for n, r in by_name.items()}
                       for key, by_name in named.items()}
        last_ns = max(int(t[-1]) for t in (self._tc_t, self._air_t, self._burner_t) if t.size)
        self.last_s = -(-last_ns // _NS)
        """The PLC second of the last recorded value (rounded up)."""
        steps = np.diff(self._tc_t)
        step_s = float(np.median(steps)) / _NS if steps.size else 1.0
        self.cycle_s = self.last_s + max(1, math.ceil(step_s))
        """Length of one pass with `loop`: the recording plus one recording period."""
        self.end_s: int | None = None if loop else self.last_s

    @property
    def n_readings(self) -> int:
        return len(self._tc_t)

    def describe(self) -> str:
        """One line for the operator: what is served, over how long."""
        hours = self.last_s / 3600.0
        burners = (f"{len(self._burner_t)} burner states" if self._burner_t.size
                   else "no burner states (all served off)")
        air = f"{len(self._air_t)} ambient" if self._air_t.size else "no ambient (served open)"
        return (f"{self.n_readings} thermocouple readings, {burners}, {air} over "
                f"{hours:.2f} h (PLC seconds 0-{self.last_s})"
                + (f", looping every {self.cycle_s} s" if self.loop else ""))

    def values_at(self, plc_seconds: int) -> PlcValues:
        s = int(plc_seconds) % self.cycle_s if self.loop else int(plc_seconds)
        t = s * _NS
        tc = self._tc[_held(self._tc_t, t)]
        air = float(self._air[_held(self._air_t, t)][0]) if self._air_t.size else math.nan
        if self._burner_t.size:
            states = [bool(v) for v in self._burners[_held(self._burner_t, t)]]
        else:
            states = [False] * n_states(self.furnace)
        held = {key: {n: v[_held(times, t)][0] for n, (times, v) in by_name.items()}
                for key, by_name in self._named.items()}
        return PlcValues([float(v) for v in tc], air, states, held["heat"],
                         held["disturbances"],
                         {n: bool(v) if n in self._bits else float(v)
                          for n, v in held["signals"].items()})

    @property
    def _bits(self) -> set[str]:
        """The signals the recording's map reads as bits."""
        return {s.name for s in self.signals if s.bit}


def _held(times: np.ndarray, t: int) -> int:
    """Index of the value in force at t: the last recorded at or before t (before the first,
    the first)."""
    return max(int(np.searchsorted(times, t, side="right")) - 1, 0)


def _series(records: list[tuple[int, list]], origin_ns: int) -> tuple[np.ndarray, np.ndarray]:
    if not records:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 1))
    records = sorted(records, key=lambda r: r[0])
    return (np.array([r[0] for r in records], dtype=np.int64) - origin_ns,
            np.array([r[1] for r in records], dtype=float))


def _read(paths: Iterable[Path], names: str, furnace: Furnace
          ) -> tuple[list, list, list, dict[str, dict[str, list]]]:
    """(publish ns, values) per topic, failed polls left out; burner states of one source;
    the `ok` values of heat inputs, disturbances and signals by name."""
    tc: list[tuple[int, list[float]]] = []
    tc_offsets: list[tuple[int, int]] = []  # (log ns, publish - log ns) of PLC readings
    air: list[tuple[int, list[float]]] = []
    plc_burners: list[tuple[int, list[bool]]] = []
    can_burners: list[tuple[int, list[bool]]] = []
    named: dict[str, dict[str, list]] = {"heat": {}, "disturbances": {}, "signals": {}}
    for topic, msg, log_ns, pub_ns in typed(read_messages(paths, FURNACE_TOPICS), furnace):
        where = f"{names}: {topic} at {iso_time(log_ns)}"
        if isinstance(msg, NamedReadings):
            key = ("heat" if isinstance(msg, Heat)
                   else "disturbances" if isinstance(msg, Disturbances) else "signals")
            for n in msg.values:
                value = msg.reading(n)
                if math.isfinite(value):
                    named[key].setdefault(n, []).append((pub_ns, [value]))
        elif isinstance(msg, Thermocouples):
            if all(msg.quality.get(s) == COMM_ERROR for s in furnace.sensors):
                continue
            tc.append((pub_ns, [number(msg.values.get(s)) for s in furnace.sensors]))
            tc_offsets.append((log_ns, pub_ns - log_ns))
        elif isinstance(msg, Ambient):
            if msg.quality == COMM_ERROR:
                continue
            air.append((pub_ns, [number(msg.t_air)]))
        elif isinstance(msg, Burners) and msg.source == "can":
            can_burners.append((log_ns, _states(msg, where, furnace)))
        elif isinstance(msg, Burners):
            plc_burners.append((pub_ns, _states(msg, where, furnace)))
    burners = plc_burners
    if not burners and can_burners and tc_offsets:
        logs = np.array([t for t, _ in tc_offsets], dtype=np.int64)
        offsets = [o for _, o in tc_offsets]
        burners = [(t + offsets[max(int(np.searchsorted(logs, t, side="right")) - 1, 0)], s)
                   for t, s in can_burners]
    return tc, air, burners, named


def _states(msg: Burners, where: str, furnace: Furnace) -> list[bool]:
    """The flame states of a burner message, zone after zone (from the counts when the lists
    are absent)."""
    states = msg.flame_states(furnace)
    if states is not None:
        return states
    counts = msg.integer_counts(furnace)
    if counts is not None:
        return states_from_counts(np.array(counts), furnace)
    raise DataError(where, f"no burner states or counts in {msg.to_json()}")
