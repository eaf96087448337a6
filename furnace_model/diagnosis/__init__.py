"""Diagnosis of the sim-to-real gap: where the paper's model errs, which unmodelled effect
explains it, and how far the error shrinks once the effect is added, judged on data the
fit has not seen.

The baseline is eq. 11 fitted with a constant offset per zone and experiment (thermocouple
bias). Held-out data are scored with the model's parameters fixed; only what belongs to the
record and not to the furnace is estimated on it (initial temperatures, thermocouple
offsets). The noise floor comes from the data themselves (the thermocouple pairs), record by
record (furnace_model.identification.noisefloor), so that "no gap" means: the baseline already predicts each
held-out record as well as that record's own sensors allow.

One concept per module, each importing only those above it in this list:

- `words`: how zones are named in lists;
- `candidate`: `CandidateResult`, one candidate fitted and scored;
- `credit`: the rules a candidate is judged by (identifiable, BIC, share of the gap closed,
  credit, ranking, near the floor), and the gap and near-floor thresholds;
- `fitting`: `Task` and `run_task`, a candidate fitted and predicted on held-out data;
- `holdout`: `split`, which data are fitted and which held out;
- `locate`: `Located`, where the baseline's error lies, and `where_lines` to say it;
- `verdict`: `Verdict` and `judge`, the verdict's status and sentence;
- `result`: `Diagnosis` and its JSON;
- `laws`: further laws of an effect and blends between two;
- `limit`: `TimeLimit`, which fits a time limit cut, by the clock or as a run recorded them;
- `pool`: candidates fitted side by side in processes;
- `search`: `diagnose`, the order in which candidates are tried and kept.
"""

from ..identification.noisefloor import GAP_RATIO, GAP_Z
from .candidate import CandidateResult
from .credit import (
    MIN_GAP_CLOSED,
    NEAR_RATIO,
    NEAR_Z,
    RULE,
    credited,
    score_against,
    shortfall,
)
from .fitting import Task, rmse_per_zone, run_task
from .holdout import MIN_FIT_SAMPLES, MIN_HOLDOUT_SAMPLES, TAIL_SHARE, split
from .laws import blend_weight, further_laws
from .limit import TimeLimit
from .locate import MIN_SHARE, Located, WhereLine, locate, where_lines
from .result import Diagnosis
from .search import COLD_GENERATIONS, MAX_EFFECTS, STEP_TRIES, diagnose
from .verdict import Verdict, judge

__all__ = [
    "COLD_GENERATIONS", "GAP_RATIO", "GAP_Z", "MAX_EFFECTS", "MIN_FIT_SAMPLES", "MIN_GAP_CLOSED",
    "MIN_HOLDOUT_SAMPLES", "MIN_SHARE", "NEAR_RATIO", "NEAR_Z", "RULE", "STEP_TRIES",
    "TAIL_SHARE", "CandidateResult", "Diagnosis", "Located", "Task", "TimeLimit", "Verdict",
    "WhereLine",
    "blend_weight", "credited", "diagnose", "further_laws", "judge", "locate", "rmse_per_zone",
    "run_task", "score_against", "shortfall", "split", "where_lines",
]
