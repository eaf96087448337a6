"""`make demo`: the main job on the embedded default, in one command.

Simulates the paper's first heat-up on the plant simulator (Table V parameters, two noisy
and slightly biased thermocouples per zone), identifies the model from the readings alone,
and prints what was found next to the simulator's truth, with what the data do and do not
determine.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from furnace_model.errors import FurnaceError
from furnace_model.experiment import write_table
from furnace_model.fit import fit
from furnace_model.plant import Plant
from furnace_model.scenario import load_scenario

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_SCENARIO = ROOT / "config" / "scenarios" / "paper_exp1.yaml"


def _bar(frac: float, width: int = 30) -> str:
    done = int(round(frac * width))
    return "[" + "#" * done + "." * (width - done) + f"] {frac * 100:5.1f}%"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="furnace-demo", description=__doc__)
    ap.add_argument("--scenario", type=Path, default=DEFAULT_SCENARIO)
    ap.add_argument("--out", type=Path, default=Path("out/demo"))
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    try:
        return run(args)
    except FurnaceError as exc:
        print(f"demo: error: {exc}", file=sys.stderr)
        return exc.exit_code


def run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario)
    print(f"1. Plant simulator: {scenario.name} — {scenario.description}")
    steps = ", ".join(f"{int(n.sum())} from min {t:g}"
                      for t, n in zip(scenario.steps_t, scenario.steps_burners, strict=True))
    print(f"   burners on: {steps}; {scenario.duration_min:g} min sampled every "
          f"{scenario.sample_min:g} min")
    run_ = Plant.from_scenario(scenario, seed=args.seed).run_scenario(scenario)
    exp = run_.to_experiment(scenario.name)
    data = args.out / f"{scenario.name}.csv"
    write_table(exp.to_frame(), data)
    print(f"   {len(exp)} samples of 6 thermocouples -> {data}")

    print("2. Identification of a..f from the readings alone (GA + least-squares polish)")
    tty = sys.stdout.isatty()
    t0 = time.perf_counter()

    def progress(frac: float) -> None:
        if tty:
            print("\r   " + _bar(frac), end="", flush=True)

    result = fit([exp], method="fast", seed=args.seed, progress=progress)
    if tty:
        print()
    print(f"   done in {time.perf_counter() - t0:.2f} s\n")

    truth = scenario.values()
    print(f"   {'':3}{'truth':>10}{'fitted':>10}{'95% interval':>26}{'error':>9}")
    for name in result.structure.names:
        lo, hi = result.ci95[name]
        err = (result.params[name] / truth[name] - 1) * 100
        flag = "  (not determined)" if name in result.undetermined else ""
        print(f"   {name:3}{truth[name]:10.5f}{result.params[name]:10.5f}"
              f"{f'[{lo:.4g}, {hi:.4g}]':>26}{err:8.2f}%{flag}")
    print()
    for zone, m in result.per_zone.items():
        print(f"   {zone:8} RMSE {m['rmse_c']:5.2f} C   MAE {m['mae_c']:5.2f} C   "
              f"fit {m['fit_pct']:6.2f}%")
    if result.determined_combinations:
        print(f"   the data determine: {', '.join(result.determined_combinations)}")
    for w in result.warnings:
        print(f"   note: {w}")
    out_json = args.out / "fit.json"
    import json

    out_json.write_text(json.dumps(result.to_json([str(data)]), indent=2))
    print(f"\n   fit -> {out_json}")
    try:
        from furnace_model.plots import plot_fit
    except ImportError:
        return 0
    for path in plot_fit(result, [exp], args.out):
        print(f"   plot -> {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
