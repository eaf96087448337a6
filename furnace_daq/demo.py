"""`make demo`: the main job on the embedded default, in one command.

The simulated PLC runs the paper's first heat-up (Table V parameters, two noisy and slightly
biased thermocouples per zone) at high speed on 127.0.0.1; the acquisition daemon polls it
over Modbus TCP once per simulated minute and logs to MCAP; the log is exported to the
tabular contract and the model is identified from it alone. At the end the identified
parameters are printed next to the simulator's truth, with what the data do and do not
determine, and where the log, the data and the plots are.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import sys
import time
from dataclasses import replace
from pathlib import Path

from furnace_model.errors import FurnaceError
from furnace_model.experiment import experiment_from_frame, write_table
from furnace_model.fit import FitResult, fit
from furnace_model.plots import plot_fit
from furnace_model.scenario import Scenario, load_scenario

from .daemon import Daemon
from .daqconfig import load_config
from .logexport import export_frame
from .mcaplog import LogWriter
from .simplc import SimPLC

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_SCENARIO = ROOT / "config" / "scenarios" / "paper_exp1.yaml"
DEFAULT_CONFIG = ROOT / "config" / "gateway.yaml"


def _bar(frac: float, width: int = 30) -> str:
    done = int(round(frac * width))
    return "[" + "#" * done + "." * (width - done) + f"] {frac * 100:5.1f}%"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="furnace-demo", description=__doc__)
    ap.add_argument("--scenario", type=Path, default=DEFAULT_SCENARIO)
    ap.add_argument("--config", type=Path, default=DEFAULT_CONFIG)
    ap.add_argument("--out", type=Path, default=Path("out/demo"))
    ap.add_argument("--speed", type=float, default=6000.0,
                    help="simulated seconds per wall second (default 6000)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    try:
        return run(args)
    except FurnaceError as exc:
        print(f"demo: error: {exc}", file=sys.stderr)
        return exc.exit_code


def run(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario)
    log_dir = args.out / "logs"
    for old in log_dir.glob("*.mcap*"):
        old.unlink()
    print(f"1. Simulated PLC: {scenario.name}: {scenario.description}")
    steps = ", ".join(f"{int(n.sum())} from min {t:g}"
                      for t, n in zip(scenario.steps_t, scenario.steps_burners, strict=True))
    print(f"   burners on: {steps}; {scenario.duration_min:g} simulated minutes at "
          f"{args.speed:g}x ({scenario.duration_min * 60 / args.speed:.0f} s)")
    asyncio.run(_acquire(scenario, args, log_dir))

    logs = sorted(log_dir.glob("*.mcap"))
    frame = export_frame(logs, period_s=60.0)
    data = args.out / f"{scenario.name}.csv"
    write_table(frame, data)
    exp = experiment_from_frame(frame, str(data))
    print(f"   log: {', '.join(str(p) for p in logs)}")
    print(f"   exported {len(exp)} one-minute rows -> {data}")

    print("3. Identification of a..f from the logged readings (GA + least-squares polish)")
    tty = sys.stdout.isatty()
    t0 = time.perf_counter()

    def progress(frac: float) -> None:
        if tty:
            print("\r   " + _bar(frac), end="", flush=True)

    result = fit([exp], method="fast", seed=args.seed, progress=progress)
    if tty:
        print()
    print(f"   done in {time.perf_counter() - t0:.2f} s\n")
    _report(result, scenario)
    out_json = args.out / "fit.json"
    out_json.write_text(json.dumps(result.to_json([str(data)]), indent=2))
    print(f"\n   fit -> {out_json}")
    for path in plot_fit(exp, result.predict(exp, result.x0[0]), args.out):
        print(f"   plot -> {path}")
    return 0


async def _acquire(scenario: Scenario, args: argparse.Namespace, log_dir: Path) -> None:
    """The simulated PLC and the daemon, as on a gateway but in one process."""
    plc = SimPLC(scenario, speed=args.speed, port=0, seed=args.seed, scan_s=0.005)
    await plc.start()
    config = load_config(args.config)
    minute_s = 60.0 / args.speed  # poll once per simulated minute, the paper's sampling
    config = replace(
        config, poll_period_s=minute_s, stale_after_s=max(config.stale_after_s, 1.0),
        plc=replace(config.plc, host=plc.host, port=plc.port),
        clock=replace(config.clock, epoch=scenario.start_time) if config.clock else None,
        log=replace(config.log, dir=log_dir))
    log_dir.mkdir(parents=True, exist_ok=True)
    log = LogWriter(log_dir, prefix=config.log.prefix, flush_interval_s=1.0,
                    file_mode=config.log.file_mode)
    daemon = Daemon(config, log)
    print(f"2. Daemon polling {plc.host}:{plc.port} every {minute_s * 1e3:.1f} ms "
          f"(one simulated minute), logging MCAP to {log_dir}")
    duration = scenario.duration_min * 60.0 / args.speed + 3 * minute_s

    async def show() -> None:
        while True:
            await asyncio.sleep(2.0)
            temps = "  ".join(f"{z} {t:7.1f} C" for z, t in
                              zip(("soak", "heat", "preheat"), plc.source.stepper.zone_true(),
                                  strict=True))
            c = daemon.counters
            print(f"   t = {plc.plc_seconds / 60:6.0f} min  {temps}  burners "
                  f"{int(plc.source.stepper.burners.sum()):2d}  polls {c.ok_polls}", flush=True)

    shower = asyncio.create_task(show())
    try:
        counters = await daemon.run(duration)
    finally:
        shower.cancel()
        await plc.stop()
    print(f"   {counters.ok_polls} of {counters.polls} polls answered, "
          f"{counters.skipped_ticks} ticks skipped")


def _report(result: FitResult, scenario: Scenario) -> None:
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


if __name__ == "__main__":
    sys.exit(main())
