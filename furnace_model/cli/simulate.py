"""`furnace-model simulate`: run a scenario through the plant simulator into the tabular
contract (CSV or Parquet), ready for `fit` and `diagnose`."""

from __future__ import annotations

import argparse
import sys

from ..errors import ConfigError
from .arguments import add_effects_from, add_furnace, furnace_of, output_file, scenario_path

MAX_ROWS = 10_000_000
"""About 1 GB of CSV: beyond it a scenario's sampling is a typo, not a data set."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="simulate a scenario into a CSV or Parquet file",
                       description=__doc__)
    p.add_argument("--scenario", required=True, metavar="SCENARIO.yaml",
                   help="scenario YAML, or the name of a shipped one (paper_exp1, "
                        "six_zone_heatup; config/scenarios/)")
    p.add_argument("--out", required=True, type=output_file, help="output .csv or .parquet")
    p.add_argument("--seed", type=int, default=0, help="noise and sensor-bias seed (default 0)")
    add_furnace(p)
    add_effects_from(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..effects.plugins import guarded
    from ..experiment import table_kind, write_table
    from ..simulation.plant import Plant
    from ..simulation.scenario import load_scenario

    table_kind(args.out)
    args.scenario = scenario_path(args.scenario)
    scenario = load_scenario(args.scenario,
                             None if args.furnace is None else furnace_of(args))
    if scenario.duration_min / scenario.sample_min > MAX_ROWS:
        raise ConfigError(str(args.scenario), "sample_min",
                          f"{scenario.duration_min:g} min sampled every {scenario.sample_min:g} "
                          f"min is more than {MAX_ROWS:,} rows: sample less often")
    result = guarded(scenario.effects, lambda: Plant.from_scenario(
        scenario, seed=args.seed).run_scenario(scenario))
    write_table(result.to_frame(), args.out)
    print(f"{scenario.name}: {result.t_min.size} samples over {scenario.duration_min:g} min "
          f"-> {args.out}", file=sys.stderr)
    return 0
