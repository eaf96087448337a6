"""Online refits on simulated runs with known truth: accuracy once the window holds burner
steps, windows on the data clock, excitation checks, failures that keep the previous model,
the refit: config section and the atomic state file."""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import pandas as pd
import pytest
from refit_helpers import scenario, simulate, through_pipeline

from furnace_daq.daqconfig import RefitConfig, parse_config
from furnace_daq.plantlog import run_messages
from furnace_daq.refit import RefitChain, WindowCutter
from furnace_daq.refitworker import RefitRunner
from furnace_daq.statefile import write_json_atomic
from furnace_model.config import Node
from furnace_model.errors import ConfigError
from furnace_model.identification.fit import WarmStart, fit
from furnace_model.log.schema import MODEL_PARAMETERS, PARAM_NAMES
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.structure import Inputs

HOUR = 3600.0



def as_json(result: tuple) -> tuple[dict, list[dict]]:
    """A chain's (message, events) as they are logged."""
    msg, events = result
    return msg.to_json(), [e.to_json() for e in events]

def combos(p: dict) -> dict[str, float]:
    """What 1-minute data determine (docs/identification.md): a, f, b/c, d/e."""
    return {"a": p["a"], "f": p["f"], "b/c": p["b"] / p["c"], "d/e": p["d"] / p["e"]}


def test_online_refits_recover_the_plant_within_3_percent():
    s = scenario("week_steps", duration_min=3 * 1440)
    cfg = RefitConfig(period_s=3 * HOUR, window_s=24 * HOUR)
    params, events = through_pipeline(simulate(s), cfg)
    truth = combos(s.params)
    assert len(params) == 3 * 8  # one per period of the data clock, none skipped
    ends = [pd.Timestamp(m["window_end"]) for m in params]
    assert all((e - s.start_time) / pd.Timedelta(hours=3) % 1 == 0 for e in ends)
    assert all(pd.Timestamp(m["window_end"]) - pd.Timestamp(m["window_start"])
               == pd.Timedelta(hours=24) for m in params)
    ok = [m for m in params if m["status"] == "ok"]
    # the first day's windows are not yet full: more than 20% of their samples are missing
    assert [m["status"] for m in params[:6]] == ["insufficient_excitation"] * 6
    assert len(ok) >= 16
    for m in ok:
        assert m["burner_steps"] >= 2
        got = combos(m)
        for name, want in truth.items():
            assert abs(got[name] / want - 1) < 0.03, (m["window_end"], name, got[name], want)
        assert all(0.8 < v < 1.4 for v in m["rmse_c"].values()), m["rmse_c"]  # noise 1.5/sqrt 2
        for p in PARAM_NAMES:
            lo, hi = m["ci95"][p]
            assert lo <= m[p] <= hi
    assert events == [], "a steady plant raises no event"


def test_windows_follow_the_data_clock_and_a_static_window_keeps_the_model():
    """Burners frozen for the last 8 h: those windows have no step, the model stays."""
    s = scenario("week_steps", duration_min=20 * 60)
    keep = s.steps_t < 12 * 60
    s.steps_t, s.steps_burners = s.steps_t[keep], s.steps_burners[keep]
    s.steps_disturbances = s.steps_disturbances[keep]
    cfg = RefitConfig(period_s=2 * HOUR, window_s=6 * HOUR)
    cutter, chain = WindowCutter(cfg, furnace=PAPER), RefitChain(cfg, furnace=PAPER)
    out = []
    for topic, msg, t in run_messages(simulate(s)):
        for w in cutter.feed(topic, msg, t):
            out.append(chain.process(w)[0].to_json())
    statuses = [m["status"] for m in out]
    assert statuses[:2] == ["insufficient_excitation"] * 2  # window not yet full
    last_ok = max(i for i, st in enumerate(statuses) if st == "ok")
    static = [m for m in out if m["burner_steps"] == 0]
    assert static, statuses
    for m in static:
        assert m["status"] == "insufficient_excitation"
        assert "burner change" in m["detail"]
        assert m["model_window_end"] == out[last_ok]["window_end"]
        assert all(m[p] == out[last_ok][p] for p in PARAM_NAMES)


def test_gaps_beyond_the_limit_are_insufficient_and_late_windows_recover():
    s = scenario("week_steps", duration_min=18 * 60)
    cfg = RefitConfig(period_s=3 * HOUR, window_s=6 * HOUR, max_gap_fraction=0.2)
    msgs = [(tp, m, t) for tp, m, t in run_messages(simulate(s))]
    t0 = msgs[0][2]
    # the daemon was stopped from hour 7 to hour 9: windows holding that gap lack 2 of 6 h
    lo, hi = t0 + int(7 * HOUR * 1e9), t0 + int(9 * HOUR * 1e9)
    msgs = [x for x in msgs if not lo <= x[2] < hi]
    cutter, chain = WindowCutter(cfg, furnace=PAPER), RefitChain(cfg, furnace=PAPER)
    by_end = {}
    for topic, msg, t in msgs:
        for w in cutter.feed(topic, msg, t):
            by_end[(w.end_ns - t0) / 3.6e12] = chain.process(w)[0].to_json()
    assert by_end[6.0]["status"] == "ok"
    for h in (9.0, 12.0):
        assert by_end[h]["status"] == "insufficient_excitation"
        assert "missing" in by_end[h]["detail"]
        assert by_end[h]["a"] == by_end[6.0]["a"]
    assert by_end[15.0]["status"] == "ok" and by_end[18.0]["status"] == "ok"


def _collect(cfg: RefitConfig) -> tuple[RefitRunner, list[dict]]:
    got: list[dict] = []
    runner = RefitRunner(cfg, lambda topic, m, t: got.append(m.to_json())
                         if topic == MODEL_PARAMETERS else None, furnace=PAPER)
    return runner, got


def test_a_killed_worker_is_a_failed_window_and_refits_go_on():
    s = scenario("week_steps", duration_min=16 * 60)
    cfg = RefitConfig(period_s=2 * HOUR, window_s=6 * HOUR)
    runner, got = _collect(cfg)
    runner.start()
    killed = False
    try:
        for topic, msg, t in run_messages(simulate(s)):
            runner.feed(topic, msg, t)
            if runner.in_flight is not None and not killed and runner.chain.model is not None:
                os.kill(runner.worker.proc.pid, signal.SIGKILL)
                killed = True
            while runner.busy():
                runner.pump(0.05)
    finally:
        runner.close()
    assert killed
    failed = [i for i, m in enumerate(got) if m["status"] == "failed"]
    assert len(failed) == 1, [(m["status"], m["detail"]) for m in got]
    i = failed[0]
    assert "died" in got[i]["detail"]
    assert got[i]["model_window_end"] == got[i - 1]["model_window_end"]  # previous model kept
    assert all(got[i][p] == got[i - 1][p] for p in PARAM_NAMES)
    assert [m["status"] for m in got[i + 1:]].count("ok") >= 2  # a new worker took over


def test_an_overrun_is_killed_and_a_spent_budget_fails():
    s = scenario("week_steps", duration_min=8 * 60)
    cfg = RefitConfig(period_s=2 * HOUR, window_s=4 * HOUR)
    runner, got = _collect(cfg)
    runner.kill_after_s = 0.0  # every fit outlives its allowance
    runner.start()
    try:
        for topic, msg, t in run_messages(simulate(s)):
            runner.feed(topic, msg, t)
        assert runner.drain(60)
    finally:
        runner.close()
    fitted = [m for m in got if m["status"] != "insufficient_excitation"]
    assert fitted and all(m["status"] == "failed" and "wall time" in m["detail"]
                          for m in fitted), got
    assert all("a" not in m for m in got), "no model yet: absent, never invented values"
    # a fit that runs out of its own budget returns, but its result is not kept
    cutter = WindowCutter(cfg, furnace=PAPER)
    chain = RefitChain(RefitConfig(period_s=2 * HOUR, window_s=4 * HOUR, budget_s=1e-3),
                       furnace=PAPER)
    out = [chain.process(w)[0].to_json() for topic, msg, t in run_messages(simulate(s))
           for w in cutter.feed(topic, msg, t)]
    assert {m["status"] for m in out} == {"insufficient_excitation", "failed"}
    assert any("time budget" in m["detail"] for m in out)


def test_refit_config_section():
    base = {"thermocouples": {s: {"address": i} for i, s in enumerate(
        ("soak_1", "soak_2", "heat_1", "heat_2", "preheat_1", "preheat_2"))},
        "burners": {"modbus": {"soak": {"address": 0}, "heat": {"address": 10},
                               "preheat": {"address": 18}}}}
    assert parse_config(Node(base, "c.yaml")).refit is None
    cfg = parse_config(Node({**base, "refit": {"period_s": 600, "state_dir": "/tmp/s"}},
                            "c.yaml")).refit
    assert (cfg.period_s, cfg.window_s, cfg.step_s, cfg.drift_windows) == (600, 86400, 60, 2)
    assert str(cfg.state_dir) == "/tmp/s"
    assert parse_config(Node({**base, "refit": {"enabled": False}}, "c.yaml")).refit is None
    with pytest.raises(ConfigError, match=r"c.yaml: refit.period_s: must be a whole multiple"):
        parse_config(Node({**base, "refit": {"period_s": 90}}, "c.yaml"))
    with pytest.raises(ConfigError, match=r"refit.window: unknown key"):
        parse_config(Node({**base, "refit": {"window": 90}}, "c.yaml"))


def test_state_file_is_replaced_whole_and_kept_on_failure(tmp_path):
    path = tmp_path / "state" / "model.json"
    write_json_atomic(path, {"a": 0.02, "n": np.int64(3)})
    assert json.loads(path.read_text()) == {"a": 0.02, "n": 3}
    write_json_atomic(path, {"a": 0.03})
    assert json.loads(path.read_text()) == {"a": 0.03}
    with pytest.raises(ValueError):
        write_json_atomic(path, {"a": float("nan")})  # not JSON: refused, old file intact
    assert json.loads(path.read_text()) == {"a": 0.03}
    assert sorted(p.name for p in path.parent.iterdir()) == ["model.json"]


def test_chain_warm_starts_from_the_previous_window():
    """`method: polish`: window k's fit starts at window k-1's result (its parameters, and as
    `WarmStart` its zone offsets and intervals): the same as fitting it by hand so."""
    s = scenario("week_steps", duration_min=12 * 60)
    cfg = RefitConfig(period_s=2 * HOUR, window_s=6 * HOUR, method="polish")
    cutter, chain = WindowCutter(cfg, furnace=PAPER), RefitChain(cfg, furnace=PAPER)
    windows, out = [], []
    for topic, msg, t in run_messages(simulate(s)):
        for w in cutter.feed(topic, msg, t):
            windows.append(w)
            out.append(chain.process(w)[0].to_json())
    i = next(k for k in range(1, len(out)) if out[k]["status"] == "ok"
             and out[k - 1]["status"] == "ok")
    prev = out[i - 1]
    by_hand = fit([windows[i].experiment], init={p: prev[p] for p in PARAM_NAMES},
                  zone_offsets=True, seed=0,
                  warm=WarmStart([prev["zone_offsets_c"]],
                                 {p: tuple(v) for p, v in prev["ci95"].items()}))
    assert all(by_hand.params[p] == out[i][p] for p in PARAM_NAMES)
    assert out[i]["search"] == {"method": "polish", "warm_start": True}
    first = next(m for m in out if m["status"] == "ok")
    assert first["search"] == {"method": "polish", "warm_start": False}  # the fast search


def test_a_chain_restored_from_its_state_goes_on_as_the_original():
    """What a restarted daemon reads back: the same model and references, so the next
    window gives the same message and the same drift judgement as an unbroken chain."""
    s = scenario("week_steps", duration_min=12 * 60)
    cfg = RefitConfig(period_s=2 * HOUR, window_s=6 * HOUR)
    cutter, chain = WindowCutter(cfg, furnace=PAPER), RefitChain(cfg, furnace=PAPER)
    windows = [w for topic, msg, t in run_messages(simulate(s)) for w in cutter.feed(topic, msg, t)]
    for w in windows[:-1]:
        chain.process(w)
    assert chain.model is not None and chain.references
    again = RefitChain(cfg, furnace=PAPER)
    again.restore(json.loads(json.dumps(chain.state())))  # as it goes through the file
    assert again.state() == chain.state()
    (got, got_events), (want, want_events) = (
        as_json(again.process(windows[-1])), as_json(chain.process(windows[-1])))
    assert got.pop("elapsed_s") > 0 and want.pop("elapsed_s") > 0  # the one clock-bound field
    assert (got, got_events) == (want, want_events)
    before = again.state()
    for bad, why in (({"version": 2}, "version 1"), ({"version": 1, "model": 3}, "model"),
                     ({**before, "references": {"a": {"value": 1}}}, "malformed"), ([], "version"),
                     ({**before, "model": {k: v for k, v in before["model"].items()
                                           if k != "ci95"}}, "not a fitted")):
        with pytest.raises(ValueError, match=why):
            again.restore(bad)
        assert again.state() == before  # nothing taken from a bad state


def test_a_backed_up_queue_drops_the_oldest_window_with_an_event():
    """Windows cut faster than they are fitted: beyond queue_max the oldest goes, said so."""
    s = scenario("week_steps", duration_min=30 * 60)
    cfg = RefitConfig(period_s=HOUR, window_s=4 * HOUR, queue_max=2)
    out: list[tuple[str, dict]] = []
    runner = RefitRunner(cfg, lambda topic, m, t: out.append((topic, m.to_json())), max_queue=2,
                         furnace=PAPER)
    runner.start()  # the worker needs a second or more to start: windows pile up meanwhile
    try:
        for topic, msg, t in run_messages(simulate(s)):
            runner.feed(topic, msg, t)
        assert runner.drain(120)
    finally:
        runner.close()
    dropped = [m for topic, m in out if topic != MODEL_PARAMETERS]
    params = [m for topic, m in out if topic == MODEL_PARAMETERS]
    assert runner.dropped > 0 and len(dropped) == runner.dropped
    assert all(m["kind"] == "window_dropped" for m in dropped)
    assert len(params) + len(dropped) == runner.windows == 30
    ends = [m["window_end"] for m in params]
    assert ends == sorted(ends) and not {m["window_end"] for m in dropped} & set(ends)


def test_a_clock_that_jumps_back_starts_the_windows_afresh():
    s = scenario("week_steps", duration_min=12 * 60)
    cfg = RefitConfig(period_s=2 * HOUR, window_s=4 * HOUR)
    msgs = list(run_messages(simulate(s)))
    back = int(24 * HOUR * 1e9)  # the second half replayed a day earlier on the data clock
    half = len(msgs) // 2
    cutter = WindowCutter(cfg, furnace=PAPER)
    windows = [w for topic, msg, t in msgs[:half] for w in cutter.feed(topic, msg, t)]
    n_before = len(windows)
    windows += [w for topic, msg, t in msgs[half:] for w in cutter.feed(topic, msg, t - back)]
    later = windows[n_before:]
    assert later and all(w.end_ns < msgs[half][2] - back + 7 * HOUR * 1e9 for w in later)
    # no window after the jump holds data from before it
    assert all(w.experiment is None or w.experiment.start_time.value >= msgs[half][2] - back
               for w in later)


def test_1hz_polls_averaged_into_minutes_recover_b_and_c():
    """Averages of 60 readings stand for the middle of their minute: timed at the bin start
    they would lag the model by 30 s and bend b and c by 10-15%."""
    s = scenario("week_steps", duration_min=30 * 60)
    s.sample_min = 1.0 / 60.0
    cfg = RefitConfig(period_s=3 * HOUR, window_s=24 * HOUR)
    params, events = through_pipeline(simulate(s), cfg)
    ok = [m for m in params if m["status"] == "ok"]
    assert len(ok) == 4, [(m["window_end"], m["status"], m["detail"]) for m in params]
    for m in ok:
        for p in ("a", "b", "c", "f"):
            assert abs(m[p] / s.params[p] - 1) < 0.03, (m["window_end"], p, m[p])
            assert p not in m["undetermined"]
        assert abs(m["d"] / m["e"] / (s.params["d"] / s.params["e"]) - 1) < 0.03
        assert all(v < 0.2 for v in m["rmse_c"].values())  # 1.5 / sqrt(2 x 60) = 0.14
    assert events == []


def _recent_f_one_step(res, exp, from_min):
    """The recent span's f as one least-squares step of f and the span's starting
    temperatures, the window's offsets held: the model is affine in both, so this is the
    exact minimum the refinement has to reach."""
    from furnace_model.simulation.structure import ModelStructure

    span = exp.between(from_min, np.inf)
    structure = ModelStructure(furnace=PAPER)
    params = dict(res.params)
    states = structure.simulate(params, Inputs.of(exp), exp.t_min, res.x0[0][None],
                                states=True).states[0]
    x = states[np.searchsorted(exp.t_min, span.t_min[0])]

    def run(values, x):
        return structure.simulate(values, Inputs.of(span), span.t_min, x[None]).zones[0]

    base = run(params, x)
    cols = [run({**params, "f": 2 * params["f"]}, x) - base]
    cols += [run(params, x + u) - base for u in np.eye(3)]
    resid = span.zone_temp - np.array([res.zone_offsets_c[0][z] for z in PAPER.zones]) - base
    good = np.isfinite(resid)
    D = np.stack([c[good] for c in cols], axis=1)
    cov = np.linalg.inv(D.T @ D)
    step = cov @ (D.T @ resid[good])
    return params["f"] * (1 + step[0]), params["f"] * res.sigma_c * np.sqrt(cov[0, 0])


def test_recent_f_is_the_least_squares_f_of_the_span():
    """The recent span's f and its standard error are the exact least-squares answer with the
    window's offsets held and its noise level, before a fuel switch. A window across the
    switch is one the model cannot fit (free, its offsets went to +278/+256/+138 °C): held
    to a thermocouple's bias, a span's start may end on what its first readings allow, so
    its f is the bounded problem's, near the free one."""
    from furnace_daq.refit import recent_f

    s = scenario("fuel_switch", duration_min=3300)
    exp = simulate(s).to_experiment("w")
    for end in (2400.0, 3100.0):
        window = exp.between(end - 1440.0, end)
        res = fit([window], zone_offsets=True, seed=0, profile=False)
        bounds = np.array([res.bounds_c[0]["offset"][z][1] for z in PAPER.zones])
        assert np.all(np.abs(res.offsets(0)) <= bounds + 1e-9)
        for span_min in (360.0, 180.0):
            got = recent_f(res, window, end - span_min)
            f, se = _recent_f_one_step(res, window, end - span_min)
            if end == 3100.0:
                assert got["f"] == pytest.approx(f, rel=0.03)
                continue
            assert got["f"] == pytest.approx(f, rel=1e-7)
            assert got["se"] == pytest.approx(se, rel=1e-4)
            assert got["n_samples"] == span_min
    # 3 h after the switch the span's f is nearer the new heat per burner than the window's
    # (which averages both fuels); it rests on the window's a..e, bent by the switch
    new = 0.8 * s.params["f"]
    assert abs(got["f"] - new) < abs(res.params["f"] - new)
    assert got["f"] == pytest.approx(new, rel=0.1)
