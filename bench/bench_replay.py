"""Replay of a week of 1 Hz logs through the online refit (refits every 15 min over 24-h
windows): wall time, refits per second, and where the time goes (reading and binning the
log alone, and the fits alone). Aim: the whole replay under 30 s on 2 cores.

The logs are written directly from a plant run (config/scenarios/week_steps.yaml at 1 Hz)
with the daemon's LogWriter, hourly files as the daemon rotates them, no Modbus; they are
kept in a cache directory so a second run measures the replay only.

    .venv/bin/python bench/bench_replay.py [--days D] [--cache DIR] [--quick] [--method M]

`--method` replays with that `refit.method` (config/gateway.yaml's settings otherwise, the
built-in ones); without it the built-in method.
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from furnace_daq.daqconfig import REFIT_METHODS, RefitConfig, load_config
from furnace_daq.mcaplog import LogWriter
from furnace_daq.plantlog import write_run
from furnace_daq.replay import replay
from furnace_model.log.resample import resample_logs
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "config" / "scenarios" / "week_steps.yaml"
GATEWAY = ROOT / "config" / "gateway.yaml"


def make_logs(days: float, out: Path) -> tuple[list[Path], int, float]:
    """(files, messages, seconds to simulate and write); reuses a complete earlier set."""
    done = out / "done"
    if done.exists():
        n = int(done.read_text())
        return sorted(out.glob("*.mcap")), n, 0.0
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("*.mcap*"):
        old.unlink()
    t0 = time.perf_counter()
    s = load_scenario(SCENARIO)
    s.duration_min = days * 1440
    s.sample_min = 1.0 / 60.0
    run = Plant.from_scenario(s, seed=1).run_scenario(s)
    with LogWriter(out, rotate_s=3600.0, flush_interval_s=3600.0) as log:
        n = write_run(run, log)
    done.write_text(str(n))
    return sorted(out.glob("*.mcap")), n, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--days", type=float, default=7.0)
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "bench_replay")
    ap.add_argument("--quick", action="store_true", help="two days instead of seven")
    ap.add_argument("--method", choices=REFIT_METHODS, help="refit.method (default: built-in)")
    args = ap.parse_args()
    config = None if args.method is None else \
        replace(load_config(GATEWAY), refit=RefitConfig(method=args.method))
    days = 2.0 if args.quick else args.days
    files, n, t_make = make_logs(days, args.cache / f"{days:g}d")
    size = sum(f.stat().st_size for f in files)
    # The built-in refit settings are the benchmark's: every 15 min, 24-h windows, 1 min.
    assert RefitConfig() == RefitConfig(period_s=900.0, window_s=86400.0, step_s=60.0)

    t0, c0 = time.perf_counter(), time.process_time()
    frame = resample_logs(files, period_s=60.0)
    t_read, c_read = time.perf_counter() - t0, time.process_time() - c0

    t0, c0 = time.perf_counter(), time.process_time()
    w0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    msgs = [m.to_json() for m in replay(files, config, args.cache / "replay-out.mcap")]
    t_replay, c_replay = time.perf_counter() - t0, time.process_time() - c0
    w1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    c_worker = (w1.ru_utime + w1.ru_stime) - (w0.ru_utime + w0.ru_stime)
    ok = [m for m in msgs if m["status"] == "ok"]
    fit_s = sum(m["elapsed_s"] for m in ok)

    print(f"{days:g} simulated days at 1 Hz ({n} messages, {len(files)} hourly files, "
          f"{size / 2**20:.0f} MiB){'' if t_make == 0 else f'; written in {t_make:.0f} s'}; "
          f"refit.method {(config.refit if config else RefitConfig()).method}\n")
    print("| step | wall time | CPU time | rate |")
    print("|---|---|---|---|")
    print(f"| read + bin the logs (`logs export`, {len(frame)} rows) | {t_read:.1f} s | "
          f"{c_read:.1f} s | {c_read / n * 1e6:.1f} us CPU per message |")
    print(f"| fits alone (worker, sum of {len(ok)} fit times) | {fit_s:.1f} s | | "
          f"{fit_s / max(len(ok), 1) * 1e3:.0f} ms per fit |")
    print(f"| replay: {len(msgs)} windows ({len(ok)} fitted, "
          f"{len(msgs) - len(ok)} not yet full or failed) | {t_replay:.1f} s | "
          f"{c_replay:.1f} s reading + {c_worker:.1f} s worker | "
          f"{len(msgs) / t_replay:.1f} refits/s |")


if __name__ == "__main__":
    main()
