"""`furnace-model fit`: identify a..f (and any effect parameters) from heat-up files, print
the paper's tables (runs, genetic mean) with intervals and per-zone errors, and optionally
write the JSON of CONTRACTS.md section 5 and the measured-vs-model plots."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import FurnaceError
from ..extras import require
from ..simulation.parameters import BASELINE
from .arguments import (
    DATA_HELP,
    add_data_window,
    add_effects_from,
    add_furnace,
    furnace_of,
    output_dir,
    output_file,
    positive_int,
    read_data,
)
from .diagnose import effect_list
from .names import METHODS

if TYPE_CHECKING:
    from ..identification.result import FitResult


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fit", help="identify the model's parameters from heat-up data",
                       description=__doc__)
    p.add_argument("data", nargs="+", type=Path, help=f"{DATA_HELP} (fitted jointly)")
    p.add_argument("--method", choices=METHODS, default="fast",
                   help="fast: evolutionary search + least-squares polish (default); "
                        "ga: the paper's genetic algorithm alone")
    p.add_argument("--runs", type=positive_int, default=1, help="independent runs (seed, seed+1, ...)")
    p.add_argument("--population", type=positive_int, help="GA population (fast 32, ga 20)")
    p.add_argument("--generations", type=positive_int, help="GA generations (fast 30, ga 2000)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the first run (default 0)")
    p.add_argument("--zone-offsets", action=argparse.BooleanOptionalAction, default=True,
                   help="fit a constant offset per zone and file, the thermocouples' bias "
                        "(default); --no-zone-offsets fits the paper's plain model")
    p.add_argument("--fix", action=_ParamValues, dest="fixed", metavar="NAME=V[,...]",
                   help="hold parameters at known values, e.g. d=0.87 (repeatable)")
    p.add_argument("--bounds", action=_ParamValues, dest="bounds", metavar="NAME=LO:HI[,...]",
                   help="search parameters only between LO and HI, e.g. d=0.1:2 (repeatable)")
    p.add_argument("--effects", type=effect_list, metavar="a,b",
                   help="fit the model extended with these effects, in their first law "
                        "(default: the paper's model alone)")
    add_furnace(p)
    add_effects_from(p)
    add_data_window(p)
    p.add_argument("--json", type=output_file, metavar="OUT", help="write the result as JSON")
    p.add_argument("--plot", type=output_dir, metavar="DIR",
                   help="write measured-vs-model PNGs here (created if missing)")
    p.set_defaults(run=run)


class _ParamValues(argparse.Action):
    """--fix NAME=V and --bounds NAME=LO:HI, repeatable and comma-separated, gathered into one
    dict per option and checked as they are read: a typo costs no fit. The parameters are
    those `fit` identifies, the paper's network's `parameters.BASELINE`; a
    network's (`k_`, `loss_`, `gain_`; --furnace) are checked against their kind's box here
    and against the furnace when it is read."""

    def __call__(self, parser, namespace, text, option_string=None):
        ranged = self.dest == "bounds"
        got = dict(getattr(namespace, self.dest) or {})
        other = getattr(namespace, "fixed" if ranged else "bounds") or {}
        for item in (i.strip() for i in text.split(",")):
            try:
                name, value = _param_value(item, ranged)
                if name in got:
                    raise ValueError(f"{name} is given twice")
                if name in other:
                    raise ValueError(f"{name} is also {'fixed' if ranged else 'bounded'}; a "
                                     "parameter is either fixed or bounded")
            except ValueError as exc:
                parser.error(f"argument {option_string}: '{item}': {exc}")
            got[name] = value
        setattr(namespace, self.dest, got)


def _param_value(item: str, ranged: bool) -> tuple[str, float | tuple[float, float]]:
    """NAME=V (or NAME=LO:HI when `ranged`), inside the parameter's own search box."""
    params = {p.name: p for p in BASELINE}
    name, eq, value = item.partition("=")
    name = name.strip()
    if not eq or not name:
        raise ValueError(f"expected {'NAME=LO:HI' if ranged else 'NAME=VALUE'}")
    if name not in params and name.startswith(("k_", "loss_", "gain_")):
        from ..simulation.network import EXCHANGE, GAIN, LOSS  # another furnace's: see _ParamValues

        params[name] = next(k for k in (EXCHANGE, LOSS, GAIN) if name.startswith(f"{k.name}_"))
    if name not in params:
        raise ValueError(f"unknown parameter {name}; the model has {', '.join(params)}")
    texts = value.split(":") if ranged else [value]
    if len(texts) != (2 if ranged else 1):
        raise ValueError("expected NAME=LO:HI" if ranged else "expected NAME=VALUE")
    nums = []
    for t in texts:
        try:
            nums.append(float(t))
        except ValueError:
            raise ValueError(f"not a number: '{t.strip()}'") from None
        if not math.isfinite(nums[-1]):
            raise ValueError(f"not a finite number: '{t.strip()}'")
    p = params[name]
    if ranged and nums[0] >= nums[1]:
        raise ValueError(f"the lower bound {nums[0]:g} must be below the upper {nums[1]:g}")
    for v in nums:
        if not p.lo <= v <= p.hi:
            raise ValueError(f"{v:g} is outside {name}'s search box, {p.lo:g} to {p.hi:g}")
    return name, (nums[0], nums[1]) if ranged else nums[0]


class ProgressBar:
    """A one-line bar on stderr, only when stderr is a terminal (logs stay clean)."""

    def __init__(self, label: str, stream=None):
        # sys.stderr when the bar is made, not when this module was first imported: a
        # caller (a test capturing output) may have replaced it since, and closed the old.
        stream = sys.stderr if stream is None else stream
        self.label, self.stream = label, stream
        self.enabled = bool(getattr(stream, "isatty", lambda: False)())
        self.t0 = time.perf_counter()
        self.shown = -1

    def __call__(self, frac: float) -> None:
        if not self.enabled:
            return
        pct = int(100 * frac)
        if pct == self.shown:
            return
        self.shown = pct
        n = pct * 30 // 100
        self.stream.write(f"\r{self.label} [{'#' * n}{'.' * (30 - n)}] {pct:3d}% "
                          f"{time.perf_counter() - self.t0:5.1f} s")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.shown >= 0:
            self.stream.write("\n")
            self.stream.flush()


def run(args: argparse.Namespace) -> int:
    from ..effects import EFFECTS
    from ..effects.plugins import guarded
    from ..identification.fit import fit
    from ..simulation.structure import ModelStructure

    if args.plot:
        require("report", "--plot")
    furnace = furnace_of(args)
    try:
        structure = ModelStructure([EFFECTS[n](**EFFECTS[n].tried.candidate_for(furnace),
                                               furnace=furnace)
                                    for n in args.effects or ()], furnace=furnace)
    except ValueError as exc:
        raise FurnaceError(str(exc)) from None
    experiments, read = read_data(args.data, args, furnace, "furnace-model fit")
    names = [e.name for e in experiments]
    if len(set(names)) != len(names):
        raise FurnaceError(f"two data files share the name {names}: plots and tables need "
                           "distinct file names")
    fixed, bounds = args.fixed or {}, args.bounds or {}
    bar = ProgressBar("fitting")
    try:
        result = guarded(structure.effects, lambda: fit(
            experiments, structure, method=args.method, runs=args.runs,
            population=args.population, generations=args.generations, seed=args.seed,
            progress=bar, zone_offsets=args.zone_offsets, fixed=fixed, bounds=bounds))
    finally:
        bar.close()
    print(render(result, experiments))
    for w in result.warnings:
        print(f"furnace-model fit: warning: {w}", file=sys.stderr)
    if args.json:
        doc = result.to_json([str(p) for p in args.data])
        doc["warnings"] = [*read, *doc["warnings"]]  # what reading left out first, as said
        _write_json(args.json, doc)
    if args.plot:
        from ..plots import plot_fit  # matplotlib only when plots are asked for

        for j, exp in enumerate(experiments):
            model = result.predict(j)
            try:
                plot_fit(exp, model, args.plot, label=result.method)
            except OSError as exc:
                raise FurnaceError(f"{args.plot}: cannot write plots: "
                                   f"{exc.strerror or exc}") from None
    return 0


def _write_json(path: Path, doc: dict) -> None:
    try:
        path.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")
    except (OSError, ValueError) as exc:
        raise FurnaceError(f"{path}: cannot write JSON: {exc}") from None


def _g(v: float) -> str:
    return f"{v:.6g}"


def render(result: FitResult, experiments) -> str:
    """The paper's tables in markdown: runs (Tables I-II), genetic mean (Table V), then
    the best fit with sd, intervals and covariance, the information criteria, why the search
    stopped, and per-zone errors."""
    names = result.structure.names
    zones = result.structure.furnace.zones
    errs_head = " | ".join(f"e_{w}" for w in range(1, len(zones) + 1))
    n = sum(len(e) for e in experiments)
    out = [f"{len(experiments)} experiment(s), {n} samples, {result.n_obs} zone readings; "
           f"method {result.method}, {len(result.runs)} run(s), {result.elapsed_s:.2f} s", ""]
    out.append("Runs (the paper's Tables I-II; e_w = mean absolute error per zone, °C)")
    out.append("| run | seed | population | generations | iterations | stopped | "
               + " | ".join(names) + f" | {errs_head} | SSE |")
    out.append("|---" * (7 + len(zones) + len(names)) + "|")
    for i, r in enumerate(result.runs, 1):
        errs = [f"{r['per_zone'][z]['mae_c']:.3f}" for z in zones]
        out.append(f"| {i} | {r['seed']} | {r['population']} | {r['generations']} | "
                   f"{r.get('iterations', '')} | {r.get('stop_reason', '')} | "
                   + " | ".join(_g(r["params"][k]) for k in names) + " | "
                   + " | ".join(errs) + f" | {r['sse']:.6g} |")
    if len(result.runs) > 1:
        out.append("| mean | | | | | | " + " | ".join(_g(result.genetic_mean[k]) for k in names)
                   + " |" + " |" * len(zones) + " |")
    tau = result.uncertainty.correlation_time if result.uncertainty is not None else 1.0
    out += ["", "Best fit: value, standard deviation and 95% interval (rates: the interval on "
            "the log scale, the sd in the parameter's units by the delta method, "
            "sd = value × sd of its log; intervals allow for the residual's autocorrelation"
            + (f", {tau:.1f} samples per independent one" if tau > 1.05 else ", white here")
            + "; 'profile': the interval follows the criterion, not its quadratic)",
            "| parameter | value | sd | 95% interval | determined |", "|---|---|---|---|---|"]
    for k in names:
        lo, hi = result.ci95[k]
        if k in result.at_bound:
            edge = result.bounds[k][0 if result.at_bound[k] == "lower" else 1]
            out.append(f"| {k} | at {result.at_bound[k]} bound {_g(edge)} | - | - "
                       "| no: on the edge of its range |")
        elif k in result.fixed:
            out.append(f"| {k} | {_g(result.params[k])} | 0 | - | fixed |")
        else:
            how = " profile" if k in result.profiled else ""
            out.append(f"| {k} | {_g(result.params[k])} | {result.std[k]:.3g} | "
                       f"[{_g(lo)}, {_g(hi)}]{how} | "
                       f"{'no' if k in result.undetermined else 'yes'} |")
    if result.cov is not None:
        out += ["", "Covariance (parameters' units; rates by the delta method)",
                "| | " + " | ".join(names) + " |", "|---" * (1 + len(names)) + "|"]
        out += [f"| {k} | " + " | ".join(f"{v:.3g}" if math.isfinite(v) else "-" for v in row) + " |"
                for k, row in zip(names, result.cov, strict=True)]
    out += ["", _criteria_line(result), _stop_line(result)]
    out += ["", "Per zone", "| zone | MAE (°C) | RMSE (°C) | fit % |", "|---|---|---|---|"]
    for z in zones:
        m = result.per_zone[z]
        out.append(f"| {z} | {m['mae_c']:.3f} | {m['rmse_c']:.3f} | {m['fit_pct']:.2f} |")
    out.append("")
    combos = [f"{k} = {_g(v['value'])} [{_g(v['ci95'][0])}, {_g(v['ci95'][1])}]"
              for k, v in result.combinations.items() if k not in names]
    if combos:
        out.append("Determined combinations: " + "; ".join(combos))
    out.append("Initial zone temperatures: " + "; ".join(
        f"{e.name} [{', '.join(f'{v:.1f}' for v in x)}]"
        for e, x in zip(experiments, result.x0, strict=True)))
    if result.zone_offsets_c:
        out.append("Zone offsets (measured minus model, 95% interval; a thermocouple's bias, "
                   "held within its bound): " + "; ".join(
                       f"{e.name} [" + ", ".join(_offset_text(result, j, z)
                                                 for z in zones) + "] °C"
                       for j, e in enumerate(experiments)))
    if result.flags:
        out.append("Flagged (on a physical bound, so the model's error, not a sensor's bias "
                   "or the record's start): " + "; ".join(
                       f"{f.record} {f.zone} {f.kind.replace('_', ' ')}" for f in result.flags))
    out.append(f"Status: {result.status}; residual sd {result.sigma_c:.3f} °C")
    return "\n".join(out)


def _offset_text(result: FitResult, j: int, zone: str) -> str:
    v = result.zone_offsets_c[j][zone]
    ci = (result.zone_offsets_ci95_c or [{}] * (j + 1))[j].get(zone)
    bound = result.bounds_c[j]["offset"][zone][1] if result.bounds_c else float("nan")
    interval = "on the bound" if ci is None else f"{ci[0]:+.2f} to {ci[1]:+.2f}"
    return f"{v:+.2f} ({interval}; bound ±{bound:.1f})"


def _criteria_line(result: FitResult) -> str:
    """AIC, AICc, BIC and FPE as System Identification Toolbox defines them, with what was
    counted: an engineer comparing numbers must know np and N."""
    ic = result.criteria
    if ic is None:
        return "Information criteria: not computed"
    k = len(result.structure.names) - len(result.fixed)
    nz = result.structure.n_zones
    states = nz * len(result.x0) if ic.n_params > k else 0
    parts = [f"{k} parameters"] + ([f"{states} initial states"] if states else []) + (
        [f"{ic.n_params - k - states} zone offsets"] if ic.n_params > k + states else [])

    def v(x: float, fmt: str) -> str:
        return format(x, fmt) if math.isfinite(x) else "n/a"

    return (f"Information criteria: AIC {v(ic.aic, '.1f')}, AICc {v(ic.aicc, '.1f')}, "
            f"BIC {v(ic.bic, '.1f')}, nAIC {v(ic.naic, '.4f')}, FPE {v(ic.fpe, '.4g')} "
            f"(°C)^{2 * nz}; np = {ic.n_params} estimated "
            f"({' + '.join(parts)}), N = {ic.n_samples:.6g} samples of {nz} zones "
            "(System Identification Toolbox's definitions, docs/identification.md)")


def _stop_line(result: FitResult) -> str:
    ga = f"{result.generations} GA generation(s)" if result.generations else "no GA"
    polish = (f"{result.iterations} polish iteration(s)" if result.method == "fast"
              else "no polish")
    return (f"Search: {ga}, then {polish}; stopped: {result.stop_reason} "
            f"({result.stop_description})")
