"""Simulated runs through the refit pipeline (the real worker process), for the refit tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from furnace_daq.daqconfig import RefitConfig
from furnace_daq.plantlog import run_messages
from furnace_daq.refitworker import RefitRunner
from furnace_model.log.schema import MODEL_EVENTS, MODEL_PARAMETERS
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.plant import Plant, PlantRun
from furnace_model.simulation.scenario import Scenario, load_scenario

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "config" / "scenarios"


def scenario(name: str, duration_min: float | None = None) -> Scenario:
    s = load_scenario(SCENARIOS / f"{name}.yaml")
    if duration_min is not None:
        s.duration_min = duration_min
    return s


def simulate(s: Scenario, seed: int = 1) -> PlantRun:
    return Plant.from_scenario(s, seed=seed).run_scenario(s)


def window_fits(run: PlantRun, config: RefitConfig) -> list[dict]:
    """The /model/parameters message of each window of a run, cut and fitted in this
    process as the daemon's worker does."""
    from furnace_daq.refit import RefitChain, WindowCutter

    cutter, chain = WindowCutter(config, furnace=PAPER), RefitChain(config, furnace=PAPER)
    return [chain.process(w)[0].to_json() for topic, msg, t in run_messages(run)
            for w in cutter.feed(topic, msg, t)]


def assert_fits_alike(clean: list[dict], other: list[dict], rel: float = 0.05) -> None:
    """The windows of a run with something left out fit as those of the run without it."""
    assert len(clean) == len(other)
    for a, b in zip(clean, other, strict=True):
        assert b["status"] == a["status"]
        if a["status"] == "ok":
            for p in "abcdef":
                assert b[p] == pytest.approx(a[p], rel=rel), (p, a["detail"])


def through_pipeline(run: PlantRun, config: RefitConfig, messages=None, timeout: float = 120.0
                     ) -> tuple[list[dict], list[dict]]:
    """(/model/parameters messages, /model/events messages) of a run fed as the daemon feeds
    what it logs; fits in the worker process."""
    params: list[dict] = []
    events: list[dict] = []

    def emit(topic: str, msg: dict, pub_ns: int) -> None:
        (params if topic == MODEL_PARAMETERS else events).append(msg.to_json())
        assert topic in (MODEL_PARAMETERS, MODEL_EVENTS)

    runner = RefitRunner(config, emit, max_queue=None, furnace=PAPER)
    runner.start()
    try:
        for topic, msg, t in (messages if messages is not None else run_messages(run)):
            runner.feed(topic, msg, t)
            if len(runner.queue) > 2:
                runner.pump(1.0)
        assert runner.drain(timeout), "refits did not finish in time"
    finally:
        runner.close()
    return params, events
