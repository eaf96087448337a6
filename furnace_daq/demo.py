"""`make demo`: the whole product in one command, on the embedded default.

The simulated PLC runs the paper's first heat-up (Table V parameters, two noisy and slightly
biased thermocouples per zone) at high speed on 127.0.0.1; the acquisition daemon polls it
over Modbus TCP once per simulated minute, logs MCAP and refits the model online on a sliding
window of the PLC clock, in its worker process, as on a gateway. The terminal follows the
simulated time, the logged temperatures and burners, and each refit. At the end the last
online model is printed next to the simulator's truth and next to one fit of the whole run
from the exported log, with what 1-minute data do and do not determine.

Another furnace: `--furnace F` (`make demo FURNACE=F`; F a description file or the name of
a shipped one, config/furnaces/) runs the same chain on the furnace description F: a
shipped scenario of that furnace (config/scenarios/, or `--scenario`), the default register map derived
from F served by the simulated PLC and read by the daemon (a config written by
`furnace-daq config`, with two extra signals, unless `--config` is given), and the
furnace's thermal network identified online and from the export: for a furnace fired at
modulated rates and with measured disturbances (`modulated`), their gains too.

Another protocol: `--protocol opcua` or `--protocol s7` (`make demo PROTOCOL=s7`) runs the
same chain with the simulated PLC serving OPC UA or S7 and the daemon reading it so, with
the shipped config of that protocol (config/gateway-opcua.yaml, config/gateway-s7.yaml).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import math
import re
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from furnace_model.errors import FurnaceError
from furnace_model.experiment import experiment_from_frame, write_table
from furnace_model.identification.fit import fit
from furnace_model.identification.model import Model
from furnace_model.identification.result import FitResult
from furnace_model.log.messages import (
    Burners,
    Heat,
    ModelDiagnosis,
    ModelEvent,
    ModelEventKind,
    ModelParameters,
    Thermocouples,
    number,
)
from furnace_model.log.resample import resample_logs
from furnace_model.log.schema import (
    BURNERS,
    HEAT,
    MODEL_DIAGNOSIS,
    MODEL_EVENTS,
    THERMOCOUPLES,
    param_names,
)
from furnace_model.shipped import SCENARIOS, shipped
from furnace_model.simulation.furnace import PAPER, Furnace
from furnace_model.simulation.furnacefile import load_furnace
from furnace_model.simulation.scenario import Scenario, load_scenario
from furnace_model.simulation.structure import ModelStructure

from .daemon import EVENT_PRIORITY, Daemon
from .daqconfig import DiagnosisConfig, RefitConfig, load_config
from .diagnosisrunner import KILL_FACTOR, KILL_MARGIN_S
from .logmeta import build_metadata, signal_fields
from .mcaplog import LogWriter
from .protocols import NAMES as PROTOCOL_NAMES
from .protocols import PROTOCOLS

DEFAULT_SCENARIO = "config/scenarios/paper_exp1.yaml"
DEFAULT_CONFIGS = {"modbus": "config/gateway.yaml", "opcua": "config/gateway-opcua.yaml",
                   "s7": "config/gateway-s7.yaml"}
"""The paper's furnace's scenario and config of each protocol, shipped files
(`furnace_model.shipped`)."""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="furnace-demo", description=__doc__)
    ap.add_argument("--furnace",
                    help="furnace description, a file or a shipped name (six-zone, modulated) "
                         "(default the paper's furnace); the scenario and the register map "
                         "are then that furnace's")
    ap.add_argument("--scenario", help="scenario, a file or a shipped name")
    ap.add_argument("--config", type=Path)
    ap.add_argument("--protocol", choices=PROTOCOL_NAMES,
                    help="how the daemon reads the simulated PLC (default: the config's, "
                         "modbus without one): the paper's furnace's shipped config of that "
                         "protocol unless --config is given")
    ap.add_argument("--out", type=Path, default=Path("out/demo"))
    ap.add_argument("--speed", type=float, default=5000.0,
                    help="simulated seconds per wall second (default 5000)")
    ap.add_argument("--refit-period-h", type=float, default=6.0,
                    help="a refit every this many simulated hours (default 6)")
    ap.add_argument("--refit-window-h", type=float, default=36.0,
                    help="each refit fits the last this many simulated hours (default 36)")
    ap.add_argument("--polls-per-minute", type=float, default=2.0,
                    help="daemon polls per simulated minute (default 2: every one-minute "
                         "sample of the refit holds a reading)")
    ap.add_argument("--every", type=float, default=2.0,
                    help="a progress line every this many wall seconds (default 2)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    try:
        return run(args)
    except FurnaceError as exc:
        print(f"demo: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("demo: interrupted", file=sys.stderr)
        return 130


DEMO_SIGNALS = (("o2_pct", "%", "int16, scale: 0.01, range: [0, 21]"), ("door_open", "", None))
"""Extra signals the demo's written config reads (name, unit, encoding; None: a bit), after
the default map's points: the simulated PLC makes them up (`simplc.simulated_signal`)."""


def _signals_yaml(furnace: Furnace) -> str:
    """The `signals:` section of DEMO_SIGNALS, placed after the furnace's default map."""
    from .servedmap import ServedMap

    size = ServedMap.default(furnace).sizes()
    register, bit = size["input"], size["discrete"]
    lines = ["", "# Extra named points, logged on /furnace/signals and exported as columns.",
             "signals:"]
    for name, unit, encoding in DEMO_SIGNALS:
        if encoding is None:
            lines.append(f'  {name}: {{table: discrete, address: {bit}, unit: "{unit}"}}')
            bit += 1
        else:
            lines.append(f'  {name}: {{table: input, address: {register}, type: {encoding}, '
                         f'unit: "{unit}"}}')
            register += 1
    return "\n".join(lines) + "\n"


def _of_furnace(args: argparse.Namespace) -> Furnace:
    """Fill in --scenario and --config for the furnace asked for: the paper's defaults, or a
    shipped scenario of that furnace and its derived map's config."""
    from furnace_model.cli.arguments import furnace_path, scenario_path

    if args.furnace is not None:
        args.furnace = furnace_path(args.furnace)
    if args.scenario is not None:
        args.scenario = scenario_path(args.scenario)
    if args.furnace is not None:
        furnace = load_furnace(args.furnace)
    elif args.scenario is not None:  # the scenario's own furnace
        furnace = load_scenario(args.scenario).furnace
        if furnace != PAPER:
            args.furnace = _scenario_furnace_file(Path(args.scenario))
    else:
        furnace = PAPER
    if args.scenario is None:
        if furnace == PAPER:
            args.scenario = shipped(DEFAULT_SCENARIO)
        else:
            mine = [p for p in sorted(shipped(SCENARIOS).glob("*.yaml"))
                    if "furnace" in p.read_text(encoding="utf-8")
                    and _scenario_furnace(p) == furnace]
            if not mine:
                raise FurnaceError(f"no shipped scenario of furnace '{furnace.name}': "
                                   "give --scenario")
            args.scenario = mine[0]
    if args.config is None:
        protocol = args.protocol or "modbus"
        if furnace == PAPER:
            args.config = shipped(DEFAULT_CONFIGS[protocol])
        elif protocol != "modbus":
            raise FurnaceError(f"--protocol {protocol}: the shipped {protocol} map is the "
                               f"paper furnace's; for furnace '{furnace.name}' give --config "
                               f"with a {protocol} map of it")
        else:
            from .gatewayconfig import gateway_yaml

            args.out.mkdir(parents=True, exist_ok=True)
            args.config = args.out / "gateway.yaml"
            args.config.write_text(gateway_yaml(furnace, str(args.furnace.resolve()))
                                   + _signals_yaml(furnace))
    return furnace


def _scenario_furnace_file(path: Path) -> Path:
    """The description file a (loaded, so valid) scenario's `furnace` key names."""
    from furnace_model.config import load_yaml
    from furnace_model.simulation.furnacefile import furnace_file

    found = furnace_file(load_yaml(path).child("furnace").string(), path.parent)
    assert found is not None, "load_scenario has resolved it"
    return found


def _scenario_furnace(path: Path) -> Furnace | None:
    try:
        return load_scenario(path).furnace
    except FurnaceError:
        return None


def run(args: argparse.Namespace) -> int:
    if not (args.speed > 0 and args.every > 0 and args.polls_per_minute > 0):
        raise FurnaceError("--speed, --polls-per-minute and --every must be positive")
    furnace = _of_furnace(args)
    scenario = load_scenario(args.scenario, furnace)
    log_dir = args.out / "logs"
    for old in [*log_dir.glob("*.mcap*"), args.out / "state" / "model.json",
                args.out / "state" / "refit_chain.json"]:
        old.unlink(missing_ok=True)  # a previous run's results must not pass for this one's
    print(f"1. Simulated PLC: {scenario.name}: {scenario.description}")
    if furnace.modulated or furnace.disturbances:
        inputs = ", ".join([f"{z} ({h.unit})" for z, h in zip(furnace.zones,
                                                              furnace.heat_inputs, strict=True)]
                           + [f"{d.name} ({d.unit})" for d in furnace.disturbances])
        steps = f"{scenario.steps_t.size} steps of {inputs}"
    else:
        steps = "burners on: " + ", ".join(
            f"{int(n.sum())} from {t / 60:g} h"
            for t, n in zip(scenario.steps_t, scenario.steps_burners, strict=True))
    print(f"   {steps}; {scenario.duration_min / 60:.1f} simulated hours at "
          f"{args.speed:g}x ({scenario.duration_min * 60 / args.speed:.0f} s)")
    refits = asyncio.run(_acquire(scenario, args, log_dir))
    logs = sorted(log_dir.glob("*.mcap"))
    print(f"   MCAP log: {', '.join(map(str, logs))}")

    print("\n3. The whole run, exported from the log and fitted once (for comparison)")
    # The PLC holds its last state after the scenario; the run is the scenario's span.
    end = None if scenario.start_time is None else \
        scenario.start_time + pd.Timedelta(minutes=scenario.duration_min)
    frame = resample_logs(logs, period_s=60.0, end=end)
    data = args.out / f"{scenario.name}.csv"
    write_table(frame, data)
    exp = experiment_from_frame(frame, str(data), furnace=furnace)
    t0 = time.perf_counter()
    whole = fit([exp], ModelStructure(furnace=furnace), method="fast", seed=args.seed,
                zone_offsets=True)
    print(f"   {len(exp)} one-minute rows -> {data}; fitted in {time.perf_counter() - t0:.2f} s")
    out_json = args.out / "fit.json"
    out_json.write_text(json.dumps(whole.to_json([str(data)]), indent=2))

    good = [m for m in refits if m.fitted]
    print("\n4. Identified parameters against the simulator's truth")
    if not good:
        print("   no online refit succeeded: see /model/parameters in the log for why",
              file=sys.stderr)
        return 1
    last = good[-1]
    start = scenario.start_time
    print(f"   last online refit: window {_hours(last.window_start, start)}-"
          f"{_hours(last.window_end, start)} h; whole run: 0-{scenario.duration_min / 60:.1f} h")
    _report(last, whole, scenario)
    label = f"online model of {_hours(last.window_end, start)} h"
    online = Model(ModelStructure(furnace=furnace),
                   {p: last.params[p] for p in param_names(furnace)})
    plots = _plots(exp, online, good, scenario, args.out, label)
    print(f"\n   MCAP log:   {', '.join(map(str, logs))}")
    state = args.out / "state" / "model.json"
    if state.exists():
        print(f"   model:      {state} (the latest refit, as the daemon keeps it)")
    print(f"   whole run:  {data}, {out_json}")
    for path in plots:
        print(f"   plot:       {path}")
    return 0


class _Tap:
    """The daemon's log, seen in passing: the display shows what was acquired and logged."""

    def __init__(self, log: LogWriter, furnace: Furnace, start: pd.Timestamp | None):
        self.inner = log
        self.furnace = furnace
        self.start = start
        self.latest: dict[str, Thermocouples | Burners | Heat] = {}

    @property
    def error(self) -> str | None:
        return self.inner.error

    def write(self, topic: str, message: dict, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        if topic == THERMOCOUPLES:
            tc = Thermocouples.from_json(message, self.furnace)
            if tc.error is None:
                self.latest[topic] = tc
        elif topic == BURNERS:
            self.latest[topic] = Burners.from_json(message, self.furnace)
        elif topic == HEAT:
            self.latest[topic] = Heat.from_json(message, self.furnace)
        elif topic == MODEL_EVENTS:
            event = ModelEvent.from_json(message)
            if event.kind == ModelEventKind.DRIFT:
                print(f"   drift event: {event.detail}", flush=True)
            elif event.kind == ModelEventKind.SENSOR_SET_ASIDE:
                print(f"   {event.detail}", flush=True)
        elif topic == MODEL_DIAGNOSIS:
            print(_diagnosis_line(ModelDiagnosis.from_json(message), self.start), flush=True)
        self.inner.write(topic, message, log_time_ns, publish_time_ns)

    def maybe_flush(self, now_monotonic: float) -> None:
        self.inner.maybe_flush(now_monotonic)

    def close(self) -> None:
        self.inner.close()


async def _start_plc(args: argparse.Namespace, scan_s: float
                     ) -> tuple[asyncio.subprocess.Process, int]:
    """`furnace-daq sim-plc` in its own process, as the PLC is its own device on a plant."""
    furnace = [] if args.furnace is None else ["--furnace", str(args.furnace)]
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "furnace_daq.cli", "sim-plc", "--scenario", str(args.scenario),
        *furnace, "--config", str(args.config), "--protocol", args.protocol,
        "--speed", f"{args.speed:g}", "--seed",
        str(args.seed), "--scan-s",
        f"{scan_s:g}", "--port", "0", stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE)
    try:
        line = (await asyncio.wait_for(proc.stdout.readline(), 60.0)).decode()
    except TimeoutError:
        line = ""
    if not line.startswith("listening on "):
        if proc.returncode is None:
            proc.kill()
        err = (await proc.stderr.read()).decode().strip()
        await proc.wait()
        raise FurnaceError(f"the simulated PLC did not start: {err or line or 'no answer'}")
    return proc, int(line.rsplit(":", 1)[1])


async def _acquire(scenario: Scenario, args: argparse.Namespace, log_dir: Path) -> list[ModelParameters]:
    """The simulated PLC, the daemon and its refit worker: three processes, as on a gateway
    polling a PLC. Returns the /model/parameters messages."""
    poll_s = 60.0 / args.polls_per_minute / args.speed
    config = load_config(args.config)
    spoken = config.plc.protocol
    if args.protocol is None:
        args.protocol = spoken
    elif args.protocol != spoken:
        raise FurnaceError(f"--protocol {args.protocol}: the first device of {args.config} "
                           f"speaks {spoken}")
    plc, port = await _start_plc(args, poll_s)
    refit = config.refit or RefitConfig()
    # Windows wait in the queue for a verdict that may set a thermocouple aside for them
    # (refitworker): at 1x it is always in, at this speed a diagnosis spans days of the plant.
    windows = int(scenario.duration_min / 60.0 / args.refit_period_h) + 2
    refit = replace(refit, period_s=args.refit_period_h * 3600.0,
                    window_s=args.refit_window_h * 3600.0, step_s=60.0,
                    state_dir=args.out / "state", queue_max=max(refit.queue_max, windows),
                    diagnosis=refit.diagnosis or DiagnosisConfig(
                        after_windows=2, time_limit_s=DEMO_DIAGNOSIS_S))
    plc_config = replace(config.plc, host="127.0.0.1", port=port)
    if plc_config.opcua is not None:
        # one Read per poll: a subscription sampled every 500 ms of the wall clock would
        # see the plant minutes apart at this speed
        plc_config = replace(plc_config, opcua=replace(plc_config.opcua, mode="poll"))
    config = replace(
        config, poll_period_s=poll_s, stale_after_s=max(config.stale_after_s, 1.0),
        plc=plc_config,
        clock=replace(config.clock, epoch=scenario.start_time) if config.clock else None,
        log=replace(config.log, dir=log_dir), refit=refit)
    log_dir.mkdir(parents=True, exist_ok=True)
    log = _Tap(LogWriter(log_dir, prefix=config.log.prefix, flush_interval_s=1.0,
                         file_mode=config.log.file_mode, metadata=build_metadata(config),
                         event_priority=EVENT_PRIORITY, signals=signal_fields(config)),
               config.furnace, scenario.start_time)
    refits: list[ModelParameters] = []

    def on_model(message: dict) -> None:
        msg = ModelParameters.from_json(message)
        refits.append(msg)
        print(_refit_line(msg, scenario.start_time), flush=True)

    daemon = Daemon(config, log, on_model=on_model)
    print(f"2. Daemon polling 127.0.0.1:{port} over {PROTOCOLS[spoken].text} every "
          f"{poll_s * 1e3:.1f} ms "
          f"({60 / args.polls_per_minute:g} simulated seconds), logging MCAP to {log_dir}; "
          f"a refit of the last {args.refit_window_h:g} h every {args.refit_period_h:g} h "
          "of PLC time")
    zones = config.furnace.zones
    columns = _columns(config.furnace)
    what = "thermocouples, °C" if _each_tc(config.furnace) else "zone means, °C"
    fired = "heat inputs" if config.furnace.modulated else "burners"
    print(f"   {'PLC time':>7}  {what:^{9 * len(columns) - 1}}  {fired}")
    print(f"   {'':7}  " + " ".join(f"{s:>8}" for s in columns) + "  " + "/".join(zones))
    duration = scenario.duration_min * 60.0 / args.speed + 3 * poll_s

    async def show() -> None:
        while True:
            await asyncio.sleep(args.every)
            print(_progress_line(log.latest, config.furnace), flush=True)

    shower = asyncio.create_task(show())
    running = asyncio.create_task(daemon.run())
    try:
        await asyncio.wait([running], timeout=duration)
        end_ns = None if scenario.start_time is None else \
            scenario.start_time.value + int(round(scenario.duration_min * 60e9))
        await _diagnoses_done(daemon, refit.diagnosis, running, end_ns)
        daemon.stop()
        counters = await running
    finally:
        daemon.stop()
        shower.cancel()
        if plc.returncode is None:
            plc.terminate()
        await plc.wait()
    print(_progress_line(log.latest, config.furnace))
    print(f"   {counters.ok_polls} of {counters.polls} polls answered, "
          f"{counters.skipped_ticks} ticks skipped; {len(refits)} refits, "
          f"{sum(m.fitted for m in refits)} ok")
    skipped = counters.skipped_ticks / max(counters.polls + counters.skipped_ticks, 1)
    if skipped > 0.1:
        print(f"   note: {100 * skipped:.0f}% of the poll ticks were skipped: this host is too "
              f"busy for {args.speed:g}x, so windows miss samples; a lower --speed helps")
    return refits


DEMO_DIAGNOSIS_S = 300.0
"""The online diagnosis's time limit where the config sets none: it answers within it with
the candidates it did not reach named."""


async def _diagnoses_done(daemon: Daemon, config: DiagnosisConfig,
                          running: asyncio.Task, end_ns: int | None) -> None:
    """At the scenario's end, the diagnoses in flight or queued, and the scenario's windows
    still to fit (they may wait for a verdict), are waited for with the PLC still polled,
    each diagnosis within its time limit and the margin its runner gives it: the verdict on
    the last fault is what the demo is there to show."""
    runner = daemon.refit.runner if daemon.refit is not None else None

    def owed() -> bool:
        assert runner is not None
        fits = [*runner.queue, *([runner.in_flight[0]] if runner.in_flight else [])]
        return runner.diagnosing() or any(end_ns is None or w.end_ns <= end_ns for w in fits)

    if runner is None or running.done() or not owed():
        return
    print(f"   the scenario has ended; waiting for its refits still queued and the online "
          f"diagnoses they wait for (each at most {config.time_limit_s:g} s, its time limit)",
          flush=True)
    each = KILL_FACTOR * config.time_limit_s + KILL_MARGIN_S
    deadline = time.monotonic() + each
    while owed() and not running.done() and time.monotonic() < deadline:
        if runner.diagnoses is not None and runner.diagnosing():
            deadline = max(deadline, runner.diagnoses.in_flight_since() + each)
        await asyncio.sleep(0.2)


def _diagnosis_line(d: ModelDiagnosis, start: pd.Timestamp | None) -> str:
    """An online diagnosis as the demo shows it: its verdict, on which window, why."""
    window = ""
    if d.fitted:
        window = (f" of {_hours(d.fitted[0]['start'], start)}-"
                  f"{_hours((d.held_out or d.fitted)[-1]['end'], start)} h")
    took = f", {d.elapsed_s:.0f} s" if d.elapsed_s is not None else ""
    return f"   online diagnosis{window} ({d.trigger}{took}): {d.status}: {d.detail}"


LINE_TCS = 8
"""The most thermocouples a progress line shows one by one (the paper's six fit; a dozen do
not, and a furnace of more shows its zone means)."""


def _each_tc(furnace: Furnace) -> bool:
    return len(furnace.sensors) <= LINE_TCS


def _columns(furnace: Furnace) -> tuple[str, ...]:
    """What the progress lines show: each thermocouple, or each zone's mean reading."""
    return furnace.sensors if _each_tc(furnace) else furnace.zones


def _progress_line(latest: dict[str, Thermocouples | Burners | Heat], furnace: Furnace
                   ) -> str:
    tc, burners, heat = latest.get(THERMOCOUPLES), latest.get(BURNERS), latest.get(HEAT)
    if not isinstance(tc, Thermocouples):
        return "   (no reading yet)"
    hours = (math.nan if tc.plc_seconds is None else tc.plc_seconds) / 3600.0
    if _each_tc(furnace):
        values: list = [tc.values.get(s) for s in furnace.sensors]
    else:
        readings = np.array([number(tc.values.get(s)) for s in furnace.sensors], dtype=float)
        values = [None if not np.isfinite(v) else float(v)
                  for v in furnace.zone_means(readings[None, :])[0]]
    temps = " ".join(f"{v:8.1f}" if isinstance(v, int | float) else f"{'-':>8}"
                     for v in values)
    inputs = []  # each zone's: burners firing, or its rate as last read
    for z in furnace.zones:
        if isinstance(burners, Burners) and z in burners.counts:
            inputs.append(str(burners.counts[z]))
        elif isinstance(heat, Heat) and z in heat.values:
            inputs.append(f"{heat.values[z]:.4g}")
        else:
            inputs.append("?")
    return f"   {hours:5.1f} h  {temps}  {'/'.join(inputs)}"


def _hours(iso: str, start: pd.Timestamp | None) -> str:
    if start is None:
        return iso
    return f"{(pd.Timestamp(iso) - start).total_seconds() / 3600.0:g}"


def _refit_line(msg: ModelParameters, start: pd.Timestamp | None) -> str:
    window = f"{_hours(msg.window_start, start)}-{_hours(msg.window_end, start)} h"
    head = f"   refit of {window:>10}: {msg.status}"
    if not msg.fitted:
        kept = "previous model kept" if msg.ci95 else "no model yet"
        return f"{head} ({msg.detail}); {kept}"
    names = list(msg.ci95 or {})  # the furnace's parameters: a..f for the paper's
    combos = msg.combinations or {}
    named = [c for c in msg.determined_combinations or () if c in combos]
    loose = [p for p in names if p not in named]
    if len(names) > 6:  # a network of many parameters: how many the window determines
        params = f"{len(names) - len(loose)} of {len(names)} parameters determined"
        if loose:
            params += f" (not: {' '.join(loose)})"
    else:
        params = " ".join(f"{c} {combos[c]['value']:.5g}" for c in named)
        if loose:
            params += "; not determined: " + " ".join(f"{p} {msg.params[p]:.3g}"
                                                      for p in loose)
    rmse = "/".join(f"{v:.2f}" for v in (msg.rmse_c or {}).values())
    took = f", {msg.elapsed_s:.2f} s" if isinstance(msg.elapsed_s, float) else ""
    return f"{head}: {params}; RMSE {rmse} °C{took}"


def combination_value(name: str, params: dict[str, float]) -> float:
    """The value at `params` of a combination as the fit names it: 'd/e', 'b*c',
    'a^0.5*c/b', 'b^0.5*e/(c*d)'."""
    num, _, den = name.partition("/")
    den = den[1:-1] if den.startswith("(") and den.endswith(")") else den
    value = 1.0
    for part, sign in ((num, 1.0), (den, -1.0)):
        for term in filter(None, part.split("*")):
            if term == "1":
                continue
            m = re.fullmatch(r"([a-z]\w*)(?:\^([0-9.]+))?", term)
            if m is None or m.group(1) not in params:
                raise ValueError(f"not a combination of parameters: {name!r}")
            value *= params[m.group(1)] ** (sign * float(m.group(2) or 1.0))
    return value


def _report(online: ModelParameters, whole: FitResult, scenario: Scenario) -> None:
    truth = scenario.values()
    names = param_names(scenario.furnace)
    width = max(10, *(len(n) + 1 for n in names))
    print(f"   {'':{width}}{'truth':>10}  {'last online refit':>28}  {'whole run':>28}")
    undetermined = set(online.undetermined or ())
    ci95 = online.ci95 or {}
    for name in names:
        lo, hi = ci95[name]
        note = "  not determined alone (online)" if name in undetermined else ""
        print(f"   {name:{width}}{truth[name]:10.5g}  "
              f"{_cell(online.params[name], truth[name], lo, hi)}  "
              f"{_cell(whole.params[name], truth[name], *whole.ci95[name])}{note}")
    combos = [c for c in online.determined_combinations or [] if c not in names]
    combos += [c for c in whole.determined_combinations if c not in names + tuple(combos)]
    if combos:
        print("   determined combinations:")
    for name in combos:
        want = combination_value(name, truth)
        cells = []
        for combos_of in (online.combinations or {}, whole.combinations):
            c = combos_of.get(name)
            cells.append(_cell(c["value"], want, *c["ci95"]) if c else f"{'-':>28}")
        print(f"   {name:{width}}{want:10.5g}  {cells[0]}  {cells[1]}")
    zones = scenario.furnace.zones
    rmse = lambda m: "/".join(f"{m[z]:.2f}" for z in zones)  # noqa: E731
    print(f"   {'RMSE, °C':{width}}{'':10}  {rmse(online.rmse_c or {}):>28}  "
          f"{rmse({z: whole.per_zone[z]['rmse_c'] for z in zones}):>28}")


def _plots(exp, online: Model, good: list[ModelParameters], scenario: Scenario, out: Path,
           label: str) -> list[Path]:
    """The demo's figures, when the `report` extra (matplotlib) is installed: the daemon's
    installation runs the demo without them."""
    from furnace_model.extras import missing

    if missing("report"):
        print("   figures skipped: matplotlib is not installed (install furnace-daq[report])")
        return []
    from furnace_model.plots import plot_fit  # matplotlib: not for the refit worker's import

    return [*plot_fit(exp, online.predict(exp), out, label),
            plot_refits(good, scenario, out / "refits.png")]


def plot_refits(refits: list[ModelParameters], scenario: Scenario, path: Path) -> Path:
    """Each fitted window's a, f, b/c and d/e (another furnace's: its heats per burner)
    against the truth, with 95% intervals: what the online identification did over the run,
    on one page."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    truth = scenario.values()
    start = scenario.start_time
    fig = Figure(figsize=(8, 4.5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    ends = [float(_hours(m.window_end, start)) if start is not None else k
            for k, m in enumerate(refits)]
    furnace = scenario.furnace
    shown = (("a", "f", "b/c", "d/e") if furnace.paper_structure
             else tuple(p for p in param_names(furnace) if p.startswith("gain_")))
    for k, name in enumerate(shown):
        want = combination_value(name, truth)
        x, y, err = [], [], []
        for end, m in zip(ends, refits, strict=True):
            c = (m.combinations or {}).get(name)
            if c is None and name in (m.ci95 or {}) and name in m.params:
                c = {"value": m.params[name], "ci95": m.ci95[name]}  # type: ignore[index]
            if c is None:
                continue
            lo, hi = c["ci95"]
            x.append(end + 0.25 * (k - (len(shown) - 1) / 2))
            y.append(100 * (c["value"] / want - 1))
            err.append([100 * (c["value"] - lo) / abs(want),
                        100 * (hi - c["value"]) / abs(want)])
        if x:
            ax.errorbar(x, y, yerr=np.array(err).T, fmt="o", ms=4, capsize=2, label=name)
    for t in scenario.steps_t[1:]:
        ax.axvline(t / 60.0, color="0.7", lw=0.8, ls="--")
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xlabel("end of the refit window (h of the run); dashed: burner steps")
    ax.set_ylabel("error against the truth (%)")
    ax.set_title(f"{scenario.name}: online refits, 95% intervals")
    ax.legend(loc="best")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    return path


def _cell(value: float, truth: float, lo: float, hi: float) -> str:
    """Value, error against the truth in %, and the 95% interval's half-width in %."""
    half = 50.0 * (hi - lo) / abs(value) if value else math.nan
    return f"{value:10.5g} {100 * (value / truth - 1):+7.2f}% (±{half:.2g}%)".rjust(28)


if __name__ == "__main__":
    sys.exit(main())
