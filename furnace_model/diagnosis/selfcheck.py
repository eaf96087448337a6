"""The diagnosis checked on known-truth cases (`furnace_model.diagnosis.cases`): each case
diagnosed and its verdict judged against the truth (`check`, `judge_case`), the outcomes
counted per effect (`summarize`, `table`: what `furnace-model selfcheck` prints)."""

from __future__ import annotations

import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..blas import on_one_thread
from ..effects import EFFECTS
from ..simulation.furnace import Furnace
from .cases import (
    SENSORS_SPEC,
    Case,
    case_rng,
    draw_case,
    draw_closed_loop_case,
    draw_sensors,
    parse_label,
    production_scenario,
)
from .faults import FAULTS
from .verdict import NAMING, STATUSES

# --- the check: diagnose known-truth cases and count -------------------------------------

ABSORBED_REASON = "baseline already at the noise floor on held-out data"
MODES = ("heat-up", "production")
"""What a case's two records are: heat-ups under random burner schedules (`draw_case`), or
production under the PLC's loops (`draw_closed_loop_case`, the shipped paper_production
scenario), where the loops set the burners from the thermocouples they read."""


@dataclass
class Outcome:
    """One diagnosed case against its truth."""

    label: str  # "none", an effect, "a+b", or a perturbation outside the library
    draw: int
    description: str
    status: str
    named: list[str]
    correct: bool
    absorbed: bool
    reason: str
    shrink_pct: float
    gap_closed_pct: float
    elapsed_s: float
    truth: dict
    held: dict[str, bool] = field(default_factory=dict)
    """The parameters the verdict gives with 95% intervals (`Effect.told`) of the true
    effects it names: whether each interval holds the truth."""

    def to_json(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v)
                for k, v in self.__dict__.items()}


def judge_case(case: Case, diagnosis) -> tuple[bool, bool, str]:
    """(correct, absorbed, reason) for a case and its diagnosis."""
    v = diagnosis.verdict
    if not case.effects:
        ok = v.status == "no_gap"
        return ok, False, "" if ok else f"verdict {v.status} {v.effects} on a furnace with no effect"
    held = diagnosis.baseline.rmse_holdout_carried_c or {}
    limit = carried_limit(case, diagnosis)
    hidden = [z for z in held if z in limit and held[z] > limit[z]]
    if v.status == "no_gap" and hidden:
        over = ", ".join(f"{z} {held[z]:.2f} > {limit[z]:.2f}" for z in hidden)
        return False, False, (f"no_gap, but with the offsets the fit carries the held-out "
                              f"error is above the gap limit and a change of bias ({over} °C)")
    if v.status == "no_gap" and case.expected_status == "explained":
        b, fl = diagnosis.baseline.rmse_holdout_c, diagnosis.noise_floor_c
        rmse = "/".join(f"{b[z]:.2f}" for z in fl)
        floor = "/".join(f"{fl[z]:.2f}" for z in fl)
        return False, True, f"{ABSORBED_REASON} (held-out RMSE {rmse} against {floor} °C)"
    if case.expected_status == "unexplained":
        if v.status != "unexplained":
            return False, False, f"verdict {v.status} {v.effects}"
        where = diagnosis.where[0] if diagnosis.where else None
        fault = next(f for f in FAULTS.values() if f.name in case.truth)
        ok, reason = fault.located(case.truth[fault.name], where)
        return ok, False, reason
    # A partial explanation names effects as an explanation does, and is held to the same
    # rules: the effects named are the truth's, and they close at least half of the gap.
    want = set(case.library_effects)
    if v.status not in NAMING or set(v.effects) != want:
        return False, False, f"verdict {v.status} {v.effects}"
    if v.gap_closed_pct < 50.0:
        return False, False, f"named, but closes only {v.gap_closed_pct:.0f}% of the gap"
    return True, False, ""


def told_held(case: Case, diagnosis) -> dict[str, bool]:
    """{parameter: whether its 95% interval holds the truth} for the told parameters
    (`Effect.told`) of each true effect the verdict names; the truth's onsets are minutes
    of every record, as the fit's are."""
    kept = diagnosis.kept
    if kept is None:
        return {}
    out = {}
    for name in [n for n in diagnosis.verdict.effects if n in case.truth and n in kept.effects]:
        for p in EFFECTS[name].told:
            if p in kept.ci95 and p in case.truth[name]:
                lo, hi = kept.ci95[p]
                out[p] = bool(lo <= case.truth[name][p] <= hi)
    return out


BIAS_CHANGE_SD = 3.0
"""`carried_limit`: how many sds of the change of a zone's mean bias between two records a
no_gap is allowed with the offsets carried from one to the other."""


def carried_limit(case: Case, diagnosis) -> dict[str, float]:
    """Per zone, the held-out RMSE with the fit's offsets carried (nothing corrected) that a
    `no_gap` may have: the gap limit, widened by the change of bias the drawn thermocouples
    can have between the fitted and the held-out record (drawn anew for each, sd
    `SENSORS_SPEC.bias_sd_c` apiece; a zone's mean bias changes with sd bias_sd sqrt(2/n)).
    A held-out record's offsets are its own within a thermocouple's bias, so the diagnosis
    may correct them; an error that the carried offsets show beyond this is one the
    correction hid."""
    furnace = case.fit[0].furnace
    limit = diagnosis.gap_limit_c or {}
    change = {z: BIAS_CHANGE_SD * SENSORS_SPEC.bias_sd_c * np.sqrt(2.0 / n)
              for z, n in zip(furnace.zones, furnace.thermocouples, strict=True)}
    return {z: float(np.hypot(v, change[z])) for z, v in limit.items()}


def selfcheck_case(label: str, k: int, seed: int = 0, *, form: str = "candidate",
                   noise: str = "white", mode: str = "heat-up", furnace: Furnace) -> Case:
    """Draw `k` of the selfcheck's row `label`: the same case `check` diagnoses. In
    production (`MODES`) the records are the production scenario's, on its own furnace,
    which `furnace` must be: the rows were checked against it."""
    sensors = draw_sensors(noise, np.random.default_rng(
        [seed, zlib.crc32(label.encode()), k, zlib.crc32(noise.encode())]))
    rng = case_rng(seed, label, k)
    if mode == "production":
        scenario = production_scenario()
        if furnace != scenario.furnace:
            raise ValueError(f"production cases run on furnace '{scenario.furnace.name}' "
                             f"(scenario {scenario.name}), not '{furnace.name}'")
        return draw_closed_loop_case(parse_label(label), rng, form=form, sensors=sensors,
                                     scenario=scenario)
    if mode != "heat-up":
        raise ValueError(f"mode must be one of {MODES}, not {mode!r}")
    return draw_case(parse_label(label), rng, form=form, sensors=sensors, furnace=furnace)


@on_one_thread
def check(labels: list[str], draws: int, seed: int = 0, *, form: str = "candidate",
          candidates: tuple[str, ...] | None = None, noise: str = "white",
          report: Callable[[Outcome], None] | None = None, first: int = 0,
          mode: str = "heat-up", furnace: Furnace) -> list[Outcome]:
    """Draw `draws` cases per label, diagnose each with its effect withheld (the diagnosis is
    told nothing about it), and judge the verdict against the truth. The thermocouples
    (`noise`) are drawn from a stream of their own, so that a case's furnace and schedule
    are the same whatever its thermocouples. `first`: the first draw's number, so that a
    check can be split into runs (draws 0-1, then 2-4) that together are the longer one.
    `mode`: heat-ups or production records (`MODES`); `furnace`: the description the cases
    run on."""
    from . import diagnose  # the diagnosis is the checked party, not a dependency

    out = []
    for label in labels:
        for k in range(first, first + draws):
            case = selfcheck_case(label, k, seed, form=form, noise=noise, mode=mode,
                                  furnace=furnace)
            t0 = time.perf_counter()
            d = diagnose(case.fit, case.holdout, effects=candidates, seed=seed)
            correct, absorbed, reason = judge_case(case, d)
            o = Outcome(label, k, case.description, d.verdict.status, list(d.verdict.effects),
                        correct, absorbed, reason, float(d.verdict.shrink_pct),
                        float(getattr(d.verdict, "gap_closed_pct", np.nan)),
                        time.perf_counter() - t0, case.truth, told_held(case, d))
            out.append(o)
            if report is not None:
                report(o)
    return out


@dataclass
class Row:
    label: str
    draws: int
    verdicts: dict[str, int]
    correct: int
    absorbed: int
    shrink_median: float
    gap_closed_median: float
    elapsed_s: float
    passed: bool


def summarize(outcomes: list[Outcome]) -> list[Row]:
    """Per label: verdict counts, correct draws, absorbed draws (apart), median held-out
    shrink of the correct ones that name effects (wholly or in part), and whether the label
    meets the acceptance: every control no_gap; a single effect named in 9 of 10 draws it
    was not absorbed in; two effects and faults outside the library, every draw."""
    rows = []
    for label in dict.fromkeys(o.label for o in outcomes):
        mine = [o for o in outcomes if o.label == label]
        counts = {s: sum(o.status == s for o in mine) for s in STATUSES}
        good = [o for o in mine if o.correct]
        absorbed = sum(o.absorbed for o in mine)
        counted = len(mine) - absorbed
        single = label in EFFECTS
        passed = (len(good) >= 0.9 * counted) if single else len(good) == len(mine)
        rows.append(Row(label, len(mine), counts, len(good), absorbed,
                        _median([o.shrink_pct for o in good if o.status in NAMING]),
                        _median([o.gap_closed_pct for o in good if o.status in NAMING]),
                        float(sum(o.elapsed_s for o in mine)), passed))
    return rows


def _median(v: list[float]) -> float:
    v = [x for x in v if np.isfinite(x)]
    return float(np.median(v)) if v else float("nan")


def table(rows: list[Row], outcomes: list[Outcome]) -> str:
    """The rows as a markdown table, then the absorbed draws and the ones not correct. The
    column of partial explanations follows the medians, so that the columns before it read
    as they always have."""
    lines = ["| effect | draws | no_gap | explained | unexplained | correct | absorbed | "
             "held-out shrink (median %) | gap closed (median %) | explained in part | "
             "elapsed (s) | pass |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        v = r.verdicts
        lines.append(f"| {r.label} | {r.draws} | {v['no_gap']} | {v['explained']} | "
                     f"{v['unexplained']} | {r.correct} | {r.absorbed} | "
                     f"{_pct(r.shrink_median)} | {_pct(r.gap_closed_median)} | "
                     f"{v.get('explained_in_part', 0)} | "
                     f"{r.elapsed_s:.0f} | {'yes' if r.passed else 'NO'} |")
    apart = [o for o in outcomes if o.absorbed]
    if apart:
        lines += ["", "Absorbed (reported apart, not failures):"]
        lines += [f"- {o.label} draw {o.draw}: {o.reason}; {o.description}" for o in apart]
    told = sorted({p for o in outcomes for p in o.held})
    if told:
        lines += ["", "95% intervals the verdicts give, holding the truth: " + ", ".join(
            f"{p} {sum(o.held[p] for o in outcomes if p in o.held)} of "
            f"{sum(p in o.held for o in outcomes)}" for p in told)]
    wrong = [o for o in outcomes if not o.correct and not o.absorbed]
    if wrong:
        lines += ["", "Not correct:"]
        lines += [f"- {o.label} draw {o.draw}: {o.reason}; {o.description}" for o in wrong]
    return "\n".join(lines)


def _pct(x: float) -> str:
    return f"{x:.0f}" if np.isfinite(x) else "-"
