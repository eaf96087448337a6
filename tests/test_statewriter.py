"""The state files written from the writer thread, in a temporary directory: both files
written whole, a failure reported once when it appears and again only when it changes."""

from __future__ import annotations

import json
from pathlib import Path

from furnace_daq.statewriter import CHAIN_FILE, MODEL_FILE, StateWriter
from furnace_model.log.messages import DaqEvent, DaqEventKind


def test_the_model_and_the_chain_are_written_and_nothing_before_start(tmp_path: Path):
    events: list[DaqEvent] = []
    writer = StateWriter(tmp_path / "state", events.append)
    writer.save({"a": 1}, {"version": 1})  # not started: nothing is written
    writer.start()
    writer.save({"a": 2}, {"version": 2})
    writer.close()
    assert json.loads((tmp_path / "state" / MODEL_FILE).read_text()) == {"a": 2}
    assert json.loads((tmp_path / "state" / CHAIN_FILE).read_text()) == {"version": 2}
    assert events == []


def test_a_failing_write_is_one_event_until_it_succeeds_again(tmp_path: Path):
    state = tmp_path / "state"
    state.write_text("a file where the directory should be")
    events: list[DaqEvent] = []
    writer = StateWriter(state, events.append)
    writer.start()
    for _ in range(3):
        writer.save({"a": 1}, None)
        writer.close()
        writer.start()
    assert len(events) == 1 and events[0].kind == DaqEventKind.STATE_WRITE_FAILED
    assert events[0].detail.startswith(f"latest model not saved: {state / MODEL_FILE}")
    state.unlink()
    writer.save({"a": 1}, None)
    writer.close()
    assert len(events) == 1 and (state / MODEL_FILE).exists()
    state.joinpath(MODEL_FILE).unlink()
    state.rmdir()
    state.write_text("broken again")
    writer.start()
    writer.save({"a": 1}, None)
    writer.close()
    assert len(events) == 2  # a failure after a success is news again
