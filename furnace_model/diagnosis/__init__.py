"""Diagnosis of the sim-to-real gap: where the paper's model errs, which unmodelled effect
explains it, and how far the error shrinks once the effect is added, judged on data the
fit has not seen."""

from .fitting import CandidateResult
from .search import (
    COLD_GENERATIONS,
    GAP_RATIO,
    NEAR_RATIO,
    Diagnosis,
    Located,
    Verdict,
    WhereLine,
    blend_weight,
    diagnose,
    further_laws,
    judge,
    locate,
    split,
    where_lines,
)

__all__ = ["COLD_GENERATIONS", "GAP_RATIO", "NEAR_RATIO", "CandidateResult", "Diagnosis",
           "Located", "Verdict", "WhereLine", "blend_weight", "diagnose", "further_laws",
           "judge", "locate", "split", "where_lines"]
