"""Profile intervals on criteria whose crossings are known."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from furnace_model.identification.fit import WarmStart, fit
from furnace_model.identification.profile import profile_interval
from furnace_model.simulation.parameters import PAPER_TABLE_V
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import SensorSpec, load_scenario

HARDEST = SensorSpec(noise_sd_c=1.5, bias_sd_c=0.5, noise_ar_per_min=0.9, white_sd_c=0.7)
"""test_coverage's hardest thermocouples: low-pass noise with white noise on top."""


def test_a_quadratic_criterion_gives_the_linearised_interval():
    lo, hi = profile_interval(lambda z: 100.0 + 4.0 * (z - 1.0) ** 2, 1.0, 0.9, 100.0, 4.0,
                              -10.0, 10.0)
    assert lo == pytest.approx(0.0, abs=0.02) and hi == pytest.approx(2.0, abs=0.02)


def test_a_skewed_criterion_gives_a_skewed_interval():
    """Rising four times as steeply on the right: the crossings at -2 and +0.5."""
    def sse(z):
        return 10.0 + (z ** 2 if z < 0 else 16.0 * z ** 2)

    lo, hi = profile_interval(sse, 0.0, 1.0, 10.0, 4.0, -50.0, 50.0)
    assert lo == pytest.approx(-2.0, rel=0.03) and hi == pytest.approx(0.5, rel=0.03)


def test_a_criterion_flat_up_to_the_box_reaches_it():
    lo, hi = profile_interval(lambda z: 5.0 + min(z, 0.0) ** 2, 0.0, 0.5, 5.0, 1.0, -3.0, 3.0)
    assert lo == pytest.approx(-1.0, rel=0.03) and hi == 3.0


def test_only_the_bracket_is_trusted_beyond_the_crossing():
    """Past the crossing at 2 the criterion falls again (another parameter at its bound):
    the end stays at the first crossing."""
    def sse(z):
        return z * z if z < 3.0 else max(9.0 - 5.0 * (z - 3.0), 0.5)

    lo, hi = profile_interval(sse, 0.0, 0.5, 0.0, 4.0, -np.inf, 40.0)
    assert hi == pytest.approx(2.0, rel=0.03)


@pytest.mark.parametrize("power", [3.0, 4.0])
@pytest.mark.parametrize("half", [5.0, 100.0])
def test_a_trial_near_the_rise_ends_the_search_wherever_it_falls(power, half):
    """A criterion rising faster than the quadratic, searched from a linearised half-width
    at or past the box: the first trial lands far past the rise and the bracket it opens
    narrows by tenths, so a later trial within 5% of the rise ends that side's search,
    which would otherwise go on to its step limit (eight per side)."""
    count = [0]

    def sse(z):
        count[0] += 1
        return 10.0 + 4.0 * abs(z) ** power

    lo, hi = profile_interval(sse, 0.0, half, 10.0, 4.0, -50.0, 50.0)
    assert lo == pytest.approx(-1.0, rel=0.015) and hi == pytest.approx(1.0, rel=0.015)
    assert count[0] <= 12


def test_a_warm_start_finds_the_cold_ends_in_fewer_evaluations():
    """Skewed criteria of random widths and powers, each searched from the linearised
    half-width and again from ends 3% off (a neighbouring window's): both find the
    crossings to 1.5% of their distance (a 2%-wide bracket's middle, or the square root's
    extrapolation from within 5% of the rise), the warm one in under half the evaluations."""
    rng = np.random.default_rng(3)
    counts = {"cold": 0, "warm": 0}
    for _ in range(200):
        left, right = rng.uniform(0.05, 5.0, 2)
        p, q = rng.uniform(1.5, 3.0, 2)
        truth = (-left, right)
        for kind in counts:
            def sse(z, kind=kind, left=left, right=right, p=p, q=q):
                counts[kind] += 1
                return 10.0 + 4.0 * (abs(z / left) ** p if z < 0 else (z / right) ** q)
            start = None if kind == "cold" else tuple(t * (1 + rng.normal(0, 0.03))
                                                       for t in truth)
            ends = profile_interval(sse, 0.0, 1.0, 10.0, 4.0, -50.0, 50.0, start)
            for end, t in zip(ends, truth, strict=True):
                assert end == pytest.approx(t, rel=0.015), (kind, ends, truth)
    assert counts["warm"] < 0.5 * counts["cold"], counts


def test_a_start_that_is_no_guide_is_searched_as_from_scratch():
    def sse(z):
        return 10.0 + (z ** 2 if z < 0 else 16.0 * z ** 2)

    cold = profile_interval(sse, 0.0, 1.0, 10.0, 4.0, -50.0, 50.0)
    for start in [(np.nan, np.nan), (1.0, -1.0), (-40.0, 30.0)]:
        lo, hi = profile_interval(sse, 0.0, 1.0, 10.0, 4.0, -50.0, 50.0, start)
        assert lo == pytest.approx(cold[0], rel=0.02) and hi == pytest.approx(cold[1], rel=0.02)


@pytest.mark.parametrize("name", ["paper_exp1", "paper_exp2"])
def test_a_profile_correlated_with_one_before_starts_from_its_ends(scenarios, monkeypatch,
                                                                  name):
    """e, profiled after d (their correlation near 1), starts from where d's refits put it
    at d's ends: it ends where its own search from the linearised half-width does, to that
    search's widths (2% of the distance on the search scale), in fewer refits."""
    from furnace_model.identification import fit as fit_module

    sc = load_scenario(scenarios / f"{name}.yaml")
    exp = Plant.from_scenario(sc, seed=1).run_scenario(sc).to_experiment()
    searches: list[tuple[float, int]] = []
    search = fit_module.profile_interval

    def counted(sse_at, z_hat, *args):
        count = [0]

        def each(z):
            count[0] += 1
            return sse_at(z)

        ends = search(each, z_hat, *args)
        searches.append((z_hat, count[0]))
        return ends

    monkeypatch.setattr(fit_module, "profile_interval", counted)
    guided = fit([exp], seed=1)
    assert guided.profiled == ["d", "e"]
    (_, _), (z_e, n_guided) = searches
    searches.clear()
    cold = fit([exp], seed=1, profile=["e"])
    assert cold.profiled == ["e"] and searches[0][0] == z_e
    n_cold = searches[0][1]
    assert n_guided < n_cold, (n_guided, n_cold)
    for g, c in zip(np.log(guided.ci95["e"]), np.log(cold.ci95["e"]), strict=True):
        assert g == pytest.approx(c, abs=0.02 * abs(c - z_e)), (guided.ci95["e"], cold.ci95["e"])


@pytest.mark.slow
def test_warm_started_window_intervals_equal_the_cold_ones(scenarios):
    """Consecutive refit windows (45 h, 15 min apart) of the paper's first heat-up, hardest
    thermocouples (low-pass noise with white on top), whose d and e (and b, c) the windows
    leave wide: each window fitted from the one before, as the daemon does, its profiles
    started once at the previous window's ends (warm) and once from scratch (cold).

    Where the criterion crosses the rise once (the lower ends, towards fast zones), a warm
    end is the cold one to 2% of its distance from the estimate (seen: under 1.5%). The
    upper ends lie in a long tail where the criterion is nearly flat and has more than one
    crossing (a refit held far out lands in another basin): there either search stops at
    some crossing, and the two agree to 10% of the distance (seen: under 9%). Both hold the
    plant's truth alike."""
    sc = replace(load_scenario(scenarios / "paper_exp1.yaml"), sensors=HARDEST)
    exp = Plant.from_scenario(sc, seed=1).run_scenario(sc).to_experiment()
    prev = fit([exp.between(0.0, 2700.0)], init={k: v * 1.05 for k, v in PAPER_TABLE_V.items()},
               zone_offsets=True)
    compared = 0
    for k in range(1, 4):
        window = exp.between(15.0 * k, 15.0 * k + 2700.0)
        warm = fit([window], init=prev.params, zone_offsets=True,
                   warm=WarmStart(prev.zone_offsets_c, dict(prev.ci95)))
        cold = fit([window], init=prev.params, zone_offsets=True,
                   warm=WarmStart(prev.zone_offsets_c, None))
        assert warm.params == cold.params and warm.profiled == cold.profiled
        assert {"d", "e"} <= set(cold.profiled)
        for name in cold.profiled:
            z = np.log(cold.params[name])
            for side, tol in ((0, 0.02), (1, 0.10)):
                zw, zc = np.log(warm.ci95[name][side]), np.log(cold.ci95[name][side])
                assert abs(zw - zc) <= tol * abs(zc - z), (k, name, warm.ci95[name],
                                                           cold.ci95[name])
                compared += 1
            truth = PAPER_TABLE_V[name]
            assert (warm.ci95[name][0] <= truth <= warm.ci95[name][1]) \
                == (cold.ci95[name][0] <= truth <= cold.ci95[name][1])
        prev = warm
    assert compared >= 24


def test_a_fit_that_misses_its_noise_floor_keeps_its_intervals_linearised(scenarios, tmp_path):
    """The paper's first heat-up with each burner 25% weaker from minute 1500, an effect the
    model leaves out: the fit misses the noise floor, where no parameter set is the truth for
    a profile to cover, so its wide parameters are not profiled and a warning says why. The
    same record without the effect is fitted to its floor and profiled."""
    text = (scenarios / "paper_exp1.yaml").read_text()
    assert "\neffects: {}\n" in text
    weaker = tmp_path / "weaker.yaml"
    weaker.write_text(text.replace("\neffects: {}\n", "\neffects:\n  fuel_change: "
                                   "{t_fuel: 1500, fuel_ratio: 0.75}\n"))
    results = {}
    for name, path in (("plain", scenarios / "paper_exp1.yaml"), ("weaker", weaker)):
        sc = load_scenario(path)
        exp = Plant.from_scenario(sc, seed=1).run_scenario(sc).to_experiment().between(0, 2700)
        results[name] = fit([exp], init={k: v * 1.05 for k, v in PAPER_TABLE_V.items()},
                            zone_offsets=True)
    plain, weaker_fit = results["plain"], results["weaker"]
    assert {"d", "e"} <= set(plain.profiled)
    assert not any("not profiled" in w for w in plain.warnings)
    assert weaker_fit.profiled == []
    said = [w for w in weaker_fit.warnings if w.startswith("intervals linearised, not profiled")]
    assert said and "misses the noise floor" in said[0], weaker_fit.warnings
    assert "offset may carry part of the model's error" in said[0]  # fitted with offsets
    worst = max(weaker_fit.per_zone, key=lambda z: weaker_fit.per_zone[z]["rmse_c"])
    assert worst in said[0]


def test_a_trial_far_outside_is_known_outside_before_its_refit_ends(scenarios, monkeypatch):
    """The paper's first heat-up without zone offsets leaves d on its upper bound and its
    linearised half-width past the box, so its profile's first trial lands on the box's
    far edge, far above the rise: its refit stops once it cannot come back below (reason
    "above"), and the intervals are those that refits run to their end give."""
    from furnace_model.identification import fit as fit_module
    from furnace_model.identification.problem import Problem

    sc = load_scenario(scenarios / "paper_exp1.yaml")
    exp = Plant.from_scenario(sc, seed=1).run_scenario(sc).to_experiment()
    polish = Problem._polish
    reasons: list[str] = []

    def counted(self, *args, **kwargs):  # a polish is a generator (Problem._polish)
        done = yield from polish(self, *args, **kwargs)
        reasons.append(done.reason)
        return done

    monkeypatch.setattr(Problem, "_polish", counted)
    early = fit([exp])
    assert {"d", "e"} <= set(early.profiled) and "above" in reasons
    monkeypatch.setattr(fit_module, "PROFILE_OUTSIDE", np.inf)
    reasons.clear()
    full = fit([exp])
    assert "above" not in reasons
    for name in ("d", "e"):
        assert early.ci95[name] == pytest.approx(full.ci95[name], rel=1e-3), name
