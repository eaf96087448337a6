"""A structure with parameter values: what a parameter file holds, and how it predicts,
scores and re-estimates records."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import FurnaceError
from ..experiment import Experiment
from ..simulation.response import Response
from ..simulation.structure import Inputs, ModelStructure
from .plausible import Flag
from .problem import Polished, Problem
from .scores import zone_metrics
from .uncertainty import gram


class Predicts:
    """Prediction from parameter values and, for the records a result was estimated on, its
    initial states and thermocouple offsets. Needs `structure`, `params`, `data`, `x0` and
    `zone_offsets_c` (None: no offsets), and `zone_offsets` (bool: a new record's offsets
    are estimated with its initial state)."""

    structure: ModelStructure
    params: dict[str, float]
    data: list[Experiment]
    x0: list[np.ndarray]
    zone_offsets_c: list[dict[str, float]] | None
    zone_offsets: bool

    @property
    def model(self) -> Model:
        """The structure with these parameter values and the offsets they carry, without
        records."""
        return Model(self.structure, dict(self.params), self.zone_offsets,
                     self.carried_offsets())

    def carried_offsets(self) -> np.ndarray | None:
        """The thermocouple offsets (zones,) carried to other records of the furnace: each
        zone's offsets over the records, weighted by their readings. None without offsets.
        Offsets belong to the sensors: a record of the same thermocouples starts from them."""
        if self.zone_offsets_c is None or not self.data:
            return None
        w = np.array([np.isfinite(e.zone_temp).sum(axis=0) for e in self.data], dtype=float)
        off = np.array([self.offsets(j) for j in range(len(self.data))])
        return (w * off).sum(axis=0) / np.maximum(w.sum(axis=0), 1.0)

    def offsets(self, j: int) -> np.ndarray:
        """Record j's zone offsets (zones,), zeros where none were estimated or held."""
        zones = self.structure.furnace.zones
        if self.zone_offsets_c is None:
            return np.zeros(len(zones))
        return np.array([self.zone_offsets_c[j][z] for z in zones], dtype=float)

    def _record(self, j: int) -> Experiment:
        if not 0 <= j < len(self.data):
            raise IndexError(f"record {j}: this result holds {len(self.data)} record(s)")
        return self.data[j]

    def response(self, record: int | Experiment, x0: np.ndarray | None = None,
                 states: bool = True) -> Response:
        """The simulated run on a record: an own record (index) from its fitted initial
        state, a new one from x0 (estimated from its data if None)."""
        if isinstance(record, int | np.integer):
            return self.model.response(self._record(int(record)), self.x0[int(record)], states)
        return self.model.response(record, x0, states)

    def predict(self, record: int | Experiment, x0: np.ndarray | None = None,
                offsets: np.ndarray | None = None) -> np.ndarray:
        """What the thermocouples read (N, 3) on a record, as its zone means.

        An own record (an index into `data`) starts from its fitted initial state and gets
        its fitted zone offsets. A new record (an Experiment): with x0 None its initial
        state, and its offsets where this result estimated offsets, are estimated from its
        data under these parameters (a new campaign's start and thermocouple biases are not
        the model's to predict); with x0 given the run starts there and `offsets` (3,; none
        if None) are added."""
        if isinstance(record, int | np.integer):
            j = int(record)
            return self.model.predict(self._record(j), self.x0[j], self.offsets(j))
        return self.model.predict(record, x0, offsets)

    def refine(self, data: Sequence[Experiment], free: Sequence[str] = (), *,
               x0: Sequence[np.ndarray] | None = None,
               offsets: Sequence[np.ndarray] | None = None,
               sigma: float | None = None) -> Refinement:
        """Re-estimate the parameters in `free` on other data, the others held at these
        values; see `Model.refine`."""
        return self.model.refine(data, free, x0=x0, offsets=offsets, sigma=sigma)


def score(params: dict, experiments: list[Experiment],
          structure: ModelStructure | None = None, zone_offsets: bool = False,
          offsets: np.ndarray | None = None) -> dict:
    """Per-zone MAE, RMSE and fit % of given parameters on experiments (the paper's
    Table VI), each experiment's initial state (and with `zone_offsets` its thermocouple
    offsets, from the carried `offsets`) estimated from its data. Without a structure, the
    baseline of the furnace the records are of."""
    structure = structure or ModelStructure(furnace=experiments[0].furnace)
    missing = [n for n in structure.names if n not in params]
    if missing:
        raise FurnaceError(f"parameter(s) {', '.join(missing)} missing for {structure.label}")
    return Model(structure, params, zone_offsets, offsets).refine(experiments).per_zone


@dataclass
class Model:
    """A structure with parameter values and no records: what a parameter file holds.
    `zone_offsets`: a record's thermocouple offsets are estimated with its initial state,
    starting from `offsets` (zones,; the fitted records' own, carried) and held within the
    bias a thermocouple can have."""

    structure: ModelStructure
    params: dict[str, float]
    zone_offsets: bool = False
    offsets: np.ndarray | None = None

    def __post_init__(self):
        missing = [n for n in self.structure.names if n not in self.params]
        if missing:
            raise FurnaceError(f"parameter(s) {', '.join(missing)} missing for "
                               f"{self.structure.label}")
        self.params = {n: float(self.params[n]) for n in self.structure.names}
        if self.offsets is not None:
            self.offsets = np.asarray(self.offsets, dtype=float).reshape(self.structure.n_zones)

    @property
    def model(self) -> Model:
        return self

    def response(self, exp: Experiment, x0: np.ndarray | None = None,
                 states: bool = True) -> Response:
        """The simulated run on exp's samples from zone temperatures (or all states) x0;
        x0 estimated from exp's data if None."""
        if x0 is None:
            x0 = self.refine([exp]).x0[0]
        return self.structure.simulate(self.params, Inputs.of(exp), exp.t_min,
                                       np.asarray(x0, dtype=float)[None], states=states)

    def predict(self, exp: Experiment, x0: np.ndarray | None = None,
                offsets: np.ndarray | None = None) -> np.ndarray:
        """What exp's thermocouples read (N, 3) as zone means. With x0 None the initial
        state (and with `zone_offsets` the offsets) are estimated from exp; else the run
        starts at x0 and `offsets` (zones,; none if None) are added."""
        if x0 is None:
            return self.refine([exp]).predict(0)
        prob = Problem([exp], self.structure, self.params, {},
                        held_offsets=None if offsets is None else [offsets])
        return prob.predict(0, prob.values(np.zeros((1, 0))), np.asarray(x0, float)[None])[0]

    def refine(self, data: Sequence[Experiment], free: Sequence[str] = (), *,
               x0: Sequence[np.ndarray] | None = None,
               offsets: Sequence[np.ndarray] | None = None,
               sigma: float | None = None) -> Refinement:
        """Re-estimate the parameters named in `free` on `data`, the others held at these
        values, with each record's initial state (and with `zone_offsets` its thermocouple
        offsets): what scoring held-out records needs (their start and biases are theirs,
        and a parameter the fitted data did not see is theirs to set), and what a recent
        span of a long window says about one parameter. Estimated offsets start from the
        carried ones (`offsets`) and stay within the thermocouples' bias bound, the initial
        states within what the record allows (`furnace_model.identification.plausible`); either on its
        bound is flagged (`Refinement.flags`).

        The free parameters are shared by all records. With none free each record is
        estimated alone: its initial state cannot depend on which other records were passed.
        x0 (per record, zone temperatures or all states) starts the search of the initial
        states (the first readings if None). `offsets` (per record, (3,)) are held, not
        estimated: offsets known from more data than a span holds. `sigma` (°C) is the
        noise level for the free parameters' covariance; None takes the refinement's own
        residual.
        """
        data = list(data)
        free = tuple(free)
        unknown = [n for n in free if n not in self.structure.names]
        if unknown:
            raise FurnaceError(f"unknown parameter(s) {unknown}; the model has "
                               f"{self.structure.names}")
        if not data:
            raise FurnaceError("no data to refine on")
        fixed = {n: v for n, v in self.params.items() if n not in free}
        estimate = self.zone_offsets and offsets is None
        groups = [list(range(len(data)))] if free else [[j] for j in range(len(data))]
        nz = self.structure.n_zones
        x0s: list[np.ndarray] = [np.zeros(nz)] * len(data)
        offs: list[np.ndarray] = [np.zeros(nz)] * len(data)
        params = dict(self.params)
        sse, n_obs, reasons, iterations = 0.0, 0, [], 0
        flags: list[Flag] = []
        cov = np.zeros((len(free), len(free)))
        carried = None if self.offsets is None or not estimate else [self.offsets] * len(data)
        for group in groups:
            prob = Problem([data[j] for j in group], self.structure, fixed, {}, estimate,
                            None if offsets is None else [offsets[j] for j in group])
            start = prob.start(prob.to_z(np.array([self.params[n] for n in prob.names])),
                               None if carried is None else [carried[j] for j in group])
            if x0 is not None:
                for i, j in enumerate(group):
                    at = prob.k + prob.block * i
                    start[at:at + nz] = np.asarray(x0[j], dtype=float)[:nz]
            p = prob.polish(start, None)
            flags += prob.flags(p.z, prob.held_by_bounds(p))
            for i, j in enumerate(group):
                x0s[j] = prob.x0_of(p.z, i).copy()
                offs[j] = (prob.offsets_of(p.z, i).copy() if offsets is None
                           else np.asarray(offsets[j], dtype=float))
            sse += float(p.r @ p.r)
            n_obs += prob.n_obs
            reasons.append(p.reason)
            iterations += p.iterations
            if free:
                params.update(prob.param_dict(p.z))
                cov = _free_cov(prob, p, sigma)
        std = {n: float(np.sqrt(cov[i, i])) if np.isfinite(cov[i, i]) else float("nan")
               for i, n in enumerate(free)}
        by_zone = None
        if estimate or offsets is not None:
            by_zone = [dict(zip(self.structure.furnace.zones, map(float, o), strict=True))
                       for o in offs]
        return Refinement(
            structure=self.structure, params=params, free=free, data=data, x0=x0s,
            zone_offsets_c=by_zone, zone_offsets=self.zone_offsets, std=std, cov=cov,
            sse=sse, n_obs=n_obs,
            stop_reason=next((r for r in reasons if r != "converged"), "converged"),
            iterations=iterations, flags=flags, carried_c=self.offsets if estimate else None)


def _free_cov(prob: Problem, polished: Polished, sigma: float | None) -> np.ndarray:
    """Covariance (own units) of the free parameters, the initial states and offsets
    marginalised out, the residuals taken as white with standard deviation sigma (the
    refinement's own if None). NaN where the data do not determine them."""
    J = polished.J
    k = prob.k
    if sigma is None:
        sigma = float(np.sqrt(polished.r @ polished.r / max(J.shape[0] - J.shape[1], 1)))
    normal = gram(J, prob.blocked)
    if not np.all(np.isfinite(normal)) or np.linalg.cond(normal) > 1e12:
        return np.full((k, k), np.nan)
    cov = sigma ** 2 * np.linalg.inv(normal)[:k, :k]
    scale = np.where(prob.log, prob.from_z(polished.z[:k]), 1.0)  # d p = p d log p
    return cov * np.outer(scale, scale)


@dataclass
class Refinement(Predicts):
    """Parameters re-estimated on records (`free`; the others held), with the records'
    initial states and offsets: it predicts its records, and new ones, as a fit does."""

    structure: ModelStructure
    params: dict[str, float]
    free: tuple[str, ...]
    data: list[Experiment]
    x0: list[np.ndarray]
    zone_offsets_c: list[dict[str, float]] | None
    zone_offsets: bool
    std: dict[str, float]
    """The free parameters' standard deviations, own units (white residuals of `sigma`)."""
    cov: np.ndarray
    """Their covariance, own units, in `free` order."""
    sse: float
    n_obs: int
    stop_reason: str
    iterations: int
    flags: list[Flag] = field(default_factory=list)
    """The records' offsets and initial temperatures that ended on their physical bound."""
    carried_c: np.ndarray | None = None
    """The offsets (zones,) the estimated ones started from: the model's, carried."""

    def corrections(self) -> list[dict[str, float]] | None:
        """Per record, how far its estimated offsets moved from the carried ones, per zone
        (None unless offsets were estimated from carried ones)."""
        if self.carried_c is None or self.zone_offsets_c is None:
            return None
        return [{z: o[z] - float(c) for z, c in zip(self.structure.furnace.zones, self.carried_c,
                                                     strict=True)}
                for o in self.zone_offsets_c]

    @property
    def per_zone(self) -> dict[str, dict[str, float]]:
        """MAE, RMSE and fit % per zone over the records (the paper's Table VI)."""
        return zone_metrics(np.concatenate([e.zone_temp for e in self.data]),
                            np.concatenate([self.predict(j) for j in range(len(self.data))]),
                            self.structure.furnace.zones)
