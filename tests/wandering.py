"""Known-truth records with a disturbance no candidate effect can represent: a held-out
heat-up whose ambient temperature wanders slowly (a few degrees over hours, as an unlogged
draught or a neighbouring furnace would make it) while the record says it is constant.
Through the loss of the zone open to ambient, that is a slow random heat input into that
zone, which the data never show: what measured records carry and the candidates cannot
follow."""

from __future__ import annotations

import numpy as np

from furnace_model.diagnosis.cases import SENSORS_SPEC, Case, network_truth
from furnace_model.effects import EFFECTS
from furnace_model.experiment import Experiment
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.structure import Inputs, ModelStructure

WANDER_RMS_C = 6.0
"""The ambient's unlogged wander (RMS, °C): on the paper's furnace it moves the preheating
zone by about 3 °C held out, three times the noise floor, while a wall draw's own gap is
several times larger."""


def wandering_holdout(case: Case, effect: str | None, seed: int = 7,
                      rms_c: float = WANDER_RMS_C) -> Experiment:
    """The case's held-out heat-up run again on the same plant (`effect` with the case's
    drawn values, or none) and burners, with an ambient that wanders about the logged one
    (four sines of 5-25 hour periods); the record keeps the constant ambient it logged."""
    exp = case.holdout[0]
    furnace = exp.furnace
    rng = np.random.default_rng(seed)
    t = exp.t_min
    wander = np.zeros_like(t)
    for period in rng.uniform(300.0, 1500.0, 4):
        wander += np.sin(2 * np.pi * t / period + rng.uniform(0, 2 * np.pi))
    wander *= rms_c / np.sqrt(np.mean(wander ** 2))
    effects, values = [], network_truth(furnace)
    if effect is not None:
        cls, truth = EFFECTS[effect], case.truth[effect]
        effects = [cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in truth.items()
                          if k in cls.specs(furnace)}, furnace=furnace)]
        values.update({p.name: truth[p.name] for p in effects[0].params})
    air = float(exp.t_air[0])
    run = Plant(ModelStructure(effects, furnace=furnace), values, SENSORS_SPEC,
                seed=seed).run(Inputs.from_samples(t, exp.burners, air + wander), t,
                               np.full(furnace.n_zones, air))
    run.t_air = np.full(t.size, air)  # what the record logged
    run.start_time = exp.start_time
    return run.to_experiment(exp.name)
