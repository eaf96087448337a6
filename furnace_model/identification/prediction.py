"""K-step-ahead prediction: the model restarted from what the thermocouples read K samples
earlier, as System Identification Toolbox's compare(data, model, K) shows it beside the
simulation.

The zone temperatures are states of the model (eq. 1-11), so the prediction of sample j
starts from the measured zone temperatures at sample j - K (the zone and sensor offsets
taken off) and runs the model K samples on the measured inputs. States the thermocouples do
not read (a wall's, a lagged sensor's gas temperature) are taken from the simulation at
that time: nothing measures them. Where a reading is missing its state is the simulated
one too; the first K samples, which have no reading K samples before them, are the
simulation's. So K = 1 shows how well the model follows one sample at a time, and as K
grows the prediction becomes the simulation (at K >= N it is the simulation).

For a linear structure this needs no further simulation: the restarted trajectory differs
from the simulated one only by its initial state, and that difference decays by the free
response, exp(A (t_j - t_{j-K})). A nonlinear structure (radiation) is restarted by
simulating each K-sample window.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from ..errors import FurnaceError
from ..experiment import Experiment
from ..simulation.structure import Inputs, ModelStructure
from .model import Model
from .scores import zone_metrics


def predict_ahead(params: dict[str, float], exp: Experiment, horizon: int,
                  structure: ModelStructure | None = None, x0: np.ndarray | None = None,
                  offsets: np.ndarray | None = None) -> np.ndarray:
    """What the thermocouples would read (N, 3), each sample predicted `horizon` samples
    ahead from the readings before it. x0 (zones,) starts the simulation (estimated from exp if
    None); `offsets` (zones,) are the zone offsets of exp's thermocouples (none if None)."""
    if int(horizon) != horizon or horizon < 1:
        raise FurnaceError(f"the prediction horizon must be a whole number of samples of at "
                           f"least 1, got {horizon}")
    k = int(horizon)
    model = Model(structure or ModelStructure(furnace=exp.furnace), params)
    structure, values = model.structure, model.params
    if x0 is None:
        x0 = model.refine([exp]).x0[0]
    off = np.zeros(structure.n_zones) if offsets is None else np.asarray(offsets, dtype=float)
    run = model.response(exp, x0)
    simulated = run.readings(np.isfinite(exp.tc))[0] + off
    if k >= len(exp):
        return simulated
    states = run.states[0]
    C = structure.system(structure.theta(values)).C[0]
    # the measured minus the simulated reading, put into the states the readings are of
    miss = np.nan_to_num(exp.zone_temp - simulated, nan=0.0) @ np.linalg.pinv(C).T
    restart = _by_free_response if structure.linear else _by_windows
    return restart(values, exp, k, structure, simulated, states, miss)


def _by_free_response(values, exp, k, structure, simulated, states, miss) -> np.ndarray:
    """Linear structures: the simulation plus the restart's difference, decayed."""
    sys = structure.system(structure.theta(values))
    A, C = sys.A[0], sys.C[0]
    out = simulated.copy()
    gap = np.round(exp.t_min[k:] - exp.t_min[:-k], 9)
    for dt in np.unique(gap):
        j = np.nonzero(gap == dt)[0]
        out[j + k] += miss[j] @ (C @ expm(A * dt)).T
    return out


def _by_windows(values, exp, k, structure, simulated, states, miss) -> np.ndarray:
    """Any structure: each window simulated from its restarted state."""
    C = structure.system(structure.theta(values)).C[0]
    additive = simulated - states @ C.T  # what the thermocouples read besides the states
    out = simulated.copy()
    t, inputs = exp.t_min, Inputs.of(exp)
    for i in range(len(exp) - k):
        start = (states[i] + miss[i])[None]
        end = structure.simulate(values, inputs, t[i:i + k + 1], start, t0=float(t[i])).zones[0, -1]
        out[i + k] = end + additive[i + k]
    return out


def score_ahead(params: dict[str, float], experiments: list[Experiment], horizon: int,
                structure: ModelStructure | None = None, zone_offsets: bool = False,
                offsets: np.ndarray | None = None) -> tuple[dict[str, dict], dict]:
    """Per-zone MAE, RMSE and fit % of the `horizon`-step-ahead prediction, per experiment
    (by name) and pooled; each experiment's initial state (and with `zone_offsets` its
    offsets, from the carried `offsets`) estimated from its data as `score` does for the
    simulation."""
    model = Model(structure or ModelStructure(furnace=experiments[0].furnace), params,
                  zone_offsets, offsets)
    per_exp, measured, predicted = {}, [], []
    for exp in experiments:
        start = model.refine([exp])
        y = predict_ahead(params, exp, horizon, model.structure, start.x0[0], start.offsets(0))
        per_exp[exp.name] = zone_metrics(exp.zone_temp, y, model.structure.furnace.zones)
        measured.append(exp.zone_temp)
        predicted.append(y)
    return per_exp, zone_metrics(np.concatenate(measured), np.concatenate(predicted),
                                 model.structure.furnace.zones)
