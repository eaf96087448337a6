"""Burner heat reaches the zone after a transport delay."""

from __future__ import annotations

import numpy as np

from ..simulation.lti import Drive
from ..simulation.parameters import Param
from .base import Effect
from .drawn import Drawn
from .tried import Tried


class DrawnDeadTime(Drawn):
    def draw(self, rng, form, duration_min, furnace):
        return self.effect(furnace=furnace), {"theta_dead": self.uniform(rng, "theta_dead")}


class DeadTime(Effect):
    name = "dead_time"
    physics = "burner heat reaches the zone only after a transport delay"
    tried = Tried(null={"theta_dead": 0.0})
    drawn = DrawnDeadTime(ranges={"theta_dead": (5.0, 45.0)})
    drive_stage = 1  # carries to the zone whatever the burners give, a fuel switch included

    def _params(self):
        return (Param("theta_dead", 5.0, 0.01, 240.0, unit="min", doc="transport delay"),)

    def transform_drive(self, theta, drive):
        P = theta["theta_dead"].shape[0]
        s = np.broadcast_to(drive.s, (P, drive.s.shape[-1]))
        du = np.broadcast_to(drive.du, (P,) + drive.du.shape[1:])
        burners = np.zeros(self.n_inputs)
        burners[self.u_burners] = 1.0
        s_new = np.concatenate([s + theta["theta_dead"][:, None], s], axis=1)
        du_new = np.concatenate([du * burners, du * (1.0 - burners)], axis=1)
        return Drive(drive.t0, drive.u0, s_new, du_new)

    def reach_back_min(self, theta):
        """The burners fired a dead time ago are still on their way to the zone."""
        return float(np.max(theta["theta_dead"]))
