"""`refit.method: ga`: the paper's genetic search on every window, from scratch, in the
worker process under the same time budget as the default polish."""

from __future__ import annotations

from dataclasses import replace

from refit_helpers import scenario, simulate, through_pipeline

from furnace_daq.daqconfig import RefitConfig
from furnace_daq.plantlog import run_messages
from furnace_daq.refit import RefitChain, WindowCutter
from furnace_model.log.schema import PARAM_NAMES
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.structure import ModelStructure

HOUR = 3600.0
GA = RefitConfig(period_s=2 * HOUR, window_s=4 * HOUR, method="ga", population=12,
                 generations=150)


def test_ga_refits_in_the_worker_say_so_and_stay_in_the_search_box():
    s = scenario("week_steps", duration_min=10 * 60)
    run = simulate(s)
    params, _ = through_pipeline(run, GA)
    fitted = [m for m in params if m["status"] != "insufficient_excitation"]
    assert len(fitted) >= 3 and all(m["status"] == "ok" for m in fitted), \
        [(m["status"], m["detail"]) for m in fitted]
    box = {p.name: (p.lo, p.hi) for p in ModelStructure(furnace=PAPER).params}
    for m in fitted:
        assert m["search"] == {"method": "ga", "warm_start": False, "population": 12,
                               "generations": 150}, m["search"]
        for p in PARAM_NAMES:
            lo, hi = box[p]
            assert lo <= m[p] <= hi, (p, m[p], box[p])
        assert "zone_offsets_c" not in m  # the paper's criterion has none
        assert all(0 < v < 20 for v in m["rmse_c"].values()), m["rmse_c"]
    # every window is searched from scratch: the last one alone, in this process, gives
    # the worker's result to the bit
    cutter = WindowCutter(GA, furnace=PAPER)
    last = [w for topic, msg, t in run_messages(run) for w in cutter.feed(topic, msg, t)][-1]
    alone = RefitChain(GA, furnace=PAPER).process(last)[0].to_json()
    assert alone["window_end"] == fitted[-1]["window_end"]
    assert all(alone[p] == fitted[-1][p] for p in PARAM_NAMES)


def test_a_ga_that_outruns_the_budget_fails_and_keeps_the_model():
    s = scenario("week_steps", duration_min=8 * 60)
    cfg = replace(GA, budget_s=0.3, generations=10_000_000)
    cutter, chain = WindowCutter(cfg, furnace=PAPER), RefitChain(cfg, furnace=PAPER)
    out = [chain.process(w)[0].to_json() for topic, msg, t in run_messages(simulate(s))
           for w in cutter.feed(topic, msg, t)]
    fitted = [m for m in out if m["status"] != "insufficient_excitation"]
    assert fitted and all(m["status"] == "failed" and "time budget" in m["detail"]
                          for m in fitted), [(m["status"], m["detail"]) for m in out]
    for m in fitted:
        assert m["elapsed_s"] >= 0.3 and "a" not in m  # no model yet: absent
        assert m["search"]["method"] == "ga" and m["search"]["generations"] < 10_000_000
