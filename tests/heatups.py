"""The paper's first heat-up as known-truth data for identification tests."""

from __future__ import annotations

import numpy as np

from furnace_model.experiment import Experiment
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import SensorSpec, load_scenario
from furnace_model.simulation.structure import ModelStructure

TC_SD = 1.5
ZONE_SD = TC_SD / np.sqrt(2)  # zone temperature = mean of two thermocouples, both reading


def heat_up(scenarios, values, sample_min, seed=1, name="exp1", sensors=None,
            structure=None) -> Experiment:
    """The paper's first experiment's burner schedule, unbiased thermocouples (sd 1.5 °C)."""
    scn = load_scenario(scenarios / "paper_exp1.yaml")
    plant = Plant(structure or ModelStructure(furnace=PAPER), values,
                  sensors or SensorSpec(noise_sd_c=TC_SD, bias_sd_c=0.0), seed=seed)
    t = np.arange(0.0, 3300.0 + 1e-9, sample_min)
    return plant.run(scn.inputs(), t, scn.initial_c).to_experiment(name)
