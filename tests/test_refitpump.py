"""The refit pump without a worker process: a model message is logged, handed to the
consumer and saved; a consumer that raises is an event, not a stop; a model event goes to
the journal only; the chain resumes from a state file, or reports one it cannot use."""

from __future__ import annotations

import json
from pathlib import Path

from daq_processes import config

from furnace_daq.daqconfig import RefitConfig
from furnace_daq.refitpump import RefitPump
from furnace_daq.statewriter import CHAIN_FILE, MODEL_FILE
from furnace_model.log.messages import (
    DaqEvent,
    DaqEventKind,
    Event,
    ModelEvent,
    ModelEventKind,
    ModelParameters,
)
from furnace_model.log.schema import MODEL_EVENTS, MODEL_PARAMETERS


class Seen:
    def __init__(self) -> None:
        self.logged: list[tuple[str, dict, int, int]] = []
        self.events: list[DaqEvent] = []
        self.told: list[Event] = []
        self.models: list[dict] = []


def pump(state_dir: Path, seen: Seen, on_model=None) -> RefitPump:
    return RefitPump(RefitConfig(state_dir=state_dir), t_air_default=30.0,
                     furnace=config(1).furnace, wall_ns=lambda: 123,
                     log_write=lambda *args: seen.logged.append(args),
                     event=lambda message, _now: seen.events.append(message),
                     tell=seen.told.append, plc_clock_seen=lambda: True, on_model=on_model)


def model() -> ModelParameters:
    return ModelParameters("ok", "fitted", "2026-01-01T00:00:00Z", "2026-01-02T00:00:00Z",
                           params={"f": 0.1})


def test_a_model_is_logged_on_the_plc_clock_handed_on_and_saved_with_the_chain(tmp_path):
    seen = Seen()
    p = pump(tmp_path, seen, on_model=seen.models.append)
    p.state.start()
    p.runner.emit(MODEL_PARAMETERS, model(), 5)
    p.state.close()
    topic, data, log_ns, pub_ns = seen.logged[0]
    assert (topic, log_ns, pub_ns) == (MODEL_PARAMETERS, 123, 5)
    assert seen.models == [data] and data["plc_time"] is not None
    assert json.loads((tmp_path / MODEL_FILE).read_text()) == data
    assert (tmp_path / CHAIN_FILE).exists() and seen.events == []


def test_a_consumer_that_raises_is_an_event_and_the_model_is_still_saved(tmp_path):
    seen = Seen()

    def broken(_data: dict) -> None:
        raise RuntimeError("consumer bug")

    p = pump(tmp_path, seen, on_model=broken)
    p.state.start()
    p.runner.emit(MODEL_PARAMETERS, model(), 5)
    p.state.close()
    assert [e.kind for e in seen.events] == [DaqEventKind.ON_MODEL_ERROR]
    assert seen.events[0].detail == "RuntimeError: consumer bug"
    assert (tmp_path / MODEL_FILE).exists()


def test_a_model_event_is_told_and_logged_but_not_a_model(tmp_path):
    seen = Seen()
    p = pump(tmp_path, seen, on_model=seen.models.append)
    p.runner.emit(MODEL_EVENTS, ModelEvent(ModelEventKind.DRIFT, "f moved"), 5)
    assert [t for t, *_ in seen.logged] == [MODEL_EVENTS]
    assert [e.kind for e in seen.told] == [ModelEventKind.DRIFT] and seen.models == []


def test_the_chain_resumes_from_its_state_or_reports_one_it_cannot_use(tmp_path):
    seen = Seen()
    pump(tmp_path, seen).resume()  # no state file: a first start, nothing to say
    assert seen.events == []
    (tmp_path / CHAIN_FILE).write_text(json.dumps(pump(tmp_path, Seen()).runner.chain.state()))
    pump(tmp_path, seen).resume()
    (tmp_path / CHAIN_FILE).write_text("{not json")
    pump(tmp_path, seen).resume()
    assert [e.kind for e in seen.events] == [DaqEventKind.REFIT_RESUMED,
                                             DaqEventKind.STATE_UNUSABLE]
    assert seen.events[0].detail.endswith("no model fitted yet")
    assert seen.events[1].detail.endswith("refits start afresh")
