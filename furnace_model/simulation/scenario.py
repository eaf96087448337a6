"""Scenarios: a plant (parameters, effects, sensors) and a schedule of its inputs (each
zone's burners or firing rate, the measured disturbances), read from YAML.

config/scenarios/paper_exp1.yaml is the reference: the paper's first experiment with its
Table V parameters. Every key is checked; an error names the file and the key path. A
scenario is of the paper's furnace unless its `furnace` key names a description
(config/furnaces/), by a path relative to the scenario file or by a name in
config/furnaces/ (`six-zone`).

A pulse-fired zone's schedule gives its mean count (duty times burners); the plant fires
it as pulse firing does, every burner on for its duty of each `pulse_cycle_min`, and what is
logged of it is the mean over each row, as `logs export` resamples it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ..config import Node, load_yaml
from ..effects import EFFECTS, Effect, Option
from ..errors import ConfigError
from .control import Control, control_from_node
from .furnace import PAPER, Furnace
from .furnacefile import named_furnace
from .network import parameters
from .structure import Inputs, ModelStructure


@dataclass(frozen=True)
class SensorSpec:
    """The furnace's thermocouples: each reads its zone plus its own bias plus noise.

    The noise is white unless `noise_ar_per_min` is set: a real thermocouple is low-pass
    (sheath, transmitter filter, gas turbulence), so its noise is a first-order
    autoregression with that correlation per minute, and `white_sd_c` adds white noise on
    top (the converter's own)."""

    noise_sd_c: float = 1.5
    bias_sd_c: float = 0.5
    bias_c: tuple[float, ...] | None = None
    """Fixed biases in the furnace's thermocouple order (`furnace.sensors`); when absent they
    are drawn (sd bias_sd_c) from the seed."""
    noise_ar_per_min: float = 0.0
    """Correlation of the noise one minute apart (0: white); its sd stays noise_sd_c."""
    white_sd_c: float = 0.0


@dataclass
class Scenario:
    name: str
    duration_min: float
    sample_min: float
    t_air_c: float
    initial_c: np.ndarray
    params: dict[str, float]
    steps_t: np.ndarray  # (J,) minutes
    steps_burners: np.ndarray  # (J, zones) heat input per zone: burners on, or a rate
    effects: list[Effect] = field(default_factory=list)
    effect_values: dict[str, float] = field(default_factory=dict)
    sensors: SensorSpec = field(default_factory=SensorSpec)
    description: str = ""
    start_time: pd.Timestamp | None = None
    file: str = ""
    furnace: Furnace = field(kw_only=True)
    steps_disturbances: np.ndarray | None = field(default=None, kw_only=True)  # (J, k)
    pulse_cycle_min: float = field(default=1.0, kw_only=True)
    control: Control | None = field(default=None, kw_only=True)
    """The PLC's zone loops (`furnace_model.simulation.control`); None: open loop, every
    input follows the schedule."""

    def __post_init__(self) -> None:
        if self.steps_disturbances is None:
            self.steps_disturbances = np.zeros((np.size(self.steps_t),
                                                len(self.furnace.disturbances)))

    def structure(self) -> ModelStructure:
        return ModelStructure(self.effects, furnace=self.furnace)

    def values(self) -> dict[str, float]:
        return {**self.params, **self.effect_values}

    def inputs(self) -> Inputs:
        """The schedule as the model takes it: pulse-fired zones at their mean count."""
        return Inputs(self.steps_t.astype(float), self.steps_burners.astype(float),
                      np.full(self.steps_t.size, self.t_air_c),
                      self.steps_disturbances.astype(float))

    def plant_inputs(self) -> Inputs:
        """The schedule as the plant is fired: pulse-fired zones burner by burner."""
        return pulse_fired(self.inputs(), self.furnace, self.pulse_cycle_min,
                           self.duration_min)

    def burners_at(self, t_min: float) -> np.ndarray:
        """Heat input per zone (zones,) the schedule asks for at time t_min."""
        return self.steps_burners[self.step_index(t_min)].copy()

    def disturbances_at(self, t_min: float) -> np.ndarray:
        return self.steps_disturbances[self.step_index(t_min)].copy()

    def step_index(self, t_min: float) -> int:
        """The schedule's step in force at t_min."""
        return max(int(np.searchsorted(self.steps_t, t_min, side="right")) - 1, 0)

    def sample_times(self) -> np.ndarray:
        n = int(np.floor(self.duration_min / self.sample_min + 1e-9))
        return np.arange(n + 1) * self.sample_min


def pulse_fired(inputs: Inputs, furnace: Furnace, cycle_min: float,
                end_min: float) -> Inputs:
    """Inputs with each pulse-fired zone's mean count m fired as pulses: in every cycle,
    floor(m) + 1 burners for the fraction m - floor(m) of it and floor(m) for the rest, so
    that the count's mean over a cycle is m. Other zones and inputs are held as given."""
    pulsed = [i for i, h in enumerate(furnace.heat_inputs) if h.kind == "pulse"]
    if not pulsed:
        return inputs
    t = np.asarray(inputs.t, dtype=float)
    end = max(end_min, float(t[-1]))
    ends = np.append(t[1:], end)
    cuts = [t]
    for lo, hi, level in zip(t, ends, inputs.burners, strict=True):
        starts = np.arange(lo, hi, cycle_min)
        cuts.append(starts)
        for i in pulsed:
            if level[i] % 1.0 > 0:
                cuts.append(np.minimum(starts + (level[i] % 1.0) * cycle_min, hi))
    grid = np.unique(np.concatenate(cuts))
    grid = grid[grid < end] if end > t[-1] else grid
    j = np.searchsorted(t, grid, side="right") - 1
    burners = inputs.burners[j].astype(float)
    mid = grid + np.diff(grid, append=end if end > grid[-1] else grid[-1] + cycle_min) / 2
    for i in pulsed:
        mean = burners[:, i]
        base = np.floor(mean)
        # Judged at the middle of each interval of the grid, away from its cut points.
        since = mid - t[j]
        phase = since - np.floor(since / cycle_min) * cycle_min
        burners[:, i] = base + (phase < (mean - base) * cycle_min)
    return Inputs(grid, burners, inputs.t_air[j], inputs.disturbances[j])


def split_total(total: int, fill_order: tuple[str, ...], furnace: Furnace) -> np.ndarray:
    """Burners on per zone when `total` are open, filling zones in order (the paper: soaking
    first, then heating, then preheating)."""
    counts = np.zeros(furnace.n_zones, dtype=int)
    left = total
    for zone in fill_order:
        i = furnace.zones.index(zone)
        counts[i] = min(left, furnace.burners[i])
        left -= counts[i]
    return counts


def load_scenario(path: str | Path, furnace: Furnace | None = None) -> Scenario:
    """A scenario, checked. `furnace`: the description the caller works with (--furnace);
    a scenario of another furnace is an error on its `furnace` key."""
    root = load_yaml(path).mapping({
        "name", "description", "duration_min", "sample_min", "start_time", "t_air_c",
        "initial_c", "model", "burners", "sensors", "effects", "furnace", "disturbances",
        "pulse_cycle_min", "control"})
    own = (named_furnace(root.child("furnace"), Path(path).parent, "the scenario")
           if root.has("furnace") else PAPER)
    if furnace is not None and furnace != own:
        where = ("is of furnace" if root.has("furnace")
                 else "names no furnace, so it is of the paper's furnace")
        raise ConfigError(str(path), "furnace", f"the scenario {where} '{own.name}', not the "
                          f"furnace '{furnace.name}' asked for")
    furnace = own
    zones, nz = furnace.zones, furnace.n_zones
    sensor_names = furnace.sensors
    name = root.get_string("name", Path(path).stem)
    duration = root.get_number("duration_min", lo=1.0, hi=1e7)
    sample = root.get_number("sample_min", 1.0, lo=1e-3, hi=duration)
    t_air = root.get_number("t_air_c", 30.0, lo=-60.0, hi=200.0)

    start_time = root.child("start_time").timestamp() if root.has("start_time") else None

    init = root.child("initial_c", t_air)
    if isinstance(init.value, list):
        initial = np.array([n.number(lo=-60.0, hi=2000.0) for n in init.elements(nz, nz)])
    else:
        initial = np.full(nz, init.number(lo=-60.0, hi=2000.0))

    network = parameters(furnace)
    model = root.child("model", {}).mapping({p.name for p in network})
    params = {p.name: model.get_number(p.name, p.default, lo=p.lo, hi=p.hi) for p in network}

    control = (control_from_node(root.child("control"), furnace, initial, duration)
               if root.has("control") else None)
    # In closed loop the schedule is for the zones no loop drives: all off when absent.
    off = () if control is None else ({"steps": [{"at_min": 0}]},)
    burners = root.child("burners", *off).mapping({"fill_order", "steps"})
    order_node = burners.child("fill_order", list(zones))
    fill = tuple(n.string(zones) for n in order_node.elements(nz, nz))
    if sorted(fill) != sorted(zones):
        raise order_node.error(f"must name each of {', '.join(zones)} once")
    times, counts = [], []
    for step in burners.child("steps").elements(min_len=1):
        step.mapping({"at_min", "total", *zones})
        at = step.get_number("at_min", lo=0.0, hi=duration)
        if times and at <= times[-1]:
            raise step.child("at_min").error(f"steps must be in time order; {at:g} follows {times[-1]:g}")
        if step.has("total"):
            if any(step.has(z) for z in zones):
                raise step.error("give either 'total' or per-zone counts, not both")
            if furnace.modulated:
                raise step.child("total").error("a total of burners needs every zone fired "
                                                "by whole burners: give each zone's input")
            total = step.get_integer("total", lo=0, hi=sum(furnace.burners))
            counts.append(split_total(total, fill, furnace))
        else:
            counts.append(np.array([
                step.get_integer(z, 0, lo=0, hi=furnace.burners[i]) if h.whole
                else step.get_number(z, 0.0, lo=0.0, hi=h.max)
                for i, (z, h) in enumerate(zip(zones, furnace.heat_inputs, strict=True))]))
        times.append(at)
    if times[0] != 0.0:
        raise burners.child("steps").error("the first step must be at_min: 0")
    times, counts, dist = _with_disturbances(root, furnace, duration, times, counts)
    cycle = root.get_number("pulse_cycle_min", 1.0, lo=1e-3, hi=60.0)

    sensors_node = root.child("sensors", {}).mapping(
        {"noise_sd_c", "bias_sd_c", "bias_c", "noise_ar_per_min", "white_sd_c"})
    bias = None
    if sensors_node.has("bias_c"):
        bias = tuple(n.number(lo=-50.0, hi=50.0)
                     for n in sensors_node.child("bias_c").elements(len(sensor_names),
                                                                     len(sensor_names)))
    sensors = SensorSpec(
        noise_sd_c=sensors_node.get_number("noise_sd_c", 1.5, lo=0.0, hi=100.0),
        bias_sd_c=sensors_node.get_number("bias_sd_c", 0.5, lo=0.0, hi=50.0),
        bias_c=bias,
        noise_ar_per_min=sensors_node.get_number("noise_ar_per_min", 0.0, lo=0.0, hi=0.999),
        white_sd_c=sensors_node.get_number("white_sd_c", 0.0, lo=0.0, hi=100.0),
    )

    effects, values = [], {}
    effects_node = root.child("effects", {})
    effects_node.mapping()
    for key, node in effects_node.items():
        if key not in EFFECTS:
            raise node.error(f"unknown effect (expected one of: {', '.join(EFFECTS)}; an "
                             "effect of your own is loaded with --effects-from)")
        node.mapping()
        if not node.get_bool("enabled", True):
            continue
        effect, vals = effect_from_yaml(EFFECTS[key], node, furnace)
        effects.append(effect)
        values.update(vals)

    return Scenario(
        name=name, duration_min=duration, sample_min=sample, t_air_c=t_air, initial_c=initial,
        params=params, steps_t=np.array(times), steps_burners=np.array(counts, dtype=float),
        steps_disturbances=dist, pulse_cycle_min=cycle, control=control,
        effects=effects, effect_values=values, sensors=sensors,
        description=root.get_string("description", ""), start_time=start_time, file=str(path),
        furnace=furnace,
    )


def _with_disturbances(root: Node, furnace: Furnace, duration: float, times: list[float],
                       counts: list[np.ndarray]
                       ) -> tuple[list[float], list[np.ndarray], np.ndarray]:
    """`disturbances`: per declared disturbance, `steps` of {at_min, value} (the first at 0),
    within its range. The burner steps and every disturbance's steps are merged onto one
    time line, each holding its last value."""
    declared = {d.name: d for d in furnace.disturbances}
    node = root.child("disturbances", {})
    node.mapping(set(declared))
    missing = [n for n in declared if not node.has(n)]
    if missing:
        raise node.error(f"furnace '{furnace.name}' declares disturbance(s) "
                         f"{', '.join(missing)}: give each its steps")
    series = []
    for name, d in declared.items():
        steps = node.child(name).mapping({"steps"}).child("steps")
        lo, hi = d.range if d.range is not None else (-1e12, 1e12)
        at, val = [], []
        for step in steps.elements(min_len=1):
            step.mapping({"at_min", "value"})
            t = step.get_number("at_min", lo=0.0, hi=duration)
            if at and t <= at[-1]:
                raise step.child("at_min").error(f"steps must be in time order; {t:g} "
                                                 f"follows {at[-1]:g}")
            at.append(t)
            val.append(step.get_number("value", lo=lo, hi=hi))
        if at[0] != 0.0:
            raise steps.error("the first step must be at_min: 0")
        series.append((np.array(at), np.array(val)))
    if not series:
        return times, counts, np.zeros((len(times), 0))
    grid = np.unique(np.concatenate([np.array(times)] + [a for a, _ in series]))
    held = np.array(counts)[np.searchsorted(times, grid, side="right") - 1]
    dist = np.column_stack([v[np.searchsorted(a, grid, side="right") - 1] for a, v in series])
    return grid.tolist(), list(held), dist


def effect_from_yaml(cls: type[Effect], node: Node, furnace: Furnace
                     ) -> tuple[Effect, dict[str, float]]:
    """`effects.<name>` of a scenario: the effect on `furnace` with its options, and its
    parameter values (each within its search box); the options the class declares for that
    furnace (its zones and thermocouples) are the keys allowed beside its parameters. An
    effect that cannot apply to the furnace is an error on its key, with the reason."""
    why = cls.refusal(furnace)
    if why:
        raise node.error(f"{cls.name} does not apply to furnace '{furnace.name}': {why}")
    specs = cls.specs(furnace)
    options = {key: _option(node.child(key), spec)
               for key, spec in specs.items() if node.has(key)}
    implied = cls.options_from_params(set(node.keys()))
    try:
        effect = cls(**{**implied, **options}, furnace=furnace)
    except ValueError as exc:
        raise node.error(str(exc)) from None
    node.mapping({"enabled", *specs, *(p.name for p in effect.params)})
    return effect, {p.name: node.get_number(p.name, p.default, lo=p.lo, hi=p.hi)
                    for p in effect.params}


def _option(node: Node, spec: Option) -> object:
    if spec.kind == "number":
        return node.number(lo=spec.lo, hi=spec.hi)
    if spec.kind == "integer":
        return node.integer(lo=spec.lo, hi=spec.hi)
    if spec.kind == "choice":
        return node.string(spec.choices)
    names = {n.string(spec.choices) for n in node.elements(min_len=1, max_len=len(spec.choices))}
    return tuple(c for c in spec.choices if c in names)
