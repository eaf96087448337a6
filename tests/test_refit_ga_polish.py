"""`refit.method: ga_polish`, the default: the genetic search seeded with the previous
window's model, then the polish. Never worse than the polish from that model, the same
search wherever and whenever it runs (seed from the window, generations from the settings),
and the budget still a wall-clock guard."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from refit_helpers import scenario, simulate

from furnace_daq.daqconfig import RefitConfig
from furnace_daq.logmeta import refit_config
from furnace_daq.plantlog import run_messages
from furnace_daq.refit import SEEDED_REACH, RefitChain, Window, WindowCutter, window_seed
from furnace_model.errors import FurnaceError
from furnace_model.identification.fit import WarmStart, fit
from furnace_model.identification.ga import genetic_search
from furnace_model.identification.problem import Problem
from furnace_model.log.schema import PARAM_NAMES
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.structure import ModelStructure

HOUR = 3600.0
CFG = RefitConfig(period_s=2 * HOUR, window_s=6 * HOUR)


@pytest.fixture(scope="module")
def windows() -> list[Window]:
    """Six-hour windows every two hours of ten hours of the steady week, 1-minute samples."""
    s = scenario("week_steps", duration_min=10 * 60)
    cutter = WindowCutter(CFG, furnace=PAPER)
    return [w for topic, msg, t in run_messages(simulate(s)) for w in cutter.feed(topic, msg, t)]


def warm_of(res) -> dict:
    return {"offsets": [res.zone_offsets_c[0]],
            "intervals": {p: tuple(v) for p, v in res.ci95.items()}}


@pytest.mark.parametrize("off", [{}, {"a": 1.3, "f": 0.8, "d": 2.0}],
                         ids=["previous optimum", "seed far off"])
def test_the_seeded_search_never_ends_worse_than_its_seed(windows, off):
    """A real window of known truth, fitted from the previous window's optimum and from a
    seed far from it: the search around the seed ends at least as low as the polish from
    the seed alone, having run every generation it was given."""
    first, second = windows[-2].experiment, windows[-1].experiment
    prev = fit([first], zone_offsets=True)
    seed = {p: v * off.get(p, 1.0) for p, v in prev.params.items()}
    polish = fit([second], init=seed, zone_offsets=True, warm=WarmStart(**warm_of(prev)))
    searched = fit([second], init=seed, zone_offsets=True, population=8, generations=10,
                   seed=7, warm=WarmStart(**warm_of(prev), reach=SEEDED_REACH))
    assert searched.generations == 10 and searched.runs[0]["population"] == 8
    assert searched.sse <= polish.sse * (1 + 1e-12), (searched.sse, polish.sse)
    assert searched.per_zone["soak"]["rmse_c"] < 2.0  # the noise is 1.5 / sqrt 2 per zone


def test_the_search_scores_what_the_polish_minimises_and_keeps_its_seed(windows):
    """The search's criterion, with the window's initial states and thermocouple offsets
    held, is the polish's at the same point; seeded, the search's best is never worse than
    the seed, even when the seed is that criterion's own optimum (elitism keeps it)."""
    exp = windows[-1].experiment
    prob = Problem([exp], ModelStructure(furnace=PAPER), {}, {}, zone_offsets=True)
    best = fit([exp], zone_offsets=True)
    zp = prob.to_z(np.array([best.params[p] for p in prob.names]))
    z = prob.start(zp, [np.array([best.zone_offsets_c[0][zone] for zone in PAPER.zones])])
    own = z[prob.k:]
    assert prob.sse_params(z[None, :prob.k], own)[0] == pytest.approx(prob.sse(z), rel=1e-10)
    assert prob.sse_params(z[None, :prob.k])[0] != pytest.approx(prob.sse(z), rel=1e-3)
    for start in (zp, zp + 0.05):
        found = genetic_search(lambda p: prob.sse_params(p, own), prob.lo, prob.hi,
                               population=6, generations=5, rng=np.random.default_rng(3),
                               start=start, spread=0.1)
        assert found.generations == 5
        assert found.best_f <= prob.sse_params(start[None], own)[0]


def test_a_search_around_a_warm_start_needs_one(windows):
    with pytest.raises(FurnaceError, match="needs `init` and method fast"):
        fit([windows[-1].experiment], warm=WarmStart(reach=SEEDED_REACH))


def test_ga_polish_is_the_default_and_its_windows_repeat_by_hand(windows):
    """The chain's window is `fit` around the previous window's result, seeded from the
    window's end: the same by hand, to the bit. The first fitted window is the offline
    fast search."""
    assert RefitConfig().method == "ga_polish"
    chain = RefitChain(CFG, furnace=PAPER)
    out = [chain.process(w)[0].to_json() for w in windows]
    ok = [i for i, m in enumerate(out) if m["status"] == "ok"]
    assert len(ok) >= 2 and ok[1] == ok[0] + 1, [m["status"] for m in out]
    first, prev, this = out[ok[0]], out[ok[1] - 1], out[ok[1]]
    seed = pd.Timestamp(this["window_end"]).value // 10**9
    assert seed == window_seed(windows[ok[1]])
    population, generations = CFG.ga_size()
    assert this["search"] == {"method": "ga_polish", "warm_start": True,
                              "population": population, "generations": generations,
                              "seed": seed}
    assert first["search"] == {"method": "ga_polish", "warm_start": False, "population": 32,
                               "generations": 30,
                               "seed": pd.Timestamp(first["window_end"]).value // 10**9}
    by_hand = fit([windows[ok[1]].experiment], init={p: prev[p] for p in PARAM_NAMES},
                  zone_offsets=True, seed=seed, population=population,
                  generations=generations,
                  warm=WarmStart([prev["zone_offsets_c"]],
                                 {p: tuple(v) for p, v in prev["ci95"].items()},
                                 SEEDED_REACH))
    assert all(by_hand.params[p] == this[p] for p in PARAM_NAMES)
    cold = fit([windows[ok[0]].experiment], zone_offsets=True, seed=first["search"]["seed"])
    assert all(cold.params[p] == first[p] for p in PARAM_NAMES)


def test_a_search_cut_by_the_budget_fails_the_window_and_keeps_the_model(windows):
    """More generations than the budget allows: the search stops at half the budget on the
    wall clock, and a result that depends on the host's speed is not kept."""
    chain = RefitChain(CFG, furnace=PAPER)
    out = [chain.process(w)[0].to_json() for w in windows[:-1]]
    kept = chain.model
    assert kept is not None, [m["status"] for m in out]
    chain.config = replace(CFG, budget_s=0.3, generations=10_000_000)
    msg = chain.process(windows[-1])[0].to_json()
    assert msg["status"] == "failed" and "time budget" in msg["detail"], msg["detail"]
    assert msg["elapsed_s"] >= 0.15 and msg["search"]["generations"] < 10_000_000
    assert msg["model_window_end"] == kept.window_end
    assert all(msg[p] == kept.params[p] for p in PARAM_NAMES)


def test_a_log_that_records_no_method_replays_with_the_polish():
    """Logs written before the methods were named were fitted by the polish alone."""
    recorded = {"period_s": 900.0, "window_s": 86400.0, "step_s": 60.0, "budget_s": 30.0}
    assert refit_config(recorded).method == "polish"
    assert refit_config({**recorded, "method": "ga_polish"}).method == "ga_polish"
