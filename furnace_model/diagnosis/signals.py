"""Whether the model's error follows a logged signal that the model does not use.

A record may carry numbers besides the model's inputs (O2, furnace pressure, a door switch,
a throughput nobody declared as a disturbance). If the held-out error follows one of them,
no library effect is the cause: heat entered that the model never saw. The test is the one
every candidate takes: the signal enters the baseline as one more measured input, with one
gain per zone (`Disturbance`), the extended model is fitted on the fitted data and judged on
the held-out data by the credit rules. A library effect cannot fake this candidate, since its
input is the signal's own time course.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ..experiment import Experiment
from ..identification.residuals import ZONE_WORDS
from ..simulation.furnace import Disturbance, Furnace
from .candidate import CandidateResult
from .credit import credited, near_floor, rank, score_against
from .fitting import Task
from .limit import TimeLimit
from .locate import Located
from .pool import run_all
from .verdict import Part, Verdict, remaining_of
from .words import temp_c

UNMODELLED_INPUT = "unmodelled_input"
"""The candidate's name in the JSON (`effect`), with the signal in `signal`."""


SETPOINT = re.compile(r"(^|[_\W])(setpoint|sp)([_\W]|$)", re.IGNORECASE)
"""A controller's reference (`setpoint_soak`, `soak_sp`, `SP heat`): heat reaches the furnace
through the burners, which the model has, never through a setpoint. In closed loop a
setpoint follows the zone's own temperature, so as an input it would absorb any misfit."""


def unused_signals(records: list[Experiment]) -> tuple[str, ...]:
    """Signals every record carries and that move within the records: a constant column
    is no input; one that some record lacks cannot be carried onto it; a setpoint is none."""
    if not records:
        return ()
    names = [n for n in records[0].signals
             if all(n in r.signals for r in records) and not SETPOINT.search(n)]
    out = []
    for n in names:
        values = np.concatenate([r.signals[n] for r in records])
        finite = values[np.isfinite(values)]
        if finite.size > 2 and np.ptp(finite) > 1e-9 * max(np.abs(finite).max(), 1.0):
            out.append(n)
    return tuple(out)


def with_signal(furnace: Furnace, name: str, records: list[Experiment]) -> Furnace:
    """The furnace with the signal declared as a disturbance of every zone, scaled by the
    largest value it takes in the records."""
    values = np.concatenate([r.signals[name] for r in records])
    values = values[np.isfinite(values)]
    lo, hi = float(values.min()), float(values.max())
    return replace(furnace, disturbances=(*furnace.disturbances, Disturbance(
        name, "unit", tuple(range(furnace.n_zones)), name, (lo, hi))))


def as_input(record: Experiment, name: str, furnace: Furnace) -> Experiment:
    """The record with the signal among its disturbances: a gap in it holds the last value
    (the first known before any)."""
    v = record.signals[name].astype(float)
    filled = _held(v)
    return Experiment(record.name, record.t_min, record.tc, record.burners, record.t_air,
                      record.start_time, record.source, furnace=furnace,
                      disturbances=np.column_stack([record.disturbances, filled]),
                      signals={k: s for k, s in record.signals.items() if k != name})


def _held(v: np.ndarray) -> np.ndarray:
    good = np.isfinite(v)
    idx = np.where(good, np.arange(v.size), 0)
    np.maximum.accumulate(idx, out=idx)
    out = v[idx]
    first = int(np.argmax(good))
    out[:first] = v[first]
    return out


def signal_candidates(names: tuple[str, ...], base: CandidateResult,
                      fit_data: list[Experiment], hold: list[Experiment],
                      tail_of: list[int | None], seed: int, floor: dict[str, float],
                      finished=None, limit: TimeLimit | None = None) -> list[CandidateResult]:
    """Each signal tried as an unmodelled input: fitted from the baseline's optimum, scored
    against the baseline like an effect; `finished` hears each as it is fitted. Those the
    time limit (`limit`) cut come back with `cut` set, unscored."""
    tasks, furnaces = [], []
    for name in names:
        furnace = with_signal(fit_data[0].furnace, name, fit_data + hold)
        furnaces.append(furnace)
        tasks.append(Task((), {}, [as_input(r, name, furnace) for r in fit_data],
                          [as_input(r, name, furnace) for r in hold], tail_of,
                          dict(base.params), seed, cold_too=True))
    out = run_all(tasks, lambda _f: None, limit=limit)
    for name, furnace, c in zip(names, furnaces, out, strict=True):
        c.signal = name
        if c.cut:
            continue
        if finished is not None:
            finished(c)
        gains = [f"gain_{name}_{z}" for z in furnace.zones]
        # Its strength: some zone's gain determined away from zero.
        c.identifiable = any(c.ci95[g][0] > 0 or c.ci95[g][1] < 0 for g in gains
                             if g in c.ci95)
        if not c.identifiable:
            c.note = f"the data do not determine a gain of {name} in any zone"
        score_against(c, base, floor)
    return out


def prefer_signal(verdict: Verdict, followed: list[CandidateResult],
                  kept: CandidateResult | None, base: CandidateResult,
                  floor: dict[str, float], near: dict[str, float], gap: tuple[str, ...],
                  where: list[Located], furnace: Furnace,
                  locate_remaining: Callable[[CandidateResult], list[Located] | None]
                  ) -> Verdict:
    """The verdict, or, when a logged signal earns credit and ranks ahead of the effects
    kept (or none is kept), the signal's: the model's error follows an input it does not
    have, which the furnace description should declare. Short of the floor, it is a partial
    explanation like an effect's, with its one part and where what it leaves lies."""
    best = min((c for c in followed if credited(c)), key=rank, default=None)
    if not gap or best is None or (kept is not None and rank(kept) <= rank(best)):
        return verdict
    worst = max(gap, key=lambda z: base.rmse_holdout_c[z] / max(floor[z], 1e-9))
    gains = {z: best.params[f"gain_{best.signal}_{z}"] for z in furnace.zones}
    most = max(gains, key=lambda z: abs(gains[z]))
    full = near_floor(best, near)
    parts, remaining = [], None
    if not full:
        parts = [Part(best.label, best.gap_closed_pct, best.shrink_pct,
                      dict(best.rmse_holdout_c))]
        remaining = remaining_of(best, floor, where, locate_remaining)
    return Verdict(
        "explained" if full else "explained_in_part", [], best.shrink_pct,
        gap_closed_pct=best.gap_closed_pct, unmodelled_inputs=[best.signal],
        parts=parts, remaining=remaining,
        sentence=
        f"The model's error follows the logged signal '{best.signal}', which the model does "
        f"not use: entered as a measured input of each zone (strongest in the "
        f"{ZONE_WORDS[most]} zone, {gains[most]:+.3g} °C/min per unit), it cuts the held-out "
        f"error in the {ZONE_WORDS[worst]} zone from {temp_c(base.rmse_holdout_c[worst])}"
        f" to {temp_c(best.rmse_holdout_c[worst])} °C and closes "
        f"{best.gap_closed_pct:.0f}% of the gap above the noise floor"
        + (", down to about the thermocouple noise." if full else
           f"; {temp_c(best.rmse_holdout_c[worst])} °C against a floor of "
           f"{temp_c(floor[worst])} °C remains.")
        + f" No effect of the library explains it better. Declare it as a disturbance in the "
          f"furnace description (disturbances: name {best.signal}, its unit, the zones it "
          f"enters) so that the model fits its gains.")
