"""When the daemon diagnoses its own furnace: the rule, on the refit's windows alone.

A diagnosis starts when a drift event fires, or when `after_windows` fitted windows in a row
miss their data by more than the noise (a zone's fit RMSE above its misfit limit, the floor
widened as the diagnosis widens it to call a gap: `ModelParameters.misfit_zones`). It looks
at the window that raised it, with the last window that fitted to its floor as reference.
Before a window has fitted to its floor there is no reference (a start-up's first windows
hold the furnace's transient) and no diagnosis. One diagnosis per episode: none again until a window fits to its floor again (the episode
is over) or a new drift event fires (a new one). Windows that were not fitted (failed, too
little excitation) neither count nor end a run.

The rule reads nothing but the windows and their messages, in order, so replay takes the
same decisions from the log as the live daemon did.
"""

from __future__ import annotations

from dataclasses import dataclass

from furnace_model.experiment import Experiment
from furnace_model.log.messages import ModelEvent, ModelEventKind, ModelParameters

from .daqconfig import DiagnosisConfig
from .refit import Window, window_seed


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

    def observe(self, window: Window, msg: ModelParameters, events: list[ModelEvent]
                ) -> DiagnosisRequest | None:
        """The window's outcome; the diagnosis it calls for, if any."""
        if not msg.fitted or window.experiment is None:
            return None
        drift = [e for e in events if e.kind == ModelEventKind.DRIFT]
        misfit = msg.misfit_zones()
        request = None
        if self.reference is None:
            pass  # nothing has fitted yet: no model to diagnose
        elif drift:
            self.fired = False  # a new episode
            request = self._request(window, "drift", "; ".join(e.detail for e in drift))
        elif misfit:
            self.misfits += 1
            if self.misfits >= self.config.after_windows and not self.fired:
                request = self._request(window, "misfit", (
                    f"{self.misfits} fitted windows in a row above their noise floor; this "
                    f"one in the {', '.join(misfit)} zone(s): "
                    + ", ".join(f"{z} {msg.rmse_c[z]:.2f} °C > {msg.misfit_limit_c[z]:.2f} °C"
                                for z in misfit)))
        if not misfit:
            self.reference, self.misfits = window, 0
            if not drift:
                self.fired = False  # the model fits again: the episode is over
        return request

    def _request(self, window: Window, trigger: str, detail: str) -> DiagnosisRequest:
        self.fired = True
        ref = self.reference
        assert window.experiment is not None and ref is not None and ref.experiment is not None
        return DiagnosisRequest(
            trigger, detail, window.experiment, (window.start_ns, window.end_ns),
            ref.experiment, (ref.start_ns, ref.end_ns), window_seed(window))
