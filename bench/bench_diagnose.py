"""Diagnosis speed: `furnace-model diagnose` as a user runs it, wall time per case, and the
same cases run alternately from another source tree (`--against`) as a ratio. Prints a
markdown table for docs/performance.md.

    PYTHONPATH=. .venv/bin/python bench/bench_diagnose.py [--quick] [--repeat 3]
        [--against TREE] [--cases NAME...]

The headline case is the worked example of docs/diagnosis.md: the paper's two heat-ups
(3310 and 3800 minutes) on a furnace with zone burners, given together so that the
diagnosis picks the holdout. The others come from furnace_model.diagnosis.cases.draw_case
(the plant simulator with one effect, random strengths and schedules): a control (no gap:
only the baseline is fitted), a case the baseline absorbs badly (zone burners: every
candidate fitted, warm and cold), a lag, a nonlinear effect (radiation); and the shape of a
measured building record (furnace_model.diagnosis.hourlyroom: one zone, four weeks of
hourly rows, a wall and a sensor lag), and the same room over two weeks of minute rows with
its heating moved every minute (20 161 samples, every one an input change); two rooms that
are not our model's plant (`two_rooms`: a wall behind each, thermostats, heat from people
nobody logged, five weeks of hourly rows with an outage); and a day of
production in closed loop (draw_closed_loop_case with a drifting thermocouple, its fitted
record from minute 720 to 2160: the loops change the burners nearly every minute), with the
candidates `sensor_drift` and `zone_losses`; and the six hours around a fuel switch in
production (the window an online diagnosis is given, draw_closed_loop_case with a fuel
change, from 210 minutes before the switch to 150 after), with every candidate; and, when
named (`six-zone ROW`), draw 0 of each row of the six-zone selfcheck (issue 33's target: a
median of 45 s, every draw within 120 s). Every case is written to files first, so that both trees diagnose the same bytes through the command line.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from furnace_model.diagnosis.cases import draw_case, draw_closed_loop_case
from furnace_model.diagnosis.hourlyroom import ROOM, hourly_room
from furnace_model.diagnosis.selfcheck import selfcheck_case
from furnace_model.simulation.furnace import PAPER
from furnace_model.simulation.furnacefile import load_furnace
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

CASES = ("paper pair", "control", "zone_burners", "sensor_lag", "radiation", "hourly room",
         "minute room", "two rooms", "production day", "fuel window")
SIX_ZONE = tuple(f"six-zone {row}" for row in (
    "zone_burners", "zone_losses", "sensor_lag", "dead_time", "wall_storage", "radiation",
    "burner_nonlinearity", "fuel_change", "sensor_drift"))
"""Draw 0 of each of the six-zone selfcheck's rows with an effect (seed 0): the case
`furnace-model selfcheck --furnace six-zone` diagnoses, written to files with its furnace's
description. Not run unless named (about 40 s each on 2 cores)."""
ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "config" / "scenarios"


def paper_pair() -> list:
    out = []
    for seed, name in ((1, "paper_exp1_zone_burners"), (2, "paper_exp2_zone_burners")):
        sc = load_scenario(SCENARIOS / f"{name}.yaml")
        out.append(Plant.from_scenario(sc, seed=seed).run_scenario(sc).to_experiment(name))
    return out


TWO_ROOMS = """
name: building
zones:
  - {name: office, burners: 1, thermocouples: 1, heat: {kind: rate, unit: kW, max: 8}}
  - {name: lab, burners: 1, thermocouples: 1, heat: {kind: rate, unit: kW, max: 6}}
links: chain
ambient: [office, lab]
burner_heat: own_zone
"""


def two_rooms(seed: int, days: int = 35, row_min: int = 60) -> pd.DataFrame:
    """Two heated rooms simulated by a plant that is not the model's: each room's air (a
    time constant of about half an hour) exchanges heat with its own heavy wall, the other
    room and the outside, its heater held by a thermostat (PI, 21 degC by day on weekdays,
    17 at other times), and people heat it on weekdays, which the log does not carry. The
    log keeps one reading per room (0.08 degC of noise, to the tenth), each row's mean heat,
    the outside air and a humidity nobody modelled, every `row_min` minutes, with 1% of one
    room's readings missing and a five-hour outage."""
    rng = np.random.default_rng(seed)
    n = days * 1440
    t = np.arange(n)
    hour, weekday = (t // 60) % 24, (t // 1440) % 7 < 5
    weather = np.convolve(np.repeat(rng.normal(0, 3, days + 1), 1440)[:n], np.ones(720) / 720,
                          mode="same")
    outside = 4 + 6 * np.sin(2 * np.pi * (t / 1440 - 0.375)) + weather
    people = (weekday & (hour >= 8) & (hour < 18)).astype(float)
    setpoint = np.where(people > 0, 21.0, 17.0)
    air_wall, wall_out, air_out, rooms = 1 / 30, 1 / 400, 1 / 600, 1 / 200  # per minute
    wall_c = 12.0  # a wall's heat capacity, in its room's air's
    x = np.array([19.0, 17.0, 19.0, 17.0])  # office air, its wall, lab air, its wall
    heat, air, integral = np.zeros((n, 2)), np.zeros((n, 2)), np.zeros(2)
    for i in range(n):
        err = setpoint[i] - x[[0, 2]]
        integral = np.clip(integral + err / 120, 0, 1.5)
        heat[i] = np.clip(0.5 * err + integral, 0, 1) * np.array([8.0, 6.0])
        q = 0.012 * heat[i] + people[i] * np.array([0.01, 0.02])
        a, w, other = x[[0, 2]], x[[1, 3]], x[[2, 0]]  # each room's air, wall, neighbour
        x = x + np.ravel(np.stack([
            air_wall * (w - a) + air_out * (outside[i] - a) + rooms * (other - a) + q,
            (air_wall * (a - w) + wall_out * (outside[i] - w)) / wall_c], axis=1))
        air[i] = x[[0, 2]]
    rows = np.arange(0, n, row_min)
    mean_heat = heat.reshape(-1, row_min, 2).mean(axis=1)
    stamps = pd.Timestamp("2026-01-05T00:00:00+01:00") + pd.to_timedelta(rows, unit="min")
    frame = pd.DataFrame({
        "timestamp": [s.isoformat() for s in stamps],
        "tc_office_1": np.round(air[rows, 0] + rng.normal(0, 0.08, rows.size), 1),
        "heat_office": np.round(mean_heat[:, 0], 3),
        "tc_lab_1": np.round(air[rows, 1] + rng.normal(0, 0.08, rows.size), 1),
        "heat_lab": np.round(mean_heat[:, 1], 3),
        "t_air": np.round(outside[rows], 1),
        "humidity": np.round(50 + 10 * people[rows] + rng.normal(0, 2, rows.size), 1)})
    frame.loc[rng.choice(rows.size, rows.size // 100, replace=False), "tc_lab_1"] = np.nan
    cut = rows.size // 3
    return frame.drop(index=range(cut, cut + max(1, 300 // row_min)))


def write_case(name: str, d: Path) -> list[str]:
    """The case's records as CSV files in d; the diagnose arguments that use them."""
    def csv(exp, stem):
        path = d / f"{stem}.csv"
        exp.to_frame().to_csv(path, index=False)
        return str(path)

    if name == "paper pair":
        a, b = paper_pair()
        return [csv(a, "exp1"), csv(b, "exp2")]
    if name == "hourly room":
        (d / "room.yaml").write_text(ROOM)
        effects = ("wall_storage", "sensor_lag")
        return [csv(hourly_room(1, effects), "a"), "--holdout",
                csv(hourly_room(2, effects), "b"), "--furnace", str(d / "room.yaml")]
    if name == "minute room":
        (d / "room.yaml").write_text(ROOM)
        effects = ("wall_storage", "sensor_lag")
        return [csv(hourly_room(1, effects, 14, sample_min=1), "a"), "--holdout",
                csv(hourly_room(2, effects, 14, sample_min=1), "b"), "--furnace",
                str(d / "room.yaml")]
    if name == "two rooms":
        (d / "building.yaml").write_text(TWO_ROOMS)
        for seed, stem in ((1, "a"), (2, "b")):
            two_rooms(seed).to_csv(d / f"{stem}.csv", index=False)
        return [str(d / "a.csv"), "--holdout", str(d / "b.csv"), "--furnace",
                str(d / "building.yaml")]
    if name == "production day":
        case = draw_closed_loop_case("sensor_drift", np.random.default_rng(3))
        return [csv(case.fit[0].between(720.0, 2160.0), "day"), "--furnace",
                "paper-production", "--effects", "sensor_drift,zone_losses"]
    if name == "fuel window":
        case = draw_closed_loop_case("fuel_change", np.random.default_rng(3))
        t = case.truth["fuel_change"]["t_fuel"]
        return [csv(case.fit[0].between(t - 210.0, t + 150.0), "window"), "--furnace",
                "paper-production"]
    if name in SIX_ZONE:
        case = selfcheck_case(name.split()[1], 0, 0,
                              furnace=load_furnace(ROOT / "config" / "furnaces" / "six-zone.yaml"))
        (d / "furnace.yaml").write_text(yaml.safe_dump(case.fit[0].furnace.describe()))
        return [csv(case.fit[0], "fit"), "--holdout", csv(case.holdout[0], "holdout"),
                "--furnace", str(d / "furnace.yaml")]
    case = draw_case(None if name == "control" else name, np.random.default_rng(7000),
                     furnace=PAPER)
    return [csv(case.fit[0], "fit"), "--holdout", csv(case.holdout[0], "holdout")]


def run(args: list[str], tree: str, out: Path) -> tuple[float, dict]:
    """Run from the tree itself: `python -m` puts the working directory ahead of PYTHONPATH,
    so from any other checkout that checkout's code would run. With the modules' bytecode
    cached, as an installed command runs (an environment that sets PYTHONDONTWRITEBYTECODE
    would compile the library's sources at every start, 0.14 s of the paper pair's)."""
    cmd = [sys.executable, "-m", "furnace_model.cli", "diagnose", *args, "--quiet",
           "--json", str(out)]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPATH"] = tree
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, cwd=tree, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr}")
    return wall, json.loads(out.read_text())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="one run per case")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--against", type=Path, metavar="TREE",
                    help="another source tree, run alternately with this one")
    ap.add_argument("--cases", nargs="+", choices=CASES + SIX_ZONE, default=CASES)
    args = ap.parse_args()
    repeat = 1 if args.quick else args.repeat
    here = str(Path(__file__).resolve().parent.parent)
    trees = [here] + ([str(args.against.resolve())] if args.against else [])
    for tree in trees:  # bytecode cached first, as an installed command finds it (`run`)
        subprocess.run([sys.executable, "-m", "compileall", "-q", f"{tree}/furnace_model"],
                       check=True, env={k: v for k, v in os.environ.items()
                                        if k != "PYTHONDONTWRITEBYTECODE"})
    print(f"cores available: {os.cpu_count()}; load average at start "
          f"{os.getloadavg()[0]:.1f}\n")
    head = "| case | verdict | candidates | median wall time (s) | runs |"
    if args.against:
        head += f" {args.against}: verdict | median wall time (s) | ratio |"
    print(head)
    print("|---" * (head.count("|") - 1) + "|", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.cases:
            d = Path(tmp) / name.replace(" ", "_")
            d.mkdir()
            files = write_case(name, d)
            times: list[list[float]] = [[] for _ in trees]
            answers: list[dict] = [{} for _ in trees]
            for _ in range(repeat):
                for k, tree in enumerate(trees):  # alternately, so both see the same load
                    wall, answers[k] = run(files, tree, d / f"out{k}.json")
                    times[k].append(wall)
            cells = []
            for k in range(len(trees)):
                v = answers[k]["verdict"]
                cells += [f"{v['status']} {'+'.join(v['effects'])}".strip(),
                          f"{statistics.median(times[k]):.1f}"]
            row = f"| {name} | {cells[0]} | {len(answers[0]['candidates'])} | {cells[1]} | " \
                  f"{repeat} |"
            if args.against:
                ratio = statistics.median(times[1]) / statistics.median(times[0])
                row += f" {cells[2]} | {cells[3]} | {ratio:.2f} |"
            print(row, flush=True)


if __name__ == "__main__":
    main()
