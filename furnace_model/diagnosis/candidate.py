"""One candidate extension of the paper's model, fitted and scored: what the search
compares, the credit rules judge and the verdict, the report and the JSON show."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..identification.fit import WarmStart


@dataclass
class CandidateResult:
    effects: tuple[str, ...]
    params: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    rmse_fit_c: dict[str, float]
    rmse_holdout_c: dict[str, float]
    shrink_pct: float = 0.0
    delta_bic: float = 0.0
    identifiable: bool = True
    note: str = ""
    fit_pred: list[np.ndarray] = field(default_factory=list)
    holdout_pred: list[np.ndarray] = field(default_factory=list)
    # added fields (the JSON may carry them)
    options: dict[str, dict] = field(default_factory=dict)
    sse_fit: float = float("nan")
    n_obs: int = 0
    n_params: int = 0
    rho1: float = 0.0  # lag-1 autocorrelation of the fit residual
    rho1_holdout: float = 0.0
    n_holdout: int = 0
    evidence: float = 0.0  # lower is better: delta_bic plus the held-out log-likelihood ratio
    gap_closed_pct: float = 0.0
    held_out_fitted: tuple[str, ...] = ()  # parameters estimated on the held-out data too
    carried_c: dict[str, float] = field(default_factory=dict)
    """Per zone, the held-out RMSE its own parameters' uncertainty may reach (`carried`)."""
    elapsed_s: float = 0.0
    warnings: list[str] = field(default_factory=list)
    offsets_c: dict[str, float] | None = None
    """The zone offsets the fit carries to other records (its thermocouples' biases)."""
    ended: WarmStart | None = None
    """Where the fit ended on each fitted record (offsets, initial states): a fit of a
    model this one is nested in starts from there (`fitting._from_null`)."""
    offsets_undetermined: tuple[str, ...] = ()
    """Zones whose offset the fitted records do not determine (a 95% interval wider than
    the offset's physical box, or none): its value is where the fit left it within a
    thermocouple's bias, not an estimate of one."""
    holdout_offsets_c: list[dict[str, float]] | None = None
    """Per whole held-out record, its offsets: the carried ones corrected within a
    thermocouple's bias."""
    rmse_holdout_carried_c: dict[str, float] | None = None
    """The held-out RMSE with the carried offsets held, nothing corrected (the baseline's):
    what the selfcheck holds a `no_gap` to."""
    flags: list[str] = field(default_factory=list)
    """Offsets and initial temperatures of the fitted and held-out records on their
    physical bounds (`furnace_model.identification.plausible`)."""
    signal: str = ""
    """A logged signal the baseline does not use, entered as an input
    (`furnace_model.diagnosis.signals`); empty for an effect."""
    cut: bool = False
    """Not fitted to its end within the diagnosis's time limit: named as not tried, never
    judged."""

    @property
    def label(self) -> str:
        if self.signal:
            return f"unmodelled input: {self.signal}"
        return "+".join(self.effects) or "baseline"

    def allowed(self, limit: dict[str, float]) -> dict[str, float]:
        """A noise limit per zone widened by what this fit's parameters carry: the two
        errors are independent, so their squares add."""
        return {z: float(np.hypot(v, self.carried_c.get(z, 0.0))) for z, v in limit.items()}

    def rmse_holdout_pooled(self) -> float:
        return pooled(self.rmse_holdout_c)

    def n_eff(self) -> float:
        """Effective sample size of the fit residual: autocorrelated samples carry less
        information than independent ones (AR(1) reading, n (1 - rho) / (1 + rho))."""
        return float(np.clip(self.n_obs * (1 - self.rho1) / (1 + self.rho1),
                             self.n_params + 10, max(self.n_obs, self.n_params + 10)))


def pooled(per_zone: dict[str, float]) -> float:
    v = [x for x in per_zone.values() if np.isfinite(x)]
    return float(np.sqrt(np.mean(np.square(v)))) if v else float("nan")
