"""Online identification as the daemon hosts it: the furnace messages it logs fed to the
refit runner (refitworker), finished fits taken from it once per tick, their messages
logged, handed to `on_model` and saved as state files, and the chain resumed from the state
a previous run left.

Refits are a guest of the acquisition: whatever goes wrong in them, the runner, a consumer
of the models or the state files, is an event on /daq/events, never the end of polling, and
nothing here waits on a fit except the bounded wait at stop.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable

from furnace_model.log.messages import (
    DaqEvent,
    DaqEventKind,
    Event,
    FurnaceMessage,
    ModelDiagnosis,
    ModelEvent,
    ModelParameters,
)
from furnace_model.simulation.furnace import Furnace

from .daqconfig import RefitConfig
from .refitworker import RefitRunner
from .statewriter import StateWriter

STOP_WAIT_S = 10.0
"""At stop, how long windows already cut may still be fitted."""


class RefitPump:
    def __init__(self, config: RefitConfig, *, t_air_default: float, furnace: Furnace,
                 wall_ns: Callable[[], int],
                 log_write: Callable[[str, dict, int, int], None],
                 event: Callable[[DaqEvent, int], None],
                 tell: Callable[[Event], None],
                 plc_clock_seen: Callable[[], bool],
                 on_model: Callable[[dict], None] | None = None):
        """`log_write(topic, message, log_ns, pub_ns)` logs a model message, `event(message,
        now_ns)` logs and tells a /daq/events message, `tell` tells the journal of a model
        event, and `plc_clock_seen()` says whether the data clock is the PLC's."""
        self.config = config
        self.wall_ns, self.log_write, self.event, self.tell = wall_ns, log_write, event, tell
        self.plc_clock_seen = plc_clock_seen
        self.on_model = on_model
        self.runner = RefitRunner(config, self._model_message,
                                  t_air_default=t_air_default,
                                  max_queue=config.queue_max, furnace=furnace)
        self.state = StateWriter(config.state_dir, self._event_now)
        self._model: dict | None = None  # the last /model/parameters message, as logged
        self._diagnosis: dict | None = None  # the last /model/diagnosis message

    def start(self) -> None:
        self.resume()
        self.runner.start()
        self.state.start()

    def feed(self, message: FurnaceMessage, pub_ns: int) -> None:
        """One logged furnace message, at its publish time (the data clock)."""
        self._guarded(self.runner.feed, message.TOPIC, message, pub_ns)

    def pump(self) -> None:
        """Take finished fits and start the next; never waits."""
        self._guarded(self.runner.pump)
        self.state.report()

    async def finish(self, watchdog: Callable[[], None]) -> None:
        """At stop: give the windows already cut their fit (bounded), then end the worker;
        `watchdog` keeps systemd from taking the wait for a hang."""
        runner = self.runner
        # systemd gives a stopping unit 30 s (TimeoutStopSec): a fit in hand gets part of it
        deadline = time.monotonic() + min(runner.kill_after_s, STOP_WAIT_S)
        while runner.busy() and time.monotonic() < deadline:
            self.pump()
            watchdog()
            await asyncio.sleep(0.01)
        left = len(runner.queue) + (runner.in_flight is not None)
        if left:
            now = self.wall_ns()
            self.event(DaqEvent(DaqEventKind.REFIT_ABANDONED,
                                f"{left} refit window(s) not fitted at stop"), now)
        runner.close()
        self.state.close()

    def _event_now(self, message: DaqEvent) -> None:
        self.event(message, self.wall_ns())

    def _guarded(self, call: Callable, *args) -> None:
        """Online identification is a guest of the acquisition: whatever goes wrong in it is
        an event, never the end of polling."""
        try:
            call(*args)
        except Exception as exc:  # noqa: BLE001
            now = self.wall_ns()
            self.event(DaqEvent(DaqEventKind.REFIT_ERROR,
                                f"refit pipeline: {type(exc).__name__}: {exc}"), now)

    def _model_message(self, topic: str, message: ModelParameters | ModelEvent | ModelDiagnosis,
                       pub_ns: int) -> None:
        if self.plc_clock_seen():  # the data clock is the PLC's: say so in its field
            message.plc_time = pub_ns
        data = message.to_json()
        self.log_write(topic, data, self.wall_ns(), pub_ns)
        if isinstance(message, ModelEvent):
            self.tell(message)
            return
        if isinstance(message, ModelDiagnosis):
            # model.json carries the last diagnosis beside the model in force
            self._diagnosis = data
            if self._model is not None:
                self.state.save({**self._model, "diagnosis": data}, None)
            return
        self._model = data
        if self.on_model is not None:  # a consumer sees the message as logged
            try:
                self.on_model(data)
            except Exception as exc:  # noqa: BLE001 - a consumer's bug is not ours to die of
                now = self.wall_ns()
                self.event(DaqEvent(DaqEventKind.ON_MODEL_ERROR,
                                    f"{type(exc).__name__}: {exc}"), now)
        # the chain has taken this window in already: its state goes with the model
        saved = data if self._diagnosis is None else {**data, "diagnosis": self._diagnosis}
        self.state.save(saved, self.runner.state())

    def resume(self) -> None:
        """Go on with the model in force, the drift references and the diagnosis episode a
        previous run left, so that a restart neither forgets the model nor starts drift
        detection or the episode afresh. A state file that cannot be used is reported and
        set aside; the chain then starts empty."""
        path = self.state.chain_path
        now = self.wall_ns()
        try:
            self.runner.restore(json.loads(path.read_text(encoding="utf-8")))
        except FileNotFoundError:
            return
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            detail = f"{path}: {getattr(exc, 'strerror', None) or exc}; refits start afresh"
            self.event(DaqEvent(DaqEventKind.STATE_UNUSABLE, detail), now)
            return
        model = self.runner.chain.model
        detail = (f"from {path}: model of the window to {model.window_end}"
                  if model is not None else f"from {path}: no model fitted yet")
        self.event(DaqEvent(DaqEventKind.REFIT_RESUMED, detail), now)
