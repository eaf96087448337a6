"""Slabs charged cold into the preheating zone: a furnace effect written as a plug-in.

Every `period_min` minutes a cold slab enters the preheating zone and, for `charge_min`
minutes, draws heat from it at `q_charge` °C/min. The zone already exchanges heat with the
outside air through its loss rate (e of eq. 6 on the paper's furnace), so the charge is
written as that air being colder by q_charge / loss while it lasts: a step down and a step
back up in the ambient input, which keeps the model linear and exactly solvable. The
charging end is the furnace's one zone losing heat to ambient; on a furnace with more than
one, the colder air would cool them all, so the effect refuses it.

Use it with any command: `furnace-model simulate|fit|diagnose|selfcheck --effects-from
examples/slab_charging/slab_charging.py`.
"""

import numpy as np

from furnace_model.effects import Drawn, Effect, Option, Tried
from furnace_model.simulation.lti import Drive
from furnace_model.simulation.network import terms
from furnace_model.simulation.parameters import Param


class DrawnSlabCharging(Drawn):
    """How the selfcheck draws it: a strength from `ranges`, the schedule at its defaults."""

    def draw(self, rng, form, duration_min, furnace):
        return self.effect(furnace=furnace), {"q_charge": self.uniform(rng, "q_charge")}


class SlabCharging(Effect):
    name = "slab_charging"
    physics = "cold slabs charged into the preheating zone draw heat from it at each charge"
    option_specs = {
        "period_min": Option(40.0, "number", lo=5.0, hi=600.0, doc="minutes between charges"),
        "charge_min": Option(8.0, "number", lo=1.0, hi=120.0, doc="minutes a charge draws heat"),
        "first_min": Option(20.0, "number", lo=0.0, hi=1e5, doc="the first charge"),
        "last_min": Option(6000.0, "number", lo=0.0, hi=1e6, doc="no charge after this"),
    }
    tried = Tried(null={"q_charge": 0.0})  # no heat drawn: no effect
    drawn = DrawnSlabCharging(ranges={"q_charge": (6.0, 14.0)})

    @classmethod
    def refusal(cls, furnace):
        if len(furnace.ambient) != 1:
            return "the charge is written through ambient, which needs one zone losing heat"
        return None

    @property
    def _loss(self) -> str:
        """The charging zone's loss rate to ambient (the paper's e)."""
        return next(t.name for t in terms(self.furnace) if t.kind == "loss")

    def _params(self):
        return (Param("q_charge", 5.0, 0.01, 100.0, unit="°C/min",
                      doc="preheating-zone cooling rate while a slab is charged"),)

    def transform_drive(self, theta, drive):
        o = self.options
        starts = np.arange(o["first_min"], o["last_min"], o["period_min"])
        times = np.concatenate([starts, starts + o["charge_min"]])
        sign = np.concatenate([-np.ones(starts.size), np.ones(starts.size)])
        colder = (theta["q_charge"] / theta[self._loss])[:, None]  # (P, 1) °C
        P, m = colder.shape[0], drive.du.shape[-1]
        du = np.zeros((P, times.size, m))
        du[:, :, self.u_air] = colder * sign
        s = drive.s
        if s.ndim == 1:
            s = np.concatenate([s, times])
        else:
            s = np.concatenate([s, np.broadcast_to(times, (s.shape[0], times.size))], axis=1)
        old = np.broadcast_to(drive.du, (P,) + drive.du.shape[1:])
        return Drive(drive.t0, drive.u0, s, np.concatenate([old, du], axis=1))
