"""Simulated runs through the refit pipeline (the real worker process), for the refit tests."""

from __future__ import annotations

from pathlib import Path

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
