"""The stepwise search's rule for adding an effect, on fits whose scores are set: which fit
a combination's step returns is the pool's business (tested with real fits elsewhere);
which effects the search keeps from them is this rule's."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from furnace_model.diagnosis import CandidateResult, score_against
from furnace_model.diagnosis import search as search_module
from furnace_model.diagnosis.search import stepwise
from furnace_model.simulation.furnace import PAPER

ZONES = PAPER.zones
FLOOR = {z: 1.0 for z in ZONES}
GAP_LIMIT = {z: 1.25 for z in ZONES}


@dataclass
class _Record:
    furnace: object = PAPER


def scored(effects: tuple[str, ...], rmse: float, sse: float, base=None) -> CandidateResult:
    c = CandidateResult(effects=effects, params={"fuel_ratio": 0.75} if effects else {},
                        ci95={}, rmse_fit_c=dict.fromkeys(ZONES, rmse),
                        rmse_holdout_c=dict.fromkeys(ZONES, rmse), sse_fit=sse, n_obs=1000,
                        n_params=10 + len(effects) * 2)
    if base is not None:
        score_against(c, base, FLOOR)
    return c


def search(monkeypatch, refitted_rmse: float) -> tuple[CandidateResult, list[CandidateResult]]:
    """A fuel change fitted alone in a side valley (5 °C held out); its combination with a
    lag at 1.02 °C; the fuel change refitted from that combination's optimum at
    `refitted_rmse`. (The kept set, the steps.)"""
    base = scored((), 10.0, 100_000.0)
    fuel = scored(("fuel_change",), 5.0, 25_000.0, base)
    lag = scored(("sensor_lag",), 9.0, 81_000.0, base)

    def run_all(tasks, progress, finished=None, limit=None):
        out = []
        for t in tasks:
            if t.effects == ("fuel_change", "sensor_lag"):
                out.append(scored(t.effects, 1.02, 1040.0))
            elif t.effects == ("fuel_change",):
                out.append(scored(t.effects, refitted_rmse, 1000.0 * refitted_rmse ** 2))
            else:
                raise AssertionError(f"unexpected fit {t.effects}")
        return out

    monkeypatch.setattr(search_module, "run_all", run_all)
    _, kept, steps = stepwise([fuel, lag], base, FLOOR, GAP_LIMIT, [_Record()], [], [None], 0,
                              {}, {}, {}, tuple(ZONES), lambda _f: None)
    return kept, steps


def test_an_effect_is_not_added_to_a_set_that_refitted_leaves_no_clear_gap(monkeypatch):
    """Refitted, the fuel change alone reaches 1.2 °C against a gap limit of 1.25: the lag,
    which takes that to 1.02 (91% of what is left above the floor, at a lower BIC), is
    not added."""
    kept, steps = search(monkeypatch, 1.2)
    assert kept.effects == ("fuel_change",) and kept.rmse_holdout_pooled() == pytest.approx(1.2)
    assert [s.effects for s in steps] == [("fuel_change",)]


def test_an_effect_is_added_where_the_refitted_set_still_leaves_a_clear_gap(monkeypatch):
    """Refitted, the fuel change alone stays at 2 °C, a clear gap: the lag, which closes
    nearly all of it, is added."""
    kept, steps = search(monkeypatch, 2.0)
    assert kept.effects == ("fuel_change", "sensor_lag")
    assert [s.effects for s in steps] == [("fuel_change",), ("fuel_change", "sensor_lag")]
