"""A fleet of three simulated furnaces, a few days of logs each, written as the daemon logs
(furnace_daq.plantlog from the plant simulator, no Modbus): one switches fuel on day 2
(heat per burner -20%), one has wall losses in the soaking and heating zones that the
paper's model lacks, one is a control. Small refit windows keep a run cheap."""

from __future__ import annotations

from pathlib import Path

import yaml

from furnace_daq.mcaplog import LogWriter
from furnace_daq.plantlog import write_run
from furnace_model.simulation.plant import Plant
from furnace_model.simulation.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
DAYS = 2
SWITCH_MIN = 1800
"""The fuel switch: day 2, 06:00 (heat per burner -20%)."""
FURNACES = {
    # name: (scenario, effects, seed)
    "switch": ("fuel_switch", None, 1),
    "wall": ("week_steps", {"zone_losses": {"g_soak": 0.006, "g_heat": 0.006}}, 2),
    "control": ("week_steps", {}, 3),
}
REFIT = {"period_s": 21600, "window_s": 21600, "step_s": 300, "budget_s": 30}
CAMPAIGNS = [{"name": "d1", "from": "2026-03-02T12:00:00Z", "to": "2026-03-03T00:00:00Z"},
             {"name": "d2", "from": "2026-03-03T00:00:00Z", "to": "2026-03-03T12:00:00Z"}]
"""Half a day each; the fuel switch lies in d2."""
DIAGNOSE = {"effects": ["zone_losses", "fuel_change"], "period_s": 300}


def scenario_for(name: str, folder: Path):
    """The furnace's scenario cut to DAYS, with its effects (written next to its logs)."""
    base, effects, seed = FURNACES[name]
    doc = yaml.safe_load((ROOT / "config" / "scenarios" / f"{base}.yaml").read_text())
    doc["duration_min"] = DAYS * 1440 - 1
    doc["burners"]["steps"] = [st for st in doc["burners"]["steps"]
                               if st["at_min"] <= doc["duration_min"]]
    if effects is not None:
        doc["effects"] = effects
    if "fuel_change" in doc["effects"]:
        doc["effects"]["fuel_change"]["t_fuel"] = SWITCH_MIN
    path = folder / f"{name}.scenario.yaml"
    path.write_text(yaml.safe_dump(doc))
    return load_scenario(path), seed


def write_fleet(root: Path, names=tuple(FURNACES), broken: bool = False) -> Path:
    """Logs under root/<name>/ and root/fleet.yaml; returns the fleet file. `broken` adds a
    furnace whose one log file is not an MCAP file, and such a file among the control's."""
    furnaces = []
    for name in names:
        s, seed = scenario_for(name, root)
        run = Plant.from_scenario(s, seed=seed).run_scenario(s)
        log = LogWriter(root / name, flush_interval_s=3600.0, rotate_s=86400.0)
        write_run(run, log, s.start_time)
        log.close()
        furnaces.append({"name": name, "logs": [name], "campaigns": CAMPAIGNS})
    if broken:
        (root / "broken").mkdir()
        (root / "broken" / "furnace-20260302T000000Z.mcap").write_bytes(b"not a log\n" * 100)
        (root / "control" / "furnace-20260303T120000Z.mcap").write_bytes(b"\x89MCAP0\r\n")
        furnaces.append({"name": "broken", "logs": ["broken"], "campaigns": CAMPAIGNS})
    path = root / "fleet.yaml"
    path.write_text(yaml.safe_dump({"furnaces": furnaces, "refit": REFIT,
                                    "diagnose": DIAGNOSE}, sort_keys=False))
    return path
