"""`furnace-model diagnose`: where the paper's model errs on these data, which unmodelled
effect explains the error, and how far the held-out error shrinks once it is added.

Without --holdout the last experiment is held out (one experiment: its last 30%). With
--furnace the data are of that furnace description and the candidates extend its network."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import FurnaceError
from ..extras import require
from .arguments import (
    DATA_HELP,
    add_data_window,
    add_effects_from,
    add_furnace,
    furnace_of,
    output_file,
    read_data,
)
from .names import EFFECTS, effect_names, is_effect

if TYPE_CHECKING:
    from ..diagnosis import Diagnosis


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("diagnose", help="explain the model's error: where, which effect, how far",
                       description=__doc__)
    p.add_argument("data", nargs="+", type=Path, help=f"{DATA_HELP} to fit")
    p.add_argument("--holdout", action="append", type=Path, metavar="DATA",
                   help="a file or log to score on, never fitted; repeat for more (default: the last "
                        "file given, or the last 30%% of a lone file)")
    p.add_argument("--json", type=output_file, metavar="OUT", help="write the diagnosis as JSON")
    p.add_argument("--report", type=output_file, metavar="OUT.html",
                   help="write a self-contained HTML report")
    p.add_argument("--effects", type=effect_list, metavar="a,b",
                   help=f"candidates to try (default all: {','.join(EFFECTS)} and those of "
                        "plug-ins)")
    add_effects_from(p)
    add_furnace(p)
    add_data_window(p)
    p.add_argument("--seed", type=int, default=0, help="random seed of the searches (default 0)")
    p.add_argument("--time-limit", type=positive_seconds, metavar="S",
                   help="answer within about S seconds: the verdict judged on what was fitted "
                        "by then, the candidates left unfitted named (the baseline always "
                        "completes)")
    p.add_argument("--quiet", action="store_true",
                   help="no progress lines on stderr (each stage of the search as it starts)")
    p.set_defaults(run=run)


def positive_seconds(text: str) -> float:
    """A time limit in seconds, for argparse."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number of seconds above 0, not {text!r}")
    return value


def effect_list(text: str, what: str = "effect") -> tuple[str, ...]:
    """A comma-separated list of effect names (CONTRACTS.md section 4), for argparse."""
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    bad = [n for n in names if not is_effect(n)]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"unknown {what}(s) {', '.join(bad) or '(none given)'}; expected names from "
            f"{', '.join(effect_names())}")
    return names


STAGES = {"baseline": "fitting the baseline", "candidates": "fitting the candidate effects",
          "from scratch": "searching the candidates that stay off the noise floor "
                          "from scratch",
          "laws": "fitting the further laws of the effects that help",
          "strengths": "profiling the strengths whose linearised intervals alone keep "
                       "candidates from credit",
          "combinations": "trying combinations of the effects that earn credit",
          "signals": "trying the logged signals the model does not use as inputs",
          "done": "judging"}


def stage_lines(stream=None):
    """A line on stderr as each stage of the search starts, with the time so far: a
    diagnosis of a long record takes minutes, and silence looks like a hang."""
    stream = stream or sys.stderr
    t0 = time.monotonic()
    seen: set[str] = set()

    def say(stage: str, _fraction: float) -> None:
        if stage in seen:
            return
        seen.add(stage)
        print(f"furnace-model diagnose: {STAGES.get(stage, stage)} "
              f"({time.monotonic() - t0:.0f} s so far)", file=stream, flush=True)

    return say


def run(args: argparse.Namespace) -> int:
    from ..diagnosis import diagnose
    if args.report:
        require("report", "--report")
    furnace = furnace_of(args)
    data, read = read_data(args.data, args, furnace, "furnace-model diagnose")
    hold = None
    if args.holdout:
        hold, read_hold = read_data(args.holdout, args, furnace, "furnace-model diagnose")
        read += read_hold
    result = diagnose(data, hold, effects=args.effects, seed=args.seed,
                      progress=None if args.quiet else stage_lines(),
                      time_limit_s=args.time_limit)
    print(summary(result))
    if args.json:
        _write(args.json, json.dumps({**result.to_json(), "read": read}, indent=1,
                                     allow_nan=False) + "\n")
    if args.report:
        from ..report import write_report

        try:
            write_report(result, args.report)
        except OSError as exc:
            raise FurnaceError(f"{args.report}: cannot write the report: {exc}") from None
    print(f"diagnosed in {result.elapsed_s:.1f} s", file=sys.stderr)
    return 0


def _write(path: Path, text: str) -> None:
    try:
        path.write_text(text)
    except OSError as exc:
        raise FurnaceError(f"{path}: cannot write: {exc}") from None


def summary(d: Diagnosis) -> str:
    """The verdict first, then the evidence behind it, in the report's order and words."""
    from ..diagnosis import RULE, shortfall
    from ..diagnosis.words import paper_like, temp_c

    b, v = d.baseline, d.verdict
    furnace = d.fit_data[0].furnace
    zone_names = furnace.zones
    per_zone = "/".join(zone_names)

    def c2(x: float) -> str:
        return temp_c(x, 2)

    if paper_like(furnace):
        model = "the paper's model, eq. 11"
    elif furnace.paper_structure:
        model = f"eq. 11 on furnace '{furnace.name}'"
    else:
        model = f"the thermal network of furnace '{furnace.name}'"
    lines = [f"Verdict: {v.status}" + (f" ({', '.join(v.effects)})" if v.effects else ""),
             v.sentence, ""]
    if d.untried:
        lines += [f"Judged without what the time limit of {d.time_limit_s:g} s left unfitted: "
                  + "; ".join(d.untried) + ". Run again with a longer --time-limit (or none) "
                  "to try them.", ""]
    lines += [f"Fitted: {', '.join(e.name for e in d.fit_data)}; held out: {d.holdout_how}",
              "", f"Baseline ({model}):",
              "| zone | RMSE fit (°C) | RMSE held out (°C) | noise floor (°C) | gap limit (°C) "
              "| gap |",
              "|---|---|---|---|---|---|"]
    limit = d.gap_limit_c or {}
    for z in zone_names:
        lines.append(f"| {z} | {c2(b.rmse_fit_c[z])} | {c2(b.rmse_holdout_c[z])} | "
                     f"{c2(d.noise_floor_c[z])} | {c2(limit.get(z, float('nan')))} | "
                     f"{'yes' if z in d.gap_zones else 'no'} |")
    carried = b.carried_c or {}
    if max(carried.values(), default=0.0) >= 0.05:
        lines += ["", "The limit includes what the fitted parameters' own uncertainty carries "
                  "onto the held-out data (°C per zone, " + per_zone + "): "
                  + "/".join(c2(carried.get(z, 0.0)) for z in zone_names)]
    offsets = d.offset_lines()
    if offsets:
        lines += ["", *offsets]
    if d.record_floors:
        lines += ["", f"Noise floor per record (°C per zone, {per_zone}; the held-out "
                  "RMSE is judged against the held-out records'):"]
        for i, f in enumerate(d.record_floors):
            role = "fitted" if i < len(d.fit_data) else "held out"
            floors = "/".join(c2(f.zones[z].floor_c) for z in zone_names)
            hows = {f.zones[z].words() for z in zone_names}
            lines.append(f"- {f.record} ({role}): {floors}; "
                         + ("; ".join(f"{z}: {f.zones[z].words()}" for z in zone_names)
                            if len(hows) > 1 else hows.pop()))
    if d.where:
        lines += ["", "Where the error lies:", *_where_text(d.where, zone_names)]
    rest = v.remaining
    if v.status == "explained_in_part" and rest is not None:
        lines += ["", "The kept effects, in the order they were added (each one's share of "
                  "the baseline's held-out gap above the noise floor):",
                  f"| effect | gap closed % | shrink % | held out after, {per_zone} (°C) |",
                  "|---|---|---|---|"]
        for p in v.parts:
            lines.append(f"| {p.effect} | {p.gap_closed_pct:.0f} | {p.shrink_pct:.0f} | "
                         + "/".join(c2(p.rmse_holdout_c[z]) for z in zone_names) + " |")
        lines += ["", f"What remains, held out (°C per zone, {per_zone}): "
                  + "/".join(c2(rest.rmse_holdout_c[z]) for z in zone_names)
                  + " against a noise floor of "
                  + "/".join(c2(rest.noise_floor_c[z]) for z in zone_names)]
        if rest.where:
            lines += [("Where it lies, on the kept model's held-out residual:"
                       if rest.where_from == "kept" else
                       "Where it lies: not found on the kept model's residual; the baseline's "
                       "error, as above:"), *_where_text(rest.where, zone_names)]
    if d.candidates:
        lines += ["", f"Candidates, best first (held-out RMSE per zone {per_zone}; "
                  f"credit: {RULE}):",
                  "| effect(s) | held out (°C) | shrink % | gap closed % | dBIC | "
                  "strength determined | credit |",
                  "|---|---|---|---|---|---|---|"]
        for c in d.candidates:
            ho = "/".join(c2(c.rmse_holdout_c[z]) for z in zone_names)
            determined = "yes" if c.identifiable else "no"
            short = shortfall(c)
            credit = "no: " + "; ".join(short) if short else "yes"
            lines.append(f"| {c.label} | {ho} | {c.shrink_pct:.0f} | {c.gap_closed_pct:.0f} | "
                         f"{c.delta_bic:.0f} | {determined} | {credit} |")
        notes = [f"- {c.label}: {c.note}" for c in d.candidates if c.note]
        if notes:
            lines += ["", "Notes:", *notes]
    return "\n".join(lines)


def _where_text(where, zones: tuple[str, ...]) -> list[str]:
    """One line per entry of 'where the error lies', as the report's table has them."""
    from ..diagnosis import where_lines

    out = []
    for w in where_lines(where, zones):
        when = (f"throughout {w.experiment} ({w.span})" if w.kind == "throughout"
                else f"{w.experiment} {w.span}")
        out.append(f"- {w.who}, {when}" + (f" ({w.clock})" if w.clock else "")
                   + f": {w.share} of {'each' if ' and ' in w.share else 'the'} "
                   f"zone's squared error; {w.regime}")
    return out
