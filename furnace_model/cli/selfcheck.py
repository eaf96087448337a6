"""`furnace-model selfcheck`: the diagnosis checked on data whose effect is known to the
check and withheld from the diagnosis. For each effect in turn (and a control with none) the
plant simulator draws random heat-ups with random strengths and schedules; each is
diagnosed, and the verdict compared with the truth.

Draws the baseline absorbs (its held-out error is already at the noise floor) are reported
apart with that reason, not counted as failures. Exit code 1 when a row misses the
acceptance: every control no_gap, each effect named in 9 of 10 draws it was not absorbed
in, combinations and faults outside the library every time. Stopped with Ctrl-C, it
prints and writes (--json, "complete": false) the cases diagnosed so far and exits with 130.

With --furnace the cases are heat-ups of that description (its zones, burners and
thermocouples, a network of generic rates: docs/diagnosis.md); an effect that cannot apply
to it is left out of the default rows and refused when named.

With --production each case is two records of production in closed loop instead of two
heat-ups: the shipped scenario paper_production on its furnace, the PLC's PI loops setting
each zone's burners from the thermocouples they read, the held-out record with the slabs
charged in another order. The same rows, judging and table; the faults outside the library
are drawn in heat-ups only."""

from __future__ import annotations

import argparse
import json
import sys
from functools import partial
from typing import TYPE_CHECKING

from ..errors import FurnaceError
from .arguments import add_effects_from, add_furnace, furnace_of, furnace_path, output_file
from .diagnose import effect_list
from .names import NOISE, OUT_OF_LIBRARY, effect_names, is_effect

if TYPE_CHECKING:
    from ..diagnosis.selfcheck import Outcome, Row

EXTRA = ("zone_burners+sensor_lag", *OUT_OF_LIBRARY)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("selfcheck", help="check the diagnosis on simulated data with known truth",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--draws", type=int, default=10, help="random cases per effect (default 10)")
    p.add_argument("--effects", nargs="+", metavar="NAME", type=_label,
                   help="what to switch on: 'none' (control), effect names, a+b for two at "
                        f"once, or {', '.join(OUT_OF_LIBRARY)} (default: none and every "
                        "effect: the nine and those of plug-ins)")
    p.add_argument("--all", action="store_true",
                   help=f"also {', '.join(EXTRA)} (with --production the pair only)")
    p.add_argument("--form", choices=("candidate", "other"), default="candidate",
                   help="draw effects in the candidates' formulation or in another one")
    p.add_argument("--candidates", metavar="a,b", type=partial(effect_list, what="candidate"),
                   help="limit the diagnosis to these candidates (default all)")
    p.add_argument("--noise", choices=NOISE, default="white",
                   help="the thermocouples: white noise (default), low-pass noise, or held-out "
                        "ones 1-3 times as noisy as the fitted ones")
    p.add_argument("--production", action="store_true",
                   help="draw production records in closed loop (the shipped scenario "
                        "paper_production, its PLC's loops firing the burners) instead of "
                        "heat-ups")
    p.add_argument("--seed", type=int, default=0, help="seed of the draws (default 0)")
    p.add_argument("--first-draw", type=int, default=0, metavar="K",
                   help="number the draws from K (default 0): --draws 3 --first-draw 2 are "
                        "draws 2-4 of a longer check, the same cases")
    p.add_argument("--json", type=output_file, metavar="OUT",
                   help="write every case and the table")
    p.add_argument("--quiet", action="store_true",
                   help="no line per case and no progress on stderr, only the table")
    add_effects_from(p)
    add_furnace(p)
    p.set_defaults(run=run)


def labels_of(args: argparse.Namespace) -> list[str]:
    """The rows the arguments ask for, checked: what this command and the fleet's selfcheck
    both draw."""
    if args.first_draw < 0:
        raise FurnaceError("--first-draw must be 0 or more")
    if args.draws < 1:
        raise FurnaceError("--draws must be at least 1")
    production = mode_of(args) == "production"
    if production and getattr(args, "furnace", None):
        raise FurnaceError("--production runs the shipped scenario paper_production on its own "
                           "furnace: leave out --furnace")
    faults = sorted({n for label in args.effects or () for n in label.split("+")}
                    & set(OUT_OF_LIBRARY))
    if production and faults:
        raise FurnaceError(f"{', '.join(faults)}: drawn in heat-ups only, not with "
                           "--production (closed-loop cases draw the library's effects)")
    drawable = _drawable()
    furnace = cases_furnace(args)
    refused = _refused(furnace)
    if args.effects:
        for name in {n for label in args.effects for n in label.split("+")} - drawable:
            raise FurnaceError(f"effect {name} has no `draw`: the selfcheck cannot make a "
                               "furnace with it at random (give its class a `drawn` part, a "
                               "furnace_model.effects.Drawn with a draw)")
        for name in sorted({n for label in args.effects for n in label.split("+")}):
            if name in refused:
                raise FurnaceError(f"{name} does not apply to furnace '{furnace.name}': "
                                   f"{refused[name]}")
    extra = [x for x in EXTRA if not set(x.split("+")) & set(refused)
             and not (production and x in OUT_OF_LIBRARY)]
    return list(args.effects or ("none", *(n for n in effect_names()
                                           if n in drawable and n not in refused))) + \
        (extra if args.all else [])


def mode_of(args: argparse.Namespace) -> str:
    """Heat-ups or production records (`diagnosis.selfcheck.MODES`)."""
    return "production" if getattr(args, "production", False) else "heat-up"


def cases_furnace(args: argparse.Namespace):
    """The furnace the cases run on: the production scenario's with --production, else the
    one --furnace names (the paper's by default)."""
    if mode_of(args) == "production":
        from ..diagnosis.cases import production_scenario

        return production_scenario().furnace
    return furnace_of(args)


def _refused(furnace) -> dict[str, str]:
    """Effects the selfcheck cannot check on this furnace, with the reason: those that do
    not apply to it and have no other reading of it to be checked on."""
    from ..effects import EFFECTS

    out = {}
    for n, cls in EFFECTS.items():
        why = cls.refusal(furnace)
        if why and cls.drawn.check_furnace(furnace) == furnace:
            out[n] = why
    return out


def run(args: argparse.Namespace) -> int:
    from ..diagnosis.selfcheck import check
    from ..progress import Progress

    labels = labels_of(args)
    outcomes: list[Outcome] = []
    # a line per case as it is judged, and the cases done with the time left at this pace
    bar = Progress("selfcheck", len(labels) * args.draws, quiet=args.quiet, unit="cases")

    def progress(o):
        outcomes.append(o)
        mark = "absorbed" if o.absorbed else ("ok" if o.correct else "WRONG")
        bar.note(f"{o.label} draw {o.draw}: {o.status} {'+'.join(o.named)} [{mark}] "
                 f"{o.elapsed_s:.0f} s{': ' + o.reason if o.reason else ''}")
        bar.finished(ok=o.correct or o.absorbed)

    try:
        check(labels, args.draws, args.seed, form=args.form, candidates=args.candidates,
              noise=args.noise, report=progress, first=args.first_draw, mode=mode_of(args),
              furnace=cases_furnace(args))
    except KeyboardInterrupt:
        bar.close()
        # A full check takes hours: stopping it must not throw away the cases diagnosed.
        if not outcomes:
            raise
        report(args, outcomes, complete=False)
        print(f"selfcheck: interrupted after {len(outcomes)} case(s); the table and --json "
              "hold those only", file=sys.stderr)
        return 130
    bar.close()
    rows = report(args, outcomes, complete=True)
    failed = [r.label for r in rows if not r.passed]
    if failed:
        print(f"selfcheck: acceptance missed for {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


def report(args: argparse.Namespace, outcomes: list[Outcome], *, complete: bool) -> list[Row]:
    """Print the table and write --json; the rows, for the acceptance."""
    from ..diagnosis.selfcheck import summarize, table

    rows = summarize(outcomes)
    print(table(rows, outcomes))
    if args.json:
        doc = {"seed": args.seed, "draws": args.draws, "first_draw": args.first_draw,
               "mode": mode_of(args), "form": args.form, "noise": args.noise,
               "candidates": list(args.candidates or effect_names()), "complete": complete,
               **({"furnace": furnace_path(args.furnace).as_posix()}
                  if getattr(args, "furnace", None) else {}),
               "rows": [r.__dict__ for r in rows], "cases": [o.to_json() for o in outcomes]}
        try:
            args.json.write_text(json.dumps(doc, indent=1, default=_plain) + "\n")
        except OSError as exc:
            raise FurnaceError(f"{args.json}: cannot write: {exc}") from None
    return rows


def _drawable() -> set[str]:
    """Effects the selfcheck can draw, with the built-in perturbations and 'none'; a plug-in
    without a `draw` is left out of the default rows and refused by name."""
    from ..effects import EFFECTS

    return {"none", *OUT_OF_LIBRARY, *(n for n, cls in EFFECTS.items() if cls.drawn.drawable)}


def _label(text: str) -> str:
    """What `cases.parse_label` accepts, checked without loading the library."""
    parts = text.split("+")
    bad = [p for p in parts if p not in OUT_OF_LIBRARY and not is_effect(p)]
    if text != "none" and (bad or not all(parts)):
        raise argparse.ArgumentTypeError(
            f"unknown effect(s) {', '.join(bad) or repr(text)}; expected 'none', names from "
            f"{', '.join([*effect_names(), *OUT_OF_LIBRARY])}, or a+b")
    return text


def _plain(x):
    try:
        return float(x)
    except (TypeError, ValueError):
        return str(x)
