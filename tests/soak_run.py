"""A soak: the real `furnace-daq run` process polling `sim-plc` at high speed through the
fault proxy, with online refits, a fault injected every few simulated minutes. Shared by
tests/test_soak.py and bench/bench_reliability.py.

What it watches from outside the daemon: its resident memory and open descriptors
(/proc/<pid>), and, through the proxy, every poll the PLC answered in time; afterwards the
log must hold each of those polls as a good reading."""

from __future__ import annotations

import signal
import statistics
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from crash_runs import wait_polling
from daq_processes import ROOT, furnace_daq, start_simplc, stop
from faultproxy import ThreadedFaultProxy

from furnace_model.log.read import read_messages
from furnace_model.log.schema import DAQ_STATUS, MODEL_PARAMETERS, THERMOCOUPLES

PERIOD_S, TIMEOUT_S, BACKOFF_CAP_S = 0.1, 0.3, 0.5
BACK_WITHIN_S = 2 * BACKOFF_CAP_S + TIMEOUT_S + PERIOD_S
"""Healing to the first good reading: a dial in the last moments of an outage fails and
waits one more backoff, then a poll may time out on a request the outage swallowed, then
one period to the next tick."""
FAULTS: tuple[tuple[str, dict], ...] = (
    ("drop", {}), ("stall", {}), ("reset", {}), ("garbage", {}), ("truncate", {}),
    ("delay", {"delay_s": 0.05}), ("refuse", {}))


@dataclass
class Fault:
    mode: str
    start_ns: int
    healed_ns: int
    back_s: float | None = None  # healing to the first good reading logged after it


@dataclass
class Soak:
    speed: float
    sim_minutes: float
    wall_s: float = 0.0
    rss_kib: list[tuple[float, int]] = field(default_factory=list)  # (s since start, KiB)
    fds: list[tuple[float, int]] = field(default_factory=list)
    faults: list[Fault] = field(default_factory=list)
    answered: int = 0  # polls the PLC answered within the timeout
    logged_ok: int = 0
    missing: list[int] = field(default_factory=list)  # PLC seconds answered but not logged
    refits: Counter = field(default_factory=Counter)  # /model/parameters by status
    exit_code: int | None = None
    stderr: str = ""

    def rss_growth(self, warm_fraction: float = 0.25) -> float:
        """Resident memory at the end against just after warm-up (means of 10% of the run)."""
        span = self.rss_kib[-1][0]
        warm = [v for t, v in self.rss_kib if warm_fraction * span <= t < (warm_fraction + 0.1)
                * span]
        end = [v for t, v in self.rss_kib if t >= 0.9 * span]
        return sum(end) / len(end) / (sum(warm) / len(warm)) - 1.0

    def fd_growth(self, warm_fraction: float = 0.25) -> int:
        """Open descriptors at the end against just after warm-up (medians of 10% of the run:
        a socket being redialled at one sample is not a leak; a leak grows with the faults)."""
        span = self.fds[-1][0]
        warm = [v for t, v in self.fds if warm_fraction * span <= t < (warm_fraction + 0.1)
                * span]
        end = [v for t, v in self.fds if t >= 0.9 * span]
        return int(statistics.median(end) - statistics.median(warm))


def config_file(directory: Path, refit: bool = True) -> Path:
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["poll_period_s"] = PERIOD_S
    doc["stale_after_s"] = 2.0
    doc["status_interval_s"] = 2.0
    doc["plc"].update(timeout_s=TIMEOUT_S, max_consecutive_errors=2,
                      reconnect={"initial_s": 0.1, "max_s": BACKOFF_CAP_S, "factor": 2.0})
    doc["log"].update(flush_interval_s=1.0, rotate_s=60.0)  # several files: rotation too
    if refit:
        # PLC-clock windows of 15 min every 5 min, fitted despite the faults' gaps: a refit
        # every 2.5 s of wall time at 120x, the first after 7.5 s.
        doc["refit"] = {"enabled": True, "period_s": 300, "window_s": 900, "step_s": 60,
                        "budget_s": 5, "min_burner_steps": 0, "max_gap_fraction": 0.5,
                        "queue_max": 2,
                        "state_dir": str(directory / "state")}
    else:
        doc.pop("refit", None)
    path = directory / "soak.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def _proc_stats(pid: int) -> tuple[int, int]:
    rss = 0
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1])
    return rss, len(list(Path(f"/proc/{pid}/fd").iterdir()))


def soak(directory: Path, sim_minutes: float, speed: float, fault_every_sim_min: float = 4.0,
         fault_wall_s: float = 0.6, refit: bool = True) -> Soak:
    """Run the soak and gather what it shows; the caller judges."""
    logs = directory / "logs"
    result = Soak(speed, sim_minutes)
    wall_s = sim_minutes * 60.0 / speed
    fault_period_s = fault_every_sim_min * 60.0 / speed
    sim, port = start_simplc("--speed", str(speed), "--scan-s", "0.05")
    try:
        with ThreadedFaultProxy(port) as proxy:
            daq = furnace_daq("run", "--config", str(config_file(directory, refit)), "--plc",
                              f"127.0.0.1:{proxy.port}", "--log-dir", str(logs))
            try:
                result.stderr = wait_polling(daq)
                t0 = time.monotonic()
                next_fault, k = t0 + fault_period_s, 0
                while (now := time.monotonic()) < t0 + wall_s:
                    rss, fds = _proc_stats(daq.pid)
                    result.rss_kib.append((now - t0, rss))
                    result.fds.append((now - t0, fds))
                    if now >= next_fault and now + fault_wall_s + 1.0 < t0 + wall_s:
                        mode, kw = FAULTS[k % len(FAULTS)]
                        k += 1
                        start = time.time_ns()
                        proxy.set_mode(mode, **kw)
                        time.sleep(fault_wall_s)
                        healed = time.time_ns()
                        proxy.set_mode("pass")
                        result.faults.append(Fault(mode, start, healed))
                        next_fault += fault_period_s
                    time.sleep(0.25)
                result.wall_s = time.monotonic() - t0
                daq.send_signal(signal.SIGTERM)
                _, err = daq.communicate(timeout=60)
                result.stderr += err
                result.exit_code = daq.returncode
            finally:
                stop(daq)
            answered = answered_polls(proxy)
    finally:
        stop(sim)
    _judge_log(result, sorted(logs.glob("*.mcap")), answered)
    return result


def answered_polls(proxy: ThreadedFaultProxy) -> Counter:
    """PLC seconds of every poll whose two reads (input registers 0-9, then the burner bits)
    the PLC answered and the proxy delivered intact, well within the daemon's timeout (half
    of it: a margin for a busy machine's scheduling)."""
    pairs = {(req.conn, req.tid): (req, resp) for req, resp in proxy.answered[:]}
    out: Counter = Counter()
    for (conn, tid), (req, resp) in pairs.items():
        bits = pairs.get((conn, tid + 1))
        if req.function_code == 4 and req.address_count == (0, 10) and bits is not None \
                and bits[0].function_code == 2 and bits[1].at - req.at <= TIMEOUT_S / 2:
            regs = resp.registers
            out[(regs[7] << 16) | regs[8]] += 1
    return out


def _judge_log(result: Soak, files: list[Path], answered: Counter) -> None:
    logged: Counter = Counter()
    ok_times = []
    for topic, m, log_ns, _ in read_messages(files, (THERMOCOUPLES, MODEL_PARAMETERS,
                                                     DAQ_STATUS)):
        if topic == THERMOCOUPLES and all(q == "ok" for q in m["quality"].values()):
            logged[int(m["plc_seconds"])] += 1
            ok_times.append(log_ns)
        elif topic == MODEL_PARAMETERS:
            result.refits[m.get("status", "?")] += 1
    result.answered = sum(answered.values())
    result.logged_ok = sum(logged.values())
    result.missing = sorted((answered - logged).elements())
    for f in result.faults:
        after = [t for t in ok_times if t > f.healed_ns]
        f.back_s = (after[0] - f.healed_ns) / 1e9 if after else None
