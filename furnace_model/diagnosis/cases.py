"""Known-truth cases for checking the diagnosis: the plant simulator with one effect (or none,
or two, or a fault outside the effect library) switched on, seen the way a plant engineer
would see it -- two heat-ups, noisy biased thermocouples, and nothing said about the effect
(`draw_case`). `furnace_model.diagnosis.selfcheck` diagnoses them and judges the verdicts.

A case is two experiments like the paper's: each a cold heat-up of 3000-3500 minutes at
1-minute samples, thermocouple noise sd 1.5 °C and a fixed bias per thermocouple (sd
0.5 °C, drawn anew per experiment: thermocouples change between campaigns). The first is
given to the diagnosis to fit, the second is held out. Burner schedules are random heat-ups
(several steps, the total mostly rising); in the fitted experiment the heating- and
preheating-zone burners fire for part of the run, so that an effect tied to them can show.

The effect belongs to the furnace, so its parameters are the same in both experiments; times
(a fuel switch, the start of a drift) count from each heat-up's start: the switch comes at
the same point of the heat-up procedure. Strengths are drawn from physically meaningful
ranges (each effect's `drawn.ranges`), not from what the diagnosis finds easy: a draw whose
effect the baseline absorbs is the selfcheck's to report, not to avoid.

`form="other"` draws the effect in a formulation the diagnosis's candidate does not use (a
second- or third-order sensor lag, radiation with an emissivity that changes with temperature
(no power law) and another reference temperature, a quadratic burner curve, a wall of two
layers in every zone or in one, losses from one zone only), so that the check does not
merely find our own equations back.

Perturbations outside the library (`OUT_OF_LIBRARY`: a door left open, a thermocouple that
intermittently reads low; `furnace_model.diagnosis.faults`) no candidate can express; the
honest verdict for them is `unexplained`, with the zone or sensor located.

Any furnace description (`furnace`): the cases are heat-ups of its network, with its zones,
burners and thermocouples, and every effect made for it (`Drawn.draw(..., furnace)`). The
paper's furnace runs on Table V; any other on `network_truth`: the network's default rates
(network.parameters) with one heat per burner for every heated zone, set so that every
burner firing would hold the hottest zone 3000 °C above ambient, as Table V's would
(3387 °C): the schedules then heat it as the paper's heat-ups do. Own-zone burners on a
furnace whose description has each zone's burners heat their own (`burner_heat: own_zone`)
are checked on the same description read the paper's way (`ZoneBurners.drawn`):
the plant is the description itself, the records are given to the diagnosis as of the
furnace with every burner heating the first zone, whose model lacks what the plant does.
"""

from __future__ import annotations

import dataclasses
import zlib
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..effects import EFFECTS, Effect
from ..experiment import Experiment
from ..shipped import shipped
from ..simulation.furnace import Furnace
from ..simulation.network import parameters, terms
from ..simulation.parameters import PAPER_TABLE_V
from ..simulation.plant import Plant
from ..simulation.scenario import Scenario, SensorSpec, load_scenario
from ..simulation.structure import Inputs, ModelStructure
from .faults import FAULTS

OUT_OF_LIBRARY = tuple(FAULTS)
"""Perturbations no candidate expresses (`furnace_model.diagnosis.faults`): the diagnosis
should say `unexplained`."""

FORMS = ("candidate", "other")
NOISE = ("white", "low-pass", "noisier-holdout")
"""The thermocouples of a case: white noise of 1.5 °C in both heat-ups (the paper's
reading); low-pass noise, as a sheathed thermocouple and its transmitter give (a first-order
autoregression of 0.5-0.9 per minute, with white noise of 0.3-1.5 °C on top in half the
draws); or the held-out heat-up's thermocouples one to three times as noisy as the fitted
one's (a campaign with other thermocouples)."""

SENSORS_SPEC = SensorSpec(noise_sd_c=1.5, bias_sd_c=0.5)
SAMPLE_MIN = 1.0
DURATION_MIN = (3000.0, 3500.0)
T_MAX_C = 1350.0
"""A schedule that would drive a zone past this is redrawn: no reheating furnace runs there."""

@dataclass
class Case:
    """Two experiments with a known truth, and what the diagnosis should conclude."""

    fit: list[Experiment]
    holdout: list[Experiment]
    truth: dict[str, dict]
    """Effect (or perturbation) name -> its drawn parameters and options; {} for a control."""
    description: str
    form: str = "candidate"
    effects: tuple[str, ...] = field(default=())

    @property
    def expected_status(self) -> str:
        if not self.effects:
            return "no_gap"
        if any(e in OUT_OF_LIBRARY for e in self.effects):
            return "unexplained"
        return "explained"

    @property
    def library_effects(self) -> tuple[str, ...]:
        return tuple(e for e in self.effects if e in EFFECTS)


DISTURBANCE_SHARE = 0.1
"""`network_truth`: a disturbance's pull at its largest, as a share of the strongest zone's
heating rate at full fire."""
TARGET_RISE_C = 3000.0
"""`network_truth`: the hottest zone's steady rise above ambient with every burner firing."""


def network_truth(furnace: Furnace) -> dict[str, float]:
    """The true parameters of a furnace's cases: Table V for the paper's; for any other the
    network's defaults with one heat per burner (every heated zone alike) scaled so that all
    burners firing would hold the hottest zone `TARGET_RISE_C` above ambient. Eq. 11's
    network has Table V, whatever its zones are called."""
    values = {p.name: p.default for p in parameters(furnace)}
    if furnace.paper_structure:
        values.update(PAPER_TABLE_V)
    else:
        structure = ModelStructure(furnace=furnace)
        system = structure.system(structure.theta(values))
        u = np.zeros(furnace.n_inputs)
        u[:furnace.n_zones] = [h.max for h in furnace.heat_inputs]  # every zone at full fire
        rise = float(np.max(-np.linalg.solve(system.A[0], system.B[0] @ u)))
        for t in terms(furnace):
            if t.kind == "gain":
                values[t.name] *= TARGET_RISE_C / rise
    # A disturbance at its largest takes from each zone it enters a tenth of the heating
    # rate of the furnace's strongest zone at full fire: a sink, as charged slabs are.
    full = max(values[t.name] * furnace.heat_inputs[t.to].max for t in terms(furnace)
               if t.kind == "gain")
    for t in terms(furnace):
        if t.kind == "disturbance":
            values[t.name] = -DISTURBANCE_SHARE * full / furnace.disturbances[t.src].scale
    return values


def draw_case(effect: str | tuple[str, ...] | None, rng: np.random.Generator, *,
              form: str = "candidate",
              sensors: tuple[SensorSpec, SensorSpec] = (SENSORS_SPEC, SENSORS_SPEC),
              furnace: Furnace) -> Case:
    """A random two-experiment case with `effect` (a contract name, one of OUT_OF_LIBRARY,
    several of them, or None for a control) switched on in the plant of `furnace`;
    `sensors`: the thermocouples of the fitted and of the held-out heat-up (campaigns
    differ)."""
    names: tuple[str, ...] = () if effect is None else (
        (effect,) if isinstance(effect, str) else tuple(effect))
    unknown = [n for n in names if n not in EFFECTS and n not in OUT_OF_LIBRARY]
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown}; expected names from "
                         f"{list(EFFECTS) + list(OUT_OF_LIBRARY)}")
    if form not in FORMS:
        raise ValueError(f"form must be one of {FORMS}, not {form!r}")
    durations = np.round(rng.uniform(*DURATION_MIN, 2))
    t_air = float(rng.uniform(15.0, 35.0))
    start = pd.Timestamp("2026-01-05T06:00:00Z") + pd.Timedelta(days=int(rng.integers(0, 300)))
    starts = [start, start + pd.Timedelta(days=int(rng.integers(3, 15)))]

    effects: list[Effect] = []
    values: dict[str, float] = network_truth(furnace)
    truth: dict[str, dict] = {}
    seen_as = furnace  # the furnace the records are given to the diagnosis as
    for name in names:
        if name not in EFFECTS:
            continue
        other = EFFECTS[name].drawn.check_furnace(furnace)
        if other != furnace:
            # the plant is the description itself; the model reads it another way
            seen_as = other
            truth[name] = {"as_furnace": other.name,
                           **{k: v for k, v in values.items() if k.startswith("gain_")}}
            continue
        eff, vals, info = _draw_effect(name, rng, form, float(durations.min()), furnace)
        effects.append(eff)
        values.update(vals)
        truth[name] = {**vals, **info}
    structure = ModelStructure(effects, furnace=furnace)

    faults = [f for f in FAULTS.values() if f.name in names]
    for f in faults:
        truth[f.name] = f.draw(rng, durations, furnace)

    exps = []
    for j in range(2):
        t = np.arange(0.0, durations[j] + SAMPLE_MIN / 2, SAMPLE_MIN)
        x0 = np.full(furnace.n_zones, t_air)
        inputs = _draw_schedule(rng, structure, values, t, x0, t_air, spread=(j == 0))
        plant = Plant(structure, values, sensors[j], seed=int(rng.integers(2**31)))
        run = None
        for f in faults:
            run = run or f.run(plant, inputs, t, x0, truth[f.name], j)
        run = run or plant.run(inputs, t, x0)
        run.start_time = starts[j]
        for f in faults:
            f.read(run, truth[f.name], j)
        exp = run.to_experiment(f"exp{j + 1}")
        if seen_as != furnace:
            exp = dataclasses.replace(exp, furnace=seen_as)
        exps.append(exp)
    many = not furnace.paper_structure  # where an effect's zones are one place of many
    description = (", ".join(f"{n}({_short(truth[n], many)})" for n in names)
                   or "no effect") + \
        f"; form {form}; durations {durations[0]:g} and {durations[1]:g} min"
    return Case(fit=[exps[0]], holdout=[exps[1]], truth=truth, description=description,
                form=form, effects=names)


PRODUCTION = "config/scenarios/paper_production.yaml"
"""The closed-loop cases' scenario (`draw_closed_loop_case`), a shipped file."""


def production_scenario() -> Scenario:
    """The closed-loop cases' scenario (`PRODUCTION`), loaded."""
    return load_scenario(shipped(PRODUCTION))


def draw_closed_loop_case(effect: str | tuple[str, ...] | None, rng: np.random.Generator, *,
                          form: str = "candidate",
                          sensors: tuple[SensorSpec, SensorSpec] = (SENSORS_SPEC, SENSORS_SPEC),
                          scenario: Scenario | None = None) -> Case:
    """`draw_case` in production: two records of a closed-loop `scenario` (default the
    shipped paper_production) with `effect` drawn on its furnace, the PLC's loops reading
    the thermocouples (so a drifting one they read moves the true zone) and firing what the
    records carry. The held-out record runs the same programmes with the slabs charged in
    another order. Perturbations outside the library are not drawn in closed loop."""
    scenario = scenario or production_scenario()
    if scenario.control is None:
        raise ValueError(f"scenario '{scenario.name}' has no control section")
    names: tuple[str, ...] = () if effect is None else (
        (effect,) if isinstance(effect, str) else tuple(effect))
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ValueError(f"closed-loop cases draw effects of the library, not {unknown}")
    furnace = scenario.furnace
    effects, values = list(scenario.effects), scenario.values()
    truth: dict[str, dict] = {}
    seen_as = furnace
    for name in names:
        other = EFFECTS[name].drawn.check_furnace(furnace)
        if other != furnace:
            seen_as = other
            truth[name] = {"as_furnace": other.name,
                           **{k: v for k, v in values.items() if k.startswith("gain_")}}
            continue
        eff, vals, info = _draw_effect(name, rng, form, scenario.duration_min, furnace)
        effects.append(eff)
        values.update(vals)
        truth[name] = {**vals, **info}
    structure = ModelStructure(effects, furnace=furnace)
    start = pd.Timestamp("2026-01-05T06:00:00Z") + pd.Timedelta(days=int(rng.integers(0, 300)))
    exps = []
    for j in range(2):
        dist = scenario.steps_disturbances
        if j == 1:  # the same day's slabs in another order, after the start-up's
            charged = np.flatnonzero(scenario.steps_t > 0)
            dist = dist.copy()
            dist[charged] = dist[rng.permutation(charged)]
        run_of = dataclasses.replace(scenario, steps_disturbances=dist,
                                     start_time=start + pd.Timedelta(days=7 * j))
        plant = Plant(structure, values, sensors[j], seed=int(rng.integers(2**31)))
        exp = plant.run_closed_loop(run_of).to_experiment(f"exp{j + 1}")
        if seen_as != furnace:
            exp = dataclasses.replace(exp, furnace=seen_as)
        exps.append(exp)
    description = (", ".join(f"{n}({_short(truth[n])})" for n in names) or "no effect") + \
        f"; closed loop ({scenario.name}); form {form}"
    return Case(fit=[exps[0]], holdout=[exps[1]], truth=truth, description=description,
                form=form, effects=names)


def _short(info: dict, lists: bool = False) -> str:
    """`lists`: say list options too (which zones, on a furnace of many)."""
    parts = []
    for k, v in info.items():
        if isinstance(v, float):
            parts.append(f"{k}={v:.4g}")
        elif isinstance(v, (str, int)):
            parts.append(f"{k}={v}")
        elif lists and isinstance(v, (list, tuple)) and all(isinstance(x, str) for x in v):
            parts.append(f"{k}={','.join(v)}")
    return " ".join(parts)


def _draw_effect(name: str, rng: np.random.Generator, form: str, duration: float,
                 furnace: Furnace) -> tuple[Effect, dict[str, float], dict]:
    """The effect object, its parameter values and its options (for the truth record)."""
    eff, vals = EFFECTS[name].drawn.draw(rng, form, duration, furnace)
    info = {k: (list(v) if isinstance(v, tuple) else v) for k, v in eff.options.items()}
    return eff, {k: float(v) for k, v in vals.items()}, info


def _draw_schedule(rng: np.random.Generator, structure: ModelStructure, values: dict,
                   t: np.ndarray, x0: np.ndarray, t_air: float, spread: bool) -> Inputs:
    """A random heat-up: 4-7 burner steps, the total mostly rising, redrawn until no zone
    passes T_MAX_C. With `spread` the burners are shared among the zones for part of the run
    (heating- and preheating-zone burners fire); otherwise zones are filled soaking first,
    as in the paper, with a random chance of a spread step."""
    furnace = structure.furnace
    nz = furnace.n_zones
    for _ in range(200):
        k = int(rng.integers(4, 8))
        gaps = rng.uniform(1.0, 2.0, k)
        times = np.concatenate(([0.0], np.cumsum(gaps[:-1]) / gaps.sum() * (t[-1] - 100.0)))
        times = np.round(times)
        totals = np.round(np.sort(rng.uniform(2.0, rng.uniform(8.0, 20.0), k)))
        totals[0] = rng.integers(2, 5)
        if rng.uniform() < 0.3 and k > 4:  # a step down now and then: the crew trims the firing
            i = int(rng.integers(2, k))
            totals[i] = max(2.0, totals[i] - rng.integers(2, 5))
        counts = np.zeros((k, nz))
        spread_from = int(rng.integers(1, k - 1))
        for i, total in enumerate(totals.astype(int)):
            if (spread and i >= spread_from) or (not spread and rng.uniform() < 0.2):
                share = rng.dirichlet([2.0] + [1.5] * (nz - 1))
                c = np.minimum(np.floor(share * total), furnace.burners)
                c[0] += total - c.sum()
                c = _fit_counts(c, furnace)
            else:
                c = _fill_soak_first(total, furnace)
            counts[i] = c
        if spread and not _others_fire(counts, furnace):
            continue
        inputs = _in_units(rng, times, counts, t_air, furnace, float(t[-1]))
        y = structure.simulate(values, inputs, t, x0).zones[0]
        if np.nanmax(y) < T_MAX_C:
            return inputs
    raise RuntimeError("no burner schedule below the temperature limit was found")


def _in_units(rng: np.random.Generator, times: np.ndarray, counts: np.ndarray, t_air: float,
              furnace: Furnace, end: float) -> Inputs:
    """The drawn burner counts as each zone is fired (a rate in its unit, a pulse-fired zone
    at a fraction of a burner more or less), and each disturbance drawn as steps every one
    to three hours within its range (0 to 1 where none is declared), merged onto one time
    line."""
    if not furnace.modulated and not furnace.disturbances:
        return Inputs(times, counts, np.full(times.size, t_air))
    heat = counts / furnace.burner_equivalents
    for i, h in enumerate(furnace.heat_inputs):
        if h.kind == "pulse":
            heat[:, i] = np.clip(heat[:, i] + rng.uniform(-0.5, 0.5, len(times)), 0.0, h.max)
    if not furnace.disturbances:
        return Inputs(times, heat, np.full(times.size, t_air))
    grid = [times]
    series = []
    for d in furnace.disturbances:
        lo, hi = d.range if d.range is not None else (0.0, 1.0)
        at = np.concatenate(([0.0], np.cumsum(rng.uniform(60.0, 180.0, 64))))
        at = at[at < end]
        series.append((at, rng.uniform(lo, hi, at.size)))
        grid.append(at)
    t = np.unique(np.concatenate(grid))
    j = np.searchsorted(times, t, side="right") - 1
    dist = np.column_stack([v[np.searchsorted(a, t, side="right") - 1] for a, v in series])
    return Inputs(t, heat[j], np.full(t.size, t_air), dist)


def _others_fire(counts: np.ndarray, furnace: Furnace) -> bool:
    """The paper's: heating- and preheating-zone burners fire together in some step. On a
    furnace of more zones: every zone after the first with burners fires in some step (a
    zone whose burners never fire in the fitted run leaves its heat per burner unseen)."""
    if counts.shape[1] == 3:
        return bool(np.any((counts[:, 1] > 0) & (counts[:, 2] > 0)))
    has = np.array(furnace.burners[1:]) > 0
    return bool(np.all((counts[:, 1:] > 0).any(axis=0) | ~has))


def _fill_soak_first(total: int, furnace: Furnace) -> np.ndarray:
    c = np.zeros(furnace.n_zones)
    left = total
    for i, cap in enumerate(furnace.burners):
        c[i] = min(left, cap)
        left -= c[i]
    return c


def _fit_counts(c: np.ndarray, furnace: Furnace) -> np.ndarray:
    """Move burners that exceed a zone's count to the next zone with room."""
    c = c.copy()
    caps = np.array(furnace.burners, dtype=float)
    extra = np.maximum(c - caps, 0.0).sum()
    c = np.minimum(c, caps)
    for i in range(furnace.n_zones):
        add = min(extra, caps[i] - c[i])
        c[i] += add
        extra -= add
    return c


def case_label(effect: str | tuple[str, ...] | None) -> str:
    if effect is None:
        return "none"
    return effect if isinstance(effect, str) else "+".join(effect)


def parse_label(label: str) -> str | tuple[str, ...] | None:
    """'none' -> None, 'a+b' -> ('a', 'b'), a name -> the name; unknown names refused."""
    if label == "none":
        return None
    parts = tuple(label.split("+"))
    bad = [p for p in parts if p not in EFFECTS and p not in OUT_OF_LIBRARY]
    if bad or not all(parts):
        raise ValueError(f"unknown effect(s) {', '.join(bad) or repr(label)}; expected 'none', "
                         f"names from {', '.join([*EFFECTS, *OUT_OF_LIBRARY])}, or a+b")
    return parts[0] if len(parts) == 1 else parts


def draw_sensors(noise: str, rng: np.random.Generator) -> tuple[SensorSpec, SensorSpec]:
    """The fitted and the held-out heat-up's thermocouples (`NOISE`)."""
    if noise == "white":
        return SENSORS_SPEC, SENSORS_SPEC
    if noise == "low-pass":
        white = float(rng.uniform(0.3, 1.5)) if rng.uniform() < 0.5 else 0.0
        spec = SensorSpec(noise_sd_c=SENSORS_SPEC.noise_sd_c, bias_sd_c=SENSORS_SPEC.bias_sd_c,
                          noise_ar_per_min=float(rng.uniform(0.5, 0.9)), white_sd_c=white)
        return spec, spec
    if noise == "noisier-holdout":
        k = float(rng.uniform(1.0, 3.0))
        return SENSORS_SPEC, SensorSpec(noise_sd_c=k * SENSORS_SPEC.noise_sd_c,
                                        bias_sd_c=SENSORS_SPEC.bias_sd_c)
    raise ValueError(f"noise must be one of {NOISE}, not {noise!r}")


def case_rng(seed: int, label: str, draw: int) -> np.random.Generator:
    """The draw's own stream: the same seed, label and draw give the same case, whatever
    else is checked in the same run."""
    return np.random.default_rng([seed, zlib.crc32(label.encode()), draw])
