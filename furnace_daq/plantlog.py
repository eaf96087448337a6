"""A simulated plant run as the daemon would have logged it, without Modbus: the messages of
/furnace/thermocouples, /furnace/burners and /furnace/ambient at every sample.

Long runs (a week at 1 Hz) cannot go through the simulated PLC in test or benchmark time;
this writes the same topics and fields from the plant simulator directly, for the refit
tests and the replay benchmark.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pandas as pd

from furnace_model.log.messages import Ambient, Burners, FurnaceMessage, Thermocouples
from furnace_model.log.schema import AMBIENT, BURNERS, THERMOCOUPLES
from furnace_model.simulation.plant import PlantRun

from .mcaplog import LogWriter
from .simplc import states_from_counts, zone_slices


def run_messages(run: PlantRun, start: pd.Timestamp | None = None
                 ) -> Iterator[tuple[str, FurnaceMessage, int]]:
    """(topic, message, publish time ns) per sample, thermocouples rounded to the PLC's
    0.1 degC as the register map delivers them."""
    t0 = (start or run.start_time or pd.Timestamp("2026-01-01T00:00:00Z")).value
    pub = t0 + np.round(run.t_min * 60e9).astype(np.int64)
    tc = np.round(run.tc * 10.0) / 10.0
    furnace = run.furnace
    ok = {s: "ok" for s in furnace.sensors}
    last_counts = None
    burner_msg: Burners | None = None
    for i in range(run.t_min.size):
        t = int(pub[i])
        yield THERMOCOUPLES, Thermocouples(dict(zip(furnace.sensors, tc[i].tolist(),
                                                    strict=True)),
                                           ok, float(run.t_min[i] * 60.0)), t
        yield AMBIENT, Ambient(float(run.t_air[i]), "ok"), t
        counts = tuple(int(n) for n in run.burners[i])
        if counts != last_counts or burner_msg is None:
            states = states_from_counts(np.array(counts), furnace)
            burner_msg = Burners({z: states[k] for z, k in zip(furnace.zones,
                                                               zone_slices(furnace),
                                                               strict=True)},
                                 dict(zip(furnace.zones, counts, strict=True)), "modbus", "ok")
            last_counts = counts
        yield BURNERS, burner_msg, t


def write_run(run: PlantRun, log: LogWriter, start: pd.Timestamp | None = None) -> int:
    """Log a run (log time = publish time, as a daemon whose PLC clock is the host's);
    returns the number of messages written. The writer must be of the run's furnace."""
    n = 0
    for topic, msg, t in run_messages(run, start):
        log.write(topic, msg.to_json(), t, t)
        n += 1
    return n
