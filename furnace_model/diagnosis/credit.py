"""Whether a candidate effect earns credit: the one rule the verdict keeps effects by, and
the one the report, the text summary and the JSON show, so that they cannot disagree.

A candidate earns credit when the data determine its own strength, it lowers the
information criterion on the fitted data (dBIC < 0) and it removes at least half of the
baseline's held-out error above the noise floor. A candidate that makes the held-out error
worse closes a negative share of the gap and never earns it; it is said to make it worse
when that shows in a printed percent.
"""

from __future__ import annotations

import numpy as np

from .fitting import CandidateResult

MIN_GAP_CLOSED = 50.0
"""Percent of the baseline's held-out error above the floor an effect must remove to count;
for a further effect in a stepwise combination, of the error the kept ones leave."""
RULE = (f"strength determined by the data, dBIC < 0 on the fitted data and at least "
        f"{MIN_GAP_CLOSED:.0f}% of the held-out gap above the noise floor closed")
"""The rule in the words the report and the text summary print beside each candidate."""


def shortfall(c: CandidateResult) -> list[str]:
    """What keeps `c` from credit, in words; empty when it earns it."""
    if not np.isfinite(c.gap_closed_pct) or not np.isfinite(c.delta_bic):
        return ["its fit failed"]
    out = []
    if not c.identifiable:
        out.append("its strength is not determined by the data")
    if c.delta_bic >= 0:
        out.append(f"the information criterion is not lower (dBIC {c.delta_bic:+.0f})")
    if c.shrink_pct <= -0.5:  # worse by at least a percent, as it is printed
        out.append(f"it makes the held-out error worse ({-c.shrink_pct:.0f}% larger)")
    elif c.gap_closed_pct < MIN_GAP_CLOSED:
        closed = max(c.gap_closed_pct, 0.0)
        out.append(f"it closes {closed:.0f}% of the held-out gap above the noise floor, under "
                   f"{MIN_GAP_CLOSED:.0f}%")
    return out


def credited(c: CandidateResult) -> bool:
    return not shortfall(c)
