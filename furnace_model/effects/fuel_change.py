"""Heat per burner changes at one instant: a fuel switch."""

from __future__ import annotations

import numpy as np

from ..simulation.lti import Drive
from ..simulation.parameters import Param
from .base import Effect, pinned, span, within
from .drawn import Drawn
from .tried import Tried

ONSET_STARTS = 8
"""Instants a fuel change is started from on a network other than eq. 11's, evenly over the
fitted records."""


class TriedFuelChange(Tried):
    def starts(self, effect, given, bounds):
        """On a network other than eq. 11's, instants across the fitted records: a switch that
        nothing places has a side valley wherever it meets a step of the record, and on a
        many-zone network the search around the baseline does not leave the one it starts
        in. On eq. 11's the search finds it from the one start."""
        if effect.furnace.paper_structure or "t_fuel" not in bounds:
            return []
        lo, hi = bounds["t_fuel"]
        return [{"t_fuel": lo + (i + 0.5) / ONSET_STARTS * (hi - lo)}
                for i in range(ONSET_STARTS)]

    def search_bounds(self, fit_data):
        """The switch lies within the fitted records (minutes from each record's start)."""
        return {"t_fuel": (min(float(e.t_min[0]) for e in fit_data),
                           max(float(e.t_min[-1]) for e in fit_data))}


class DrawnFuelChange(Drawn):
    def draw(self, rng, form, duration_min, furnace):
        return self.effect(furnace=furnace), {
            "t_fuel": round(self.uniform(rng, "t_fuel_frac") * duration_min),
            "fuel_ratio": self.uniform(rng, "fuel_ratio")}


class FuelChange(Effect):
    name = "fuel_change"
    physics = "heat per burner changes at one instant (a fuel switch, e.g. natural gas to biogas)"
    tried = TriedFuelChange(null={"fuel_ratio": 1.0})
    drawn = DrawnFuelChange(ranges={"t_fuel_frac": (0.3, 0.8), "fuel_ratio": (0.65, 0.9)})
    told = ("fuel_ratio", "t_fuel")
    drive_stage = 0  # at the burner: a transport delay then carries it to the zone

    @classmethod
    def found(cls, params, options):
        return cls.found_within(params, options, {})

    @classmethod
    def found_within(cls, params, options, ci95):
        """How much heat a burner gives now, and since when: a fuel to check with the plant."""
        if "fuel_ratio" not in params or "t_fuel" not in params:
            return ""  # a derived effect with parameters of its own
        ratio = params["fuel_ratio"]
        ci = ci95.get("fuel_ratio")
        since = f"from minute {within(params['t_fuel'], ci95.get('t_fuel'), '{:.0f}')}"
        if pinned(ratio - 1.0, None if ci is None else (ci[0] - 1.0, ci[1] - 1.0)):
            factor = ", ".join(w for w in (f"x{ratio:.2f}", span(ci, "x{:.2f}")) if w)
            return f"each burner gives {100.0 * (ratio - 1.0):+.0f}% heat ({factor}) {since}"
        return (f"each burner's heat changes {since}, by a share the record does not pin "
                f"down: {within(ratio, ci, 'x{:.2f}')}")

    def _params(self):
        return (
            Param("t_fuel", 1000.0, 0.0, 1e6, log=False, unit="min", doc="time of the switch"),
            Param("fuel_ratio", 0.8, 0.1, 3.0, unit="-", doc="heat per burner after / before"),
        )

    def transform_drive(self, theta, drive):
        tc, rho = theta["t_fuel"], theta["fuel_ratio"]
        P = tc.shape[0]
        s = np.broadcast_to(drive.s, (P, drive.s.shape[-1]))
        du = np.array(np.broadcast_to(drive.du, (P,) + drive.du.shape[1:]))
        u0 = np.broadcast_to(drive.u0, (P, drive.u0.shape[-1]))
        u_at = u0 + np.einsum("pk,pkm->pm", (s < tc[:, None]).astype(float), du)
        du[..., self.u_burners] *= np.where(s >= tc[:, None], rho[:, None], 1.0)[..., None]
        jump = np.zeros((P, 1, du.shape[-1]))
        jump[:, 0, self.u_burners] = (rho - 1.0)[:, None] * u_at[:, self.u_burners]
        return Drive(drive.t0, drive.u0, np.concatenate([s, tc[:, None]], axis=1),
                     np.concatenate([du, jump], axis=1))

    def reach_back_min(self, theta):
        """No reach: a switch already passed scales the input in force (the jump it adds falls
        before the start and is folded into that input), and one still to come reads the
        level in force at its instant from the inputs ahead."""
        return 0.0
