"""A diagnosis as it is returned, and its JSON (CONTRACTS.md section 6 and the detail behind
it)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..experiment import Experiment
from ..identification.noisefloor import RecordFloor
from .candidate import CandidateResult
from .credit import credited
from .locate import Located
from .signals import UNMODELLED_INPUT
from .verdict import Verdict
from .words import temp_c


@dataclass
class Diagnosis:
    fit_data: list[Experiment]
    holdout: list[Experiment]
    holdout_how: str
    baseline: CandidateResult
    noise_floor_c: dict[str, float]
    where: list[Located]
    residual_tests: dict
    candidates: list[CandidateResult]
    verdict: Verdict
    elapsed_s: float
    gap_zones: tuple[str, ...] = ()
    sensor_noise_c: dict[str, float] | None = None
    record_floors: list[RecordFloor] | None = None
    """Each record's own floor, the fitted records first, then the held-out ones."""
    noise_floor_fit_c: dict[str, float] | None = None
    gap_limit_c: dict[str, float] | None = None
    """Held-out RMSE per zone above which the zone has a gap."""
    kept: CandidateResult | None = None
    """The model the verdict judged: the effects the stepwise search kept, as fitted."""
    time_limit_s: float | None = None
    untried: list[str] = field(default_factory=list)
    """What the time limit left unfitted (candidates, searches from scratch, combinations):
    the verdict is judged without them."""
    cut: list[str] = field(default_factory=list)
    """The same fits as `limit.TimeLimit` names them: given back to `diagnose` (`cut=`), they
    repeat this diagnosis without the clock."""

    def offset_lines(self) -> list[str]:
        """The baseline's thermocouple offsets, fitted and carried to the held-out records,
        and every offset or start on its physical bound, in words."""
        b = self.baseline
        if b.offsets_c is None:
            return []
        zones = list(b.offsets_c)

        def values(d: dict[str, float]) -> str:
            return "/".join(temp_c(d[z], 2, sign=True) for z in zones)

        out = [f"Zone offsets the baseline carries ({'/'.join(zones)}): {values(b.offsets_c)} "
               "°C, a thermocouple's bias at most"]
        if b.offsets_undetermined:
            out.append(f"- not determined by the fitted records in the "
                       f"{', '.join(b.offsets_undetermined)} zone(s): their 95% interval is "
                       "wider than a thermocouple's bias allows (a furnace held at its "
                       "setpoints cannot tell a shift of its readings from one of its level), "
                       "so the value is where the fit left it, not a bias")
        gap = [z for z in zones if z in self.gap_zones]
        if gap:
            # an offset that takes up what the model leaves out is no sensor's bias
            kept = self.best() if self.verdict.effects else None
            out.append(f"- the baseline misses the held-out data in the {', '.join(gap)} "
                       "zone(s): an offset there may take up part of the model's error too"
                       + (f"; with {kept.label} the fit carries {values(kept.offsets_c)} °C"
                          if kept is not None and kept.offsets_c is not None else ""))
        for e, o in zip(self.holdout, b.holdout_offsets_c or [], strict=False):  # whole records
            out.append(f"- {e.name} (held out): {values(o)} °C")
        if b.rmse_holdout_carried_c is not None:
            out.append("Held-out RMSE with the carried offsets held: "
                       + "/".join(temp_c(b.rmse_holdout_carried_c[z], 2) for z in zones) + " °C")
        out += [f"- flagged: {f}" for f in b.flags]
        return out

    def best(self) -> CandidateResult | None:
        """The kept effects' model when the verdict names effects (wholly or in part); else
        the best-ranked candidate, if any was tried."""
        if self.verdict.status in ("explained", "explained_in_part"):
            if self.kept is not None and list(self.kept.effects) == self.verdict.effects:
                return self.kept
            for c in self.candidates:
                if list(c.effects) == self.verdict.effects:
                    return c
        return self.candidates[0] if self.candidates else None

    def to_json(self) -> dict:
        """CONTRACTS.md section 6, plus the detail behind it."""
        def cand(c: CandidateResult) -> dict:
            return {"effect": UNMODELLED_INPUT if c.signal else "+".join(c.effects),
                    **({"signal": c.signal} if c.signal else {}),
                    "effects": list(c.effects),
                    "params": _round(c.params), "ci95": {k: [_r(v[0]), _r(v[1])]
                                                         for k, v in c.ci95.items()},
                    "options": _plain(c.options),
                    "rmse_fit_c": _round(c.rmse_fit_c), "rmse_holdout_c": _round(c.rmse_holdout_c),
                    "shrink_pct": _r(c.shrink_pct), "gap_closed_pct": _r(c.gap_closed_pct),
                    "delta_bic": _r(c.delta_bic), "evidence": _r(c.evidence),
                    "identifiable": c.identifiable, "credit": credited(c),
                    "held_out_fitted": list(c.held_out_fitted),
                    "carried_c": _round(c.carried_c),
                    "note": c.note, "elapsed_s": _r(c.elapsed_s)}

        b = self.baseline
        return {
            "baseline": {"rmse_fit_c": _round(b.rmse_fit_c),
                         "rmse_holdout_c": _round(b.rmse_holdout_c),
                         "noise_floor_c": _round(self.noise_floor_c),
                         "noise_floor_fit_c": _round(self.noise_floor_fit_c or {}),
                         "gap_limit_c": _round(self.gap_limit_c or {}),
                         "carried_c": _round(b.carried_c),
                         "offsets_c": None if b.offsets_c is None else _round(b.offsets_c),
                         "holdout_offsets_c": (None if b.holdout_offsets_c is None else
                                               [_round(o) for o in b.holdout_offsets_c]),
                         "rmse_holdout_carried_offsets_c": (
                             None if b.rmse_holdout_carried_c is None
                             else _round(b.rmse_holdout_carried_c)),
                         "flags": list(b.flags),
                         "params": _round(b.params),
                         "ci95": {k: [_r(v[0]), _r(v[1])] for k, v in b.ci95.items()},
                         "gap_zones": list(self.gap_zones)},
            "where": [_where(w) for w in self.where],
            "candidates": [cand(c) for c in self.candidates],
            "verdict": _verdict(self.verdict),
            "holdout_how": self.holdout_how,
            "data": [e.source or e.name for e in self.fit_data],
            "holdout": [e.source or e.name for e in self.holdout],
            "sensor_noise_c": _round(self.sensor_noise_c or {}),
            "noise_floors": [{**f.to_json(), "role": "fit" if i < len(self.fit_data)
                              else "holdout"} for i, f in enumerate(self.record_floors or [])],
            "residual_tests": self.residual_tests,
            "elapsed_s": _r(self.elapsed_s),
            "time_limit_s": self.time_limit_s,
            "untried": list(self.untried),
        }


def _where(w: Located) -> dict:
    return {"zone": w.zone, "sensor": w.sensor, "start": w.start, "end": w.end,
            "share_of_error": _r(w.share_of_error), "regime": w.regime,
            "experiment": w.experiment, "start_min": _r(w.start_min),
            "end_min": _r(w.end_min), "kind": w.kind}


def _verdict(v: Verdict) -> dict:
    """The verdict's JSON; a partial explanation adds its parts and what remains."""
    out = {"status": v.status, "effects": list(v.effects), "shrink_pct": _r(v.shrink_pct),
           "gap_closed_pct": _r(v.gap_closed_pct),
           "unmodelled_inputs": list(v.unmodelled_inputs), "sentence": v.sentence}
    if v.status == "explained_in_part":
        rest = v.remaining
        out["parts"] = [{"effect": p.effect, "gap_closed_pct": _r(p.gap_closed_pct),
                         "shrink_pct": _r(p.shrink_pct),
                         "rmse_holdout_c": _round(p.rmse_holdout_c)} for p in v.parts]
        out["remaining"] = None if rest is None else {
            "rmse_holdout_c": _round(rest.rmse_holdout_c),
            "noise_floor_c": _round(rest.noise_floor_c),
            "where": [_where(w) for w in rest.where], "where_from": rest.where_from}
    return out


def _r(x: float) -> float | None:
    x = float(x)
    return round(x, 6) if np.isfinite(x) else None


def _round(d: dict) -> dict:
    return {k: _r(v) for k, v in d.items()}


def _plain(d: dict) -> dict:
    return {k: {o: list(v) if isinstance(v, tuple) else v for o, v in opts.items()}
            for k, opts in d.items()}
