"""What a fit returns: its parameters with their intervals, the records' own unknowns, how
its search went, and the parameter file it writes."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..experiment import Experiment
from ..simulation.structure import ModelStructure
from .criteria import Criteria
from .model import Predicts
from .plausible import Flag
from .problem import STOP_REASONS
from .uncertainty import Uncertainty


@dataclass
class FitResult(Predicts):
    structure: ModelStructure
    params: dict[str, float]
    x0: list[np.ndarray]
    ci95: dict[str, tuple[float, float]]
    corr: np.ndarray
    undetermined: list[str]
    determined_combinations: list[str]
    warnings: list[str]
    per_zone: dict[str, dict[str, float]]
    sse: float
    n_obs: int
    elapsed_s: float
    runs: list[dict]
    method: str = "fast"
    status: str = "ok"  # ok | insufficient_excitation
    genetic_mean: dict[str, float] = field(default_factory=dict)
    sigma_c: float = float("nan")  # residual standard deviation
    combinations: dict[str, dict] = field(default_factory=dict)  # name -> {value, ci95}
    zone_offsets_c: list[dict[str, float]] | None = None  # per experiment: offset per zone
    uncertainty: Uncertainty | None = None
    std: dict[str, float] = field(default_factory=dict)  # own units; 0 fixed, NaN at a bound
    cov: np.ndarray | None = None  # own units, names order; fixed 0, at a bound NaN
    fixed: list[str] = field(default_factory=list)
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)  # searched box
    at_bound: dict[str, str] = field(default_factory=dict)  # name -> "lower" | "upper"
    stop_reason: str = ""  # a key of STOP_REASONS, for the best run
    iterations: int = 0  # accepted polish steps of the best run's result
    generations: int = 0  # GA generations of the best run
    criteria: Criteria | None = None
    ci95_white: dict[str, tuple[float, float]] = field(default_factory=dict)
    """The intervals were the residuals white (ci95 allows for their autocorrelation)."""
    profiled: list[str] = field(default_factory=list)
    """Parameters whose interval follows the criterion (profile likelihood)."""
    data: list[Experiment] = field(default_factory=list)
    """The fitted records, in order: `predict(j)` is record j as the fit models it."""
    zone_offsets_ci95_c: list[dict[str, list[float] | None]] | None = None
    """Per record, each zone offset's 95% interval; None on its bound."""
    bounds_c: list[dict] = field(default_factory=list)
    """Per record, the physical box of its offsets and initial temperatures (`_bounds_c`)."""
    flags: list[Flag] = field(default_factory=list)
    """The records' offsets and initial temperatures that ended on their physical bound."""
    moves: int = 0
    """How often a profile's refit ended lower than the fit and the fit moved there
    (`fit`'s `PROFILE_MOVES`): its search had stopped in a side valley."""

    @property
    def zone_offsets(self) -> bool:
        """Whether the fit estimated thermocouple offsets: a new record gets them too."""
        return self.zone_offsets_c is not None

    def linearised_ci95(self) -> dict[str, tuple[float, float]]:
        """The fitted parameters' linearised intervals (with the residual's colour), where
        `ci95` holds profiled ones for `profiled`."""
        unc = self.uncertainty
        if unc is None:
            return {}
        lo, hi = (np.array([self.bounds[n][k] for n in unc.names]) for k in (0, 1))
        return dict(zip(unc.names, unc.ci95(lo, hi), strict=True))

    @property
    def stop_description(self) -> str:
        return STOP_REASONS.get(self.stop_reason, "")

    def to_json(self, data: list[str]) -> dict:
        """CONTRACTS.md section 5, plus the diagnostics of this fit."""
        return {
            "model": self.structure.furnace.model_label + ("" if not self.structure.effects
                                                           else "+" + self.structure.label),
            "furnace": self.structure.furnace.name,
            "effects": [{"name": e.name, "options": _plain(e.options)}
                        for e in self.structure.effects],
            "params": dict(self.params),
            "ci95": {k: [v[0], v[1]] for k, v in self.ci95.items()},
            "per_zone": self.per_zone,
            "runs": self.runs,
            "data": list(data),
            "elapsed_s": self.elapsed_s,
            "method": self.method,
            "status": self.status,
            "genetic_mean": self.genetic_mean,
            "undetermined": self.undetermined,
            "determined_combinations": self.determined_combinations,
            "combinations": self.combinations,
            "corr": {"names": list(self.ci95), "matrix": np.round(self.corr, 6).tolist()},
            "warnings": self.warnings,
            "x0": [np.round(x, 4).tolist() for x in self.x0],
            "sse": self.sse,
            "n_obs": self.n_obs,
            "sigma_c": self.sigma_c,
            "zone_offsets_c": self.zone_offsets_c,
            "zone_offsets_ci95_c": self.zone_offsets_ci95_c,
            "offsets_c": _zone_dict(self.structure, self.carried_offsets()),
            "bounds_c": self.bounds_c,
            "flags": [f.to_json() for f in self.flags],
            **self._report_json(),
        }

    def _report_json(self) -> dict:
        """What System Identification Toolbox's present, getcov, aic and fpe give."""
        names = self.structure.names
        cov = self.cov if self.cov is not None else np.zeros((len(names),) * 2)
        unc, ic = self.uncertainty, self.criteria
        return {
            "std": {k: _finite(v) for k, v in self.std.items()},
            "cov": {"names": list(names), "matrix": _finite(cov)},
            "cov_search": None if unc is None else {
                "names": list(unc.names), "scale": ["log" if g else "linear" for g in unc.log],
                "matrix": _finite(unc.cov)},
            "fixed": {k: self.params[k] for k in self.fixed},
            "bounds": {k: [lo, hi] for k, (lo, hi) in self.bounds.items()},
            "at_bound": dict(self.at_bound),
            "ci95_white": {k: [v[0], v[1]] for k, v in self.ci95_white.items()},
            "profiled": list(self.profiled),
            "residual_correlation_time": (self.uncertainty.correlation_time
                                          if self.uncertainty is not None else None),
            "stop_reason": self.stop_reason,
            "iterations": self.iterations,
            "generations": self.generations,
            **{k: None if ic is None else _finite(getattr(ic, k))
               for k in ("aic", "aicc", "bic", "naic", "fpe")},
            "n_estimated": None if ic is None else ic.n_params,
            "n_samples": None if ic is None else ic.n_samples,
        }


def _zone_dict(structure: ModelStructure, v: np.ndarray | None) -> dict[str, float] | None:
    return None if v is None else dict(zip(structure.furnace.zones, map(float, v), strict=True))


def _finite(v):
    """A number or array for JSON, which has no NaN or infinity: those become null."""
    if np.ndim(v):
        return [_finite(x) for x in v]
    return float(v) if np.isfinite(v) else None


def _plain(options: dict) -> dict:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in options.items()}
