"""CPU seconds of one closed-loop case per effect: the two records
`draw_closed_loop_case` runs on the shipped paper_production scenario (3000 min, the loops
once a minute), the plant stepped one control period at a time. An effect that moves
burner steps per parameter set (a transport delay, a fuel switch at an instant) makes each
step simulate from the inputs it can still need, so the cost should follow the control
periods, as it does for the other effects.

    .venv/bin/python bench/bench_closed_loop.py [--quick] [--effects dead_time fuel_change]
"""

from __future__ import annotations

import argparse
import time

from furnace_model.cli.names import effect_names
from furnace_model.diagnosis.cases import case_label, case_rng, draw_closed_loop_case


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--effects", nargs="*", default=None,
                    help="rows to time ('none' for the control); default every default row")
    ap.add_argument("--quick", action="store_true",
                    help="the control and the two effects that reach back only")
    args = ap.parse_args()
    labels = args.effects or (["none", "dead_time", "fuel_change"] if args.quick
                              else ["none", *effect_names()])
    print("| effect | CPU (s) for the closed-loop pair |")
    print("|---|---|")
    for label in labels:
        effect = None if label == "none" else label
        c0 = time.process_time()
        draw_closed_loop_case(effect, case_rng(0, case_label(effect), 0))
        print(f"| {label} | {time.process_time() - c0:.1f} |", flush=True)


if __name__ == "__main__":
    main()
