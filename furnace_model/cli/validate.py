"""`furnace-model validate`: score fitted parameters on other experiments (the paper's
Table VI): per-zone MAE, RMSE and fit %, each experiment's initial state estimated from its
own first readings onward, and its thermocouple offsets from those the fit carries, held
within a thermocouple's bias; with --horizon K also the K-step-ahead prediction beside the
simulation."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import FurnaceError
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

if TYPE_CHECKING:
    from ..identification.model import Model
    from ..simulation.structure import ModelStructure


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("validate", help="score fitted parameters on other data (Table VI)",
                       description=__doc__)
    p.add_argument("data", nargs="+", type=Path, help=f"{DATA_HELP} to score on")
    p.add_argument("--params", required=True, type=Path, metavar="FIT.json",
                   help="JSON written by `furnace-model fit --json`")
    p.add_argument("--zone-offsets", action=argparse.BooleanOptionalAction, default=None,
                   help="estimate each file's constant offset per zone (thermocouple bias), "
                        "from the fit's and within a thermocouple's bias (default: when the "
                        "fit estimated offsets); --no-zone-offsets scores with none")
    p.add_argument("--horizon", type=positive_int, metavar="K",
                   help="also score the K-step-ahead prediction (the model restarted from the "
                        "readings K samples earlier), as System Identification Toolbox's "
                        "compare(data, model, K)")
    p.add_argument("--json", type=output_file, metavar="OUT", help="write the scores as JSON")
    add_furnace(p)
    add_effects_from(p)
    add_data_window(p)
    p.add_argument("--plot", type=output_dir, metavar="DIR",
                   help="write measured-vs-model PNGs here (created if missing)")
    p.set_defaults(run=run)


def load_params(path: Path, furnace=None) -> tuple[dict[str, float], ModelStructure]:
    """Parameters and structure from a fit's JSON, checked: a wrong file is one clear line.
    `furnace`: the description the parameters are of (the paper's if None); a fit of
    another furnace, by its JSON's `furnace`, is refused."""
    from ..effects import EFFECTS
    from ..simulation.furnace import PAPER
    from ..simulation.structure import ModelStructure

    furnace = furnace or PAPER
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise FurnaceError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FurnaceError(f"{path}: not a readable JSON file: {exc}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("params"), dict):
        raise FurnaceError(f"{path}: no 'params' object (expected the JSON of furnace-model fit)")
    effects = []
    if not isinstance(doc.get("effects") or [], list):
        raise FurnaceError(f"{path}: effects: expected a list, got {type(doc['effects']).__name__}")
    for i, e in enumerate(doc.get("effects") or []):
        name = e.get("name") if isinstance(e, dict) else None
        if name not in EFFECTS:
            raise FurnaceError(f"{path}: effects[{i}]: unknown effect {name!r}")
        opts = {k: tuple(v) if isinstance(v, list) else v for k, v in (e.get("options") or {}).items()}
        try:
            effects.append(EFFECTS[name](**opts, furnace=furnace))
        except (TypeError, ValueError) as exc:
            raise FurnaceError(f"{path}: effects[{i}]: {exc}") from None
    fitted_on = doc.get("furnace", PAPER.name)
    if fitted_on != furnace.name:
        raise FurnaceError(f"{path}: furnace: the fit is of furnace '{fitted_on}', not of "
                           f"furnace '{furnace.name}' (--furnace)")
    try:
        structure = ModelStructure(effects, furnace=furnace)
    except ValueError as exc:
        raise FurnaceError(f"{path}: {exc}") from None
    params = {}
    for p in structure.params:
        v = doc["params"].get(p.name)
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise FurnaceError(f"{path}: params.{p.name}: expected a number, got {v!r}")
        # the fit never leaves these bounds: a value beyond them is a hand-edited or foreign file
        tol = 1e-9 * max(abs(p.lo), abs(p.hi))
        if not (math.isfinite(v) and p.lo - tol <= v <= p.hi + tol):
            raise FurnaceError(f"{path}: params.{p.name}: {v:g} is outside the range a fit "
                               f"searches, {p.lo:g} to {p.hi:g}")
        params[p.name] = float(v)
    return params, structure


def load_model(path: Path, furnace=None) -> Model:
    """The model a fit's JSON holds: its parameters, and the thermocouple offsets it carries
    (`offsets_c`; from a file that predates it, its records' `zone_offsets_c` averaged),
    with offsets estimated on new records when the fit estimated them."""
    from ..identification.model import Model

    params, structure = load_params(path, furnace)
    doc = json.loads(path.read_text())
    zones = structure.furnace.zones
    per_record = doc.get("zone_offsets_c")
    carried = doc.get("offsets_c")
    if carried is None and isinstance(per_record, list) and per_record:
        carried = {z: sum(float((o or {}).get(z, 0.0)) for o in per_record) / len(per_record)
                   for z in zones}
    offsets = None
    if carried is not None:
        if not isinstance(carried, dict):
            raise FurnaceError(f"{path}: offsets_c: expected an object of zone offsets, got "
                               f"{type(carried).__name__}")
        values = []
        for z in zones:
            v = carried.get(z)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise FurnaceError(f"{path}: offsets_c.{z}: expected a number, got {v!r}")
            values.append(float(v))
        offsets = values
    return Model(structure, params, per_record is not None, offsets)


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from ..identification.scores import zone_metrics

    furnace = furnace_of(args)
    model = load_model(args.params, furnace)
    if args.zone_offsets is not None:
        model = dataclasses.replace(model, zone_offsets=args.zone_offsets)
    params, structure = model.params, model.structure
    experiments, read = read_data(args.data, args, furnace, "furnace-model validate")
    k = args.horizon
    refined = model.refine(experiments)  # each record alone: its start, its offsets
    per_exp = {e.name: zone_metrics(e.zone_temp, refined.predict(j), furnace.zones)
               for j, e in enumerate(experiments)}
    pooled = refined.per_zone if len(experiments) > 1 else next(iter(per_exp.values()))
    ahead_exp, ahead = {}, None
    if k:
        from ..identification.prediction import score_ahead

        ahead_exp, ahead = score_ahead(params, experiments, k, structure, model.zone_offsets,
                                       model.offsets)
    rows = [*per_exp.items(), *([("all", pooled)] if len(experiments) > 1 else [])]
    lines = [f"Parameters from {args.params} ({structure.label}) on {len(experiments)} "
             "experiment(s)", ""]
    if k:
        lines += [f"Simulation, and the prediction {k} sample(s) ahead from the readings "
                  "(as compare(data, model, K))", "",
                  "| experiment | zone | MAE (°C) | RMSE (°C) | fit % | "
                  f"{k}-step RMSE (°C) | {k}-step fit % |", "|---|---|---|---|---|---|---|"]
    else:
        lines += ["| experiment | zone | MAE (°C) | RMSE (°C) | fit % |", "|---|---|---|---|---|"]
    for name, pz in rows:
        for z in furnace.zones:
            m = pz[z]
            row = f"| {name} | {z} | {m['mae_c']:.3f} | {m['rmse_c']:.3f} | {m['fit_pct']:.2f} |"
            if k:
                a = (ahead if name == "all" else ahead_exp[name])[z]
                row += f" {a['rmse_c']:.3f} | {a['fit_pct']:.2f} |"
            lines.append(row)
    lines += _offset_lines(model, refined, experiments)
    print("\n".join(lines))
    for f in refined.flags:
        print(f"furnace-model validate: warning: {f.words()}", file=sys.stderr)
    if args.json:
        corrections = refined.corrections()
        doc = {"params_file": str(args.params), "params": params, "data": [str(p) for p in args.data],
               "per_experiment": per_exp, "per_zone": pooled, "horizon": k,
               "prediction": {"per_experiment": ahead_exp, "per_zone": ahead} if k else None,
               "offsets_c": (None if model.offsets is None or not model.zone_offsets
                             else dict(zip(furnace.zones, map(float, model.offsets), strict=True))),
               "zone_offsets_c": ({e.name: refined.zone_offsets_c[j]
                                   for j, e in enumerate(experiments)}
                                  if refined.zone_offsets_c else None),
               "offset_corrections_c": ({e.name: corrections[j]
                                         for j, e in enumerate(experiments)}
                                        if corrections else None),
               "x0": {e.name: [float(v) for v in refined.x0[j]]
                      for j, e in enumerate(experiments)},
               "flags": [f.to_json() for f in refined.flags], "read": read}
        try:
            args.json.write_text(json.dumps(doc, indent=1) + "\n")
        except OSError as exc:
            raise FurnaceError(f"{args.json}: cannot write JSON: {exc}") from None
    if args.plot:
        from ..plots import plot_fit

        for j, exp in enumerate(experiments):
            try:
                plot_fit(exp, refined.predict(j), args.plot, label="validation")
            except OSError as exc:
                raise FurnaceError(f"{args.plot}: cannot write plots: "
                                   f"{exc.strerror or exc}") from None
    print(f"scored {len(experiments)} record(s)", file=sys.stderr)
    return 0


def _offset_lines(model: Model, refined, experiments) -> list[str]:
    """Each record's zone offsets and how far they moved from the carried ones."""
    if not refined.zone_offsets_c:
        return ["", "No zone offsets (--no-zone-offsets, or a fit without them)"]
    corrections = refined.corrections()
    out = [""]
    if model.offsets is not None:
        out.append("Zone offsets carried by the fit: ["
                   + ", ".join(f"{v:+.2f}" for v in model.offsets) + "] °C")
    for j, e in enumerate(experiments):
        line = (f"Zone offsets of {e.name}: ["
                + ", ".join(f"{v:+.2f}" for v in refined.zone_offsets_c[j].values()) + "] °C")
        if corrections:
            line += (" (corrected by [" + ", ".join(f"{v:+.2f}" for v in corrections[j].values())
                     + "] °C, each offset held within a thermocouple's bias)")
        out.append(line)
    return out
