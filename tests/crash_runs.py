"""Kill the real daemon process at random moments and count what it lost: shared by
tests/test_crash.py and bench/bench_reliability.py.

The loss is judged against what the PLC served, not against a clock: the fault proxy
between the daemon and `sim-plc` (in pass mode) records every thermocouple read it passes to
the daemon, and the log must hold all but the polls of the last flush interval.
A daemon starved of CPU polls less and loses no more, so a busy machine cannot fail this."""

from __future__ import annotations

import random
import signal
import time
from dataclasses import dataclass
from pathlib import Path

import yaml
from daq_processes import ROOT, furnace_daq, stop, wait_for_line
from faultproxy import ThreadedFaultProxy

from furnace_model.log.read import read_messages
from furnace_model.log.schema import THERMOCOUPLES

PERIOD_S = 0.05
FLUSH_S = 0.5
THERMOCOUPLE_FC = 4


class ServedReads:
    """Thermocouple reads (FC4 responses at address 0) the proxy passed to the daemon, counted
    since the last call."""

    def __init__(self, proxy: ThreadedFaultProxy):
        self.proxy, self._seen = proxy, 0

    def take(self) -> int:
        answered = self.proxy.answered[:]  # appended to by the proxy's thread
        new, self._seen = answered[self._seen:], len(answered)
        return sum(1 for req, resp in new if req.function_code == THERMOCOUPLE_FC
                   and req.address_count is not None and req.address_count[0] == 0
                   and resp.function_code == THERMOCOUPLE_FC)


def daemon_config(directory: Path, flush_s: float = FLUSH_S, period_s: float = PERIOD_S) -> Path:
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["poll_period_s"] = period_s
    doc["plc"]["timeout_s"] = 0.5
    doc["plc"]["reconnect"] = {"initial_s": 0.1, "max_s": 0.5, "factor": 2.0}
    doc["log"]["flush_interval_s"] = flush_s
    doc["refit"]["enabled"] = False  # polling and logging only: no refit worker
    path = directory / "daq.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def good_readings(files: list[Path]) -> int:
    """Thermocouple messages read from the PLC (not comm errors) in these files, finished
    or not."""
    return sum(1 for _, m, _, _ in read_messages(sorted(files), [THERMOCOUPLES])
               if m["quality"]["soak_1"] != "comm_error")


@dataclass
class Kill:
    after_s: float  # from the process start
    served: int  # thermocouple reads the PLC answered to this daemon
    logged: int  # of them, readable from the files it left

    @property
    def lost(self) -> int:
        return self.served - self.logged


def kill_runs(log_dir: Path, proxy: ThreadedFaultProxy, served: ServedReads, config: Path,
              n: int, seed: int,
              max_after_s: float = 2.0) -> list[Kill]:
    """Start `furnace-daq run` n times on one log directory and SIGKILL it at a random moment
    (one in five during start-up, the others up to `max_after_s` into polling). Each start recovers the `.part`
    the previous kill left; the last kill's `.part` stays for the caller."""
    rng = random.Random(seed)
    kills = []
    for _ in range(n):
        before = set(log_dir.iterdir())
        proc = furnace_daq("run", "--config", str(config), "--plc", f"127.0.0.1:{proxy.port}",
                           "--log-dir", str(log_dir))
        t_start = time.monotonic()
        if rng.random() < 0.2:  # during start-up: imports, recovery of the last kill's file
            time.sleep(rng.uniform(0.0, 1.0))
        else:
            wait_polling(proc)
            time.sleep(rng.uniform(0.05, max_after_s))
        after_s = time.monotonic() - t_start
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        stop(proc)
        time.sleep(0.05)  # the proxy sees the connection close
        n_served = served.take()
        new = [p for p in set(log_dir.iterdir()) - before if p.name.endswith((".part", ".mcap"))
               and ".recovered." not in p.name]
        kills.append(Kill(after_s, n_served, good_readings(new) if new else 0))
    return kills


def wait_polling(proc, timeout: float = 30.0) -> str:
    """Until the daemon says it polls (its log and recovery are set up by then); what it
    wrote on stderr so far."""
    try:
        return "".join(wait_for_line(proc, r"^<6>polling ", timeout))
    except AssertionError as exc:
        raise RuntimeError(f"furnace-daq run did not start polling: {exc}") from None


def max_loss_polls(flush_s: float = FLUSH_S, period_s: float = PERIOD_S) -> int:
    """Polls one flush interval can hold, plus the poll in flight and the one being written."""
    return int(flush_s / period_s) + 2
