"""A simulated plant run as the daemon would have logged it, without Modbus: the messages of
/furnace/thermocouples, /furnace/burners and /furnace/ambient at every sample (and
/furnace/heat, /furnace/disturbances for a furnace with rate-fired zones, disturbances).

Long runs (a week at 1 Hz) cannot go through the simulated PLC in test or benchmark time;
this writes the same topics and fields from the plant simulator directly, for the refit
tests and the replay benchmark. A pulse-fired zone cannot be written so: its burners pulse
within a sample, and a run holds only their mean; it goes through the simulated PLC.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pandas as pd

from furnace_model.log.messages import (
    Ambient,
    Burners,
    Disturbances,
    FurnaceMessage,
    Heat,
    Thermocouples,
)
from furnace_model.log.schema import AMBIENT, BURNERS, DISTURBANCES, HEAT, THERMOCOUPLES
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
    if any(h.kind == "pulse" for h in furnace.heat_inputs):
        raise ValueError(f"furnace '{furnace.name}' has pulse-fired zones: their burners "
                         "pulse within a sample; log the run through the simulated PLC")
    ok = {s: "ok" for s in furnace.sensors}
    zones = furnace.switched_zones
    rated = [furnace.zones[i] for i in furnace.rated]
    names = [d.name for d in furnace.disturbances]
    last_counts = None
    burner_msg: Burners | None = None
    for i in range(run.t_min.size):
        t = int(pub[i])
        yield THERMOCOUPLES, Thermocouples(dict(zip(furnace.sensors, tc[i].tolist(),
                                                    strict=True)),
                                           ok, float(run.t_min[i] * 60.0)), t
        yield AMBIENT, Ambient(float(run.t_air[i]), "ok"), t
        if rated:
            yield HEAT, Heat({z: float(run.burners[i, j]) for z, j in zip(
                rated, furnace.rated, strict=True)}, dict.fromkeys(rated, "ok"),
                {z: furnace.heat_inputs[j].unit for z, j in zip(rated, furnace.rated,
                                                               strict=True)}), t
        if names:
            assert run.disturbances is not None
            yield DISTURBANCES, Disturbances(
                dict(zip(names, run.disturbances[i].tolist(), strict=True)),
                dict.fromkeys(names, "ok"), {d.name: d.unit for d in furnace.disturbances}), t
        if not zones:
            continue
        counts = tuple(int(run.burners[i, j]) for j in furnace.switched)
        if counts != last_counts or burner_msg is None:
            states = states_from_counts(np.array(counts), furnace)
            burner_msg = Burners({z: states[k] for z, k in zip(zones, zone_slices(furnace),
                                                               strict=True)},
                                 dict(zip(zones, counts, strict=True)), "modbus", "ok")
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
