"""A thermocouple an online diagnosis finds drifting is left out of the refit's later windows:
which windows, which zones may lose one, the state that carries it over a restart, and the
config that trusts one again."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from furnace_daq.daqconfig import DiagnosisConfig, RefitConfig, parse_config
from furnace_daq.logmeta import plain, refit_config
from furnace_daq.refit import RefitChain, Window
from furnace_model.config import Node
from furnace_model.errors import ConfigError
from furnace_model.experiment import Experiment
from furnace_model.simulation.furnace import PAPER

ROOT = Path(__file__).resolve().parents[1]
HOUR_NS = 3600 * 10**9


def window(k: int, n: int = 30) -> Window:
    """The k-th hour: soak_1 reads 10 °C above soak_2, the other pairs agree."""
    rng = np.random.default_rng(k)
    tc = np.tile([905.0, 895.0, 800.0, 800.0, 600.0, 600.0], (n, 1)) + rng.normal(0, 1, (n, 6))
    exp = Experiment(f"w{k}", np.arange(n, dtype=float) * 2.0, tc, np.ones((n, 3)),
                     np.full(n, 30.0), furnace=PAPER)
    return Window(k * HOUR_NS, (k + 1) * HOUR_NS, exp, n, n, 1)


def chain(**diagnosis) -> RefitChain:
    return RefitChain(RefitConfig(diagnosis=DiagnosisConfig(**diagnosis)), furnace=PAPER)


def test_windows_that_end_from_the_instant_on_leave_the_thermocouple_out():
    c = chain()
    assert c.set_aside_from("soak_1", 3 * HOUR_NS, 0)
    early, late = window(1), window(2)  # ending at 2 h and at 3 h
    assert c.trusted(early) is early
    at = c.trusted(late)
    assert at.set_aside == ("soak_1",) and at.explained_until == 0
    raw = late.experiment
    assert np.allclose(at.experiment.zone_temp[:, 0], raw.tc[:, 1])  # soak_2 alone
    assert np.allclose(at.experiment.zone_temp[:, 1:], raw.zone_temp[:, 1:])
    assert np.isfinite(raw.tc[:, 0]).all()  # the window as cut is left as it was


def test_a_zones_last_thermocouple_and_a_trusted_one_are_never_set_aside():
    c = chain(trusted=("heat_2",))
    assert c.set_aside_from("soak_1", 0, 0)
    assert not c.set_aside_from("soak_2", 0, 0)  # the soaking zone would read nothing
    assert not c.set_aside_from("soak_1", 0, 0)  # already
    assert not c.set_aside_from("heat_2", 0, 0)  # trusted
    assert not c.set_aside_from("roof_9", 0, 0)  # not a thermocouple of the furnace
    assert c.set_aside == {"soak_1": (0, 0)}


def test_the_state_carries_it_over_a_restart_unless_the_config_trusts_it_again():
    c = chain()
    c.set_aside_from("soak_1", 5 * HOUR_NS, 0)
    state = c.state()
    again = chain()
    again.restore(state)
    assert again.set_aside == {"soak_1": (5 * HOUR_NS, 0)}
    replaced = chain(trusted=("soak_1",))
    replaced.restore(state)
    assert replaced.set_aside == {}
    older = {k: v for k, v in state.items() if k != "set_aside"}  # a state from before
    again.restore(older)
    assert again.set_aside == {}


def parse(diagnosis: object):
    doc = yaml.safe_load((ROOT / "config" / "gateway.yaml").read_text())
    doc["refit"]["diagnosis"] = diagnosis
    return parse_config(Node(doc, "daq.yaml")).refit.diagnosis


def test_the_config_names_trusted_thermocouples_of_its_furnace():
    d = parse({"set_aside": False, "trusted": ["soak_1"]})
    assert d == DiagnosisConfig(set_aside=False, trusted=("soak_1",))
    with pytest.raises(ConfigError, match=r"refit\.diagnosis\.trusted\[0\]: must be one of"):
        parse({"trusted": ["soak_9"]})
    # the recorded settings give it back; a log from before the setting was refitted with
    # every thermocouple, and its replay is too
    assert refit_config(plain(RefitConfig(diagnosis=d))).diagnosis == d
    old = plain(RefitConfig(diagnosis=DiagnosisConfig()))
    del old["diagnosis"]["set_aside"], old["diagnosis"]["trusted"]
    assert refit_config(old).diagnosis.set_aside is False
