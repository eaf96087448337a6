"""When the daemon diagnoses its own furnace: the rule, on the refit's windows alone.

A diagnosis starts when a drift event fires, or when `after_windows` fitted windows in a row
miss their data by more than the noise (a zone's fit RMSE above its misfit limit, the floor
widened as the diagnosis widens it to call a gap: `ModelParameters.misfit_zones`). It looks
at the window that raised it, with the last window that fitted to its floor as reference.
Before a window has fitted to its floor there is no reference (a start-up's first windows
hold the furnace's transient) and no diagnosis. One diagnosis per episode: none again until
a window fits to its floor again (the episode is over), a new drift event fires, or a
thermocouple is set aside (`Window.set_aside`: the windows hold other readings from then on);
each of those opens a new one. Windows that were not fitted (failed, too little excitation)
neither count nor end a run.

When. The diagnosis fits the first 1 - TAIL_SHARE of the window and judges the rest: an
effect that began in the held-out part cannot be fitted, only missed (a fuel change seen by a
window's last hours would be 'unexplained'). The change came after the reference ended (that
window fitted; or after the window whose verdict set a thermocouple aside, which the model
with the drift explained), so the request waits for the first window whose fitted part
reaches `CHANGE_SHARE` of a window beyond that end: with a window of 36 h every 6 h, the
third after it.

The rule reads nothing but the windows and their messages, in order, so replay takes the
same decisions from the log as the live daemon did.

A restarted daemon goes on with the episode (`state`, saved with the refit chain's): the
reference window, data and all, the count of misfits and what is pending. A request that
had no verdict when the daemon stopped is asked again of the first misfit window after.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass

import numpy as np
import pandas as pd

from furnace_model.diagnosis.holdout import TAIL_SHARE
from furnace_model.experiment import Experiment
from furnace_model.log.messages import ModelEvent, ModelEventKind, ModelParameters
from furnace_model.simulation.furnace import Furnace

from .daqconfig import DiagnosisConfig
from .refit import Window, window_seed

CHANGE_SHARE = 0.1
"""How much of a window after the reference's end the fitted part must hold: enough samples
after a change to fit the effect's parameters (2.4 h of a day-long window)."""


@dataclass(frozen=True)
class DiagnosisRequest:
    """One diagnosis to run: the window that raised it, the reference and why."""

    trigger: str  # drift | misfit
    trigger_detail: str
    recent: Experiment
    recent_span: tuple[int, int]  # [start, end) ns on the data clock
    reference: Experiment
    reference_span: tuple[int, int]
    seed: int

    @property
    def key(self) -> int:
        """The end of the window that raised it, ns: the publish time of its
        /model/diagnosis message, by which replay finds the logged one."""
        return self.recent_span[1]


class DiagnosisTrigger:
    def __init__(self, config: DiagnosisConfig):
        self.config = config
        self.reference: Window | None = None
        """The last window fitted to its floor."""
        self.misfits = 0
        self.fired = False
        """A diagnosis was requested in this episode."""
        self.pending: tuple[str, str, int] | None = None
        """The episode's trigger, its detail and `fit_until` when it opened, while its
        request waits for a window whose fitted part holds the change."""
        self.set_aside: tuple[str, ...] = ()
        self.fit_until: int | None = None
        """The end of the last window the model fitted, or that a verdict which set a
        thermocouple aside explained: a change the episode diagnoses came after it."""

    def observe(self, window: Window, msg: ModelParameters, events: list[ModelEvent]
                ) -> DiagnosisRequest | None:
        """The window's outcome; the diagnosis it calls for, if any."""
        if not msg.fitted or window.experiment is None:
            return None
        if window.set_aside != self.set_aside:  # the readings changed: a new episode
            self.set_aside = window.set_aside
            self.misfits, self.fired, self.pending = 0, False, None
            if window.explained_until is not None:
                self.fit_until = max(self.fit_until or 0, window.explained_until)
        drift = [e for e in events if e.kind == ModelEventKind.DRIFT]
        misfit = msg.misfit_zones()
        if self.reference is not None:  # else nothing has fitted yet: no model to diagnose
            if drift:  # a new episode
                self.fired = False
                assert self.fit_until is not None  # set with the reference
                self.pending = ("drift", "; ".join(e.detail for e in drift), self.fit_until)
            elif misfit:
                self.misfits += 1
                if self.misfits >= self.config.after_windows and not self.fired \
                        and self.pending is None and self.fit_until is not None:
                    self.pending = ("misfit", (
                        f"{self.misfits} fitted windows in a row above their noise floor; "
                        f"this one in the {', '.join(misfit)} zone(s): "
                        + ", ".join(f"{z} {msg.rmse_c[z]:.2f} °C > "
                                    f"{msg.misfit_limit_c[z]:.2f} °C" for z in misfit)),
                        self.fit_until)
        request = None
        if self.pending is not None and (misfit or self.pending[0] == "drift") \
                and _holds(window, self.pending[2]):
            request = self._request(window, *self.pending[:2])
        if not misfit:
            self.reference, self.misfits, self.fit_until = window, 0, window.end_ns
            if not drift and (self.pending is None or self.pending[0] == "misfit"):
                # the model fits again: the episode is over
                self.fired, self.pending = False, None
        return request

    def state(self, unanswered: DiagnosisRequest | None = None) -> dict:
        """The episode as plain JSON; `unanswered`: the oldest request without a verdict,
        which the restarted daemon asks again (its windows are gone with the process)."""
        fired, pending = self.fired, self.pending
        if unanswered is not None:
            fired, pending = False, (unanswered.trigger, unanswered.trigger_detail, 0)
        return {"reference": None if self.reference is None else _window_state(self.reference),
                "misfits": self.misfits, "fired": fired,
                "pending": None if pending is None else list(pending),
                "set_aside": list(self.set_aside), "fit_until": self.fit_until}

    @classmethod
    def from_state(cls, config: DiagnosisConfig, state: object, furnace: Furnace
                   ) -> DiagnosisTrigger:
        """A trigger that goes on from a saved `state()`; ValueError, naming what is wrong,
        for anything that is not one."""
        out = cls(config)
        try:
            if not isinstance(state, dict):
                raise TypeError("not a mapping")
            ref = state["reference"]
            out.reference = None if ref is None else _window_from(ref, furnace)
            out.misfits, out.fired = int(state["misfits"]), bool(state["fired"])
            p = state["pending"]
            out.pending = None if p is None else (str(p[0]), str(p[1]), int(p[2]))
            out.set_aside = tuple(str(x) for x in state["set_aside"])
            until = state["fit_until"]
            out.fit_until = None if until is None else int(until)
        except (KeyError, TypeError, IndexError, ValueError, AttributeError) as exc:
            raise ValueError(f"malformed diagnosis trigger state ({type(exc).__name__}: "
                             f"{exc})") from None
        return out

    def _request(self, window: Window, trigger: str, detail: str) -> DiagnosisRequest:
        self.fired, self.pending = True, None
        ref = self.reference
        assert window.experiment is not None and ref is not None and ref.experiment is not None
        return DiagnosisRequest(
            trigger, detail, window.experiment, (window.start_ns, window.end_ns),
            ref.experiment, (ref.start_ns, ref.end_ns), window_seed(window))


def _holds(window: Window, change_after_ns: int) -> bool:
    """Whether the window's fitted part reaches CHANGE_SHARE of a window past the change.
    A window cut at an outage holds only the rows after it, and the diagnosis fits the
    first part of those."""
    span = window.end_ns - window.start_ns
    start = window.outage[1] if window.outage else window.start_ns
    return start + (1 - TAIL_SHARE) * (window.end_ns - start) \
        >= change_after_ns + CHANGE_SHARE * span


def _packed(a: np.ndarray) -> dict:
    """An array as JSON, exact and NaN-safe: its shape and its float64 bytes in base64."""
    a = np.ascontiguousarray(a, dtype="<f8")
    return {"shape": list(a.shape), "f8": base64.b64encode(a.tobytes()).decode("ascii")}


def _unpacked(d: dict) -> np.ndarray:
    return np.frombuffer(base64.b64decode(d["f8"], validate=True),
                         dtype="<f8").reshape(d["shape"]).copy()


def _window_state(w: Window) -> dict:
    e = w.experiment
    return {"start_ns": w.start_ns, "end_ns": w.end_ns, "expected_bins": w.expected_bins,
            "complete_bins": w.complete_bins, "burner_steps": w.burner_steps,
            "set_aside": list(w.set_aside), "explained_until": w.explained_until,
            "outage": None if w.outage is None else list(w.outage),
            "experiment": None if e is None else {
                "name": e.name, "source": e.source,
                "start_ns": None if e.start_time is None else int(e.start_time.value),
                **{k: _packed(getattr(e, k)) for k in ("t_min", "tc", "burners", "t_air",
                                                      "disturbances")}}}


def _window_from(d: dict, furnace: Furnace) -> Window:
    e = d["experiment"]
    exp = None if e is None else Experiment(
        str(e["name"]), *(_unpacked(e[k]) for k in ("t_min", "tc", "burners", "t_air")),
        None if e["start_ns"] is None else pd.Timestamp(int(e["start_ns"]), unit="ns", tz="UTC"),
        str(e["source"]), furnace=furnace, disturbances=_unpacked(e["disturbances"]))
    if exp is not None and exp.tc.shape[1] != len(furnace.sensors):
        raise ValueError(f"its reference window holds {exp.tc.shape[1]} thermocouples, the "
                         f"furnace {len(furnace.sensors)}")
    outage = d["outage"]
    return Window(int(d["start_ns"]), int(d["end_ns"]), exp, int(d["expected_bins"]),
                  int(d["complete_bins"]), int(d["burner_steps"]),
                  tuple(str(x) for x in d["set_aside"]),
                  None if d["explained_until"] is None else int(d["explained_until"]),
                  None if outage is None else (int(outage[0]), int(outage[1])))
