"""Heat exchange by radiation: the fourth power of absolute temperature, not linear."""

from __future__ import annotations

import numpy as np

from ..simulation.parameters import Param
from .base import KELVIN, Effect, Option
from .drawn import Drawn
from .tried import Clues, Trial, Tried


class DrawnRadiation(Drawn):
    def draw(self, rng, form, duration_min, furnace):
        effect = self.effect(furnace=furnace)
        if form == "other":
            # No other exponent: the candidate fits its own. An emissivity that rises or
            # falls with temperature is no power law at all (its local exponent at the
            # reference is 4 + s); another reference temperature alone is no other law (the
            # fitted exchange rates absorb it).
            slope = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.4, 0.8))
            effect = self.effect(emissivity_slope=slope,
                                 t_ref_c=float(rng.uniform(600.0, 1100.0)), furnace=furnace)
        return effect, {"rad_share": self.uniform(rng, "rad_share")}


class TriedRadiation(Tried):
    def trial(self, clues: Clues) -> Trial:
        """The law referred to the fitted records' own mean temperature: there the share
        changes only the law's curvature, not its slope, so that it does not trade against
        the exchange rates. Referred to a furnace's 900 °C, a record about 20 °C (a heated
        room) puts a slope of (293/1173)^3 at its operating point: every exchange shrinks
        64-fold as the share goes to 1 and its rate must grow as much, a curved valley the
        polish crawls along to its iteration limit. The same laws are reachable from any
        reference (the rates absorb it), so this changes the path, not the optimum."""
        temps = np.concatenate([e.zone_temp.ravel() for e in clues.fit_data])
        temps = temps[np.isfinite(temps)]
        options = dict(self.candidate_for(clues.furnace))
        if temps.size:
            options["t_ref_c"] = float(np.round(np.mean(temps)))
        return Trial(options)

    def law_options(self, law: dict, first: dict) -> dict:
        return {**law, "t_ref_c": first["t_ref_c"]} if "t_ref_c" in first else dict(law)


class Radiation(Effect):
    name = "radiation"
    physics = "heat exchange grows with the fourth power of absolute temperature, not linearly"
    linear = False
    option_specs = {
        "exponent": Option(4.0, "number", lo=1.5, hi=6.0,
                           doc="power of absolute temperature (None: fitted)"),
        "t_ref_c": Option(900.0, "number", lo=-50.0, hi=2000.0,
                          doc="where the law's slope equals the paper's linear exchange "
                              "(the diagnosis: the fitted records' mean temperature)"),
        "emissivity_slope": Option(0.0, "number", lo=-1.0, hi=1.0,
                                   doc="emissivity change with temperature: no power law"),
    }
    # A furnace's effective exponent depends on its gas and walls, not only on
    # Stefan-Boltzmann: fitted too, as a further law.
    tried = TriedRadiation(null={"rad_share": 0.0}, candidate_options={"exponent": 4.0},
                           further_laws=({"exponent": None},), blends=True)
    drawn = DrawnRadiation(ranges={"rad_share": (0.2, 0.8)})

    def _params(self):
        share = Param("rad_share", 0.5, 0.0, 1.0, log=False, unit="-",
                      doc="share of each exchange that is radiative at the reference temperature")
        if self.options["exponent"] is not None:
            return (share,)
        return (share, Param("rad_exponent", 4.0, 1.5, 6.0, log=False, unit="-",
                             doc="effective exponent: a furnace's gas and walls set it, not "
                                 "only Stefan-Boltzmann"))

    def nonlinear_off(self, theta):
        return theta["rad_share"] == 0.0

    def nonlinear_rhs(self, theta, x, A, B, u):
        return self.nonlinear_rhs_over(theta, x[:, None], A, B, u[:, None])[:, 0]

    def nonlinear_rhs_over(self, theta, X, A, B, U):
        # Each linear exchange k (Tj - Ti) becomes k [(1-w)(Tj - Ti) + w (rho(Tj) - rho(Ti))]
        # with rho(T) = T_K^p / (p T_ref^(p-1)), whose slope is 1 at T_ref: the paper's model is
        # the linearisation of this one at the reference temperature. An emissivity that
        # changes with temperature, 1 + s (T_K / T_ref - 1), makes the law other than a power
        # of T (the furnace's own law, for the diagnosis's robustness check).
        # Worked zone by zone over the S states (P, zones, S): with the zones innermost, every
        # product of a relaxation's thousands of nodes would loop over two or three numbers.
        p, tref = self.options["exponent"], self.options["t_ref_c"] + KELVIN
        s = self.options["emissivity_slope"]
        if p is None:
            p = theta["rad_exponent"][:, None, None]

        def excess(T):
            ratio = np.maximum(T + KELVIN, 1.0) / tref
            if np.ndim(p) == 0 and p == 4.0:  # the hot path: squares, not a power
                law = ratio * ratio
                law *= law
            else:
                law = ratio ** p
            if s:
                law *= np.maximum(1.0 + s * (ratio - 1.0), 0.0)
            return tref / (p + s) * law - T

        w = theta["rad_share"][:, None, None]
        nz = self.n_zones
        r = excess(np.swapaxes(X[..., :nz], 1, 2).copy())  # (P, zones, S)
        r_air = excess(U[:, None, :, self.u_air])  # (P, 1, S)
        K = A[:, :nz, :nz] * (1.0 - np.eye(nz))
        k_air = B[:, :nz, self.u_air, None]
        moved = K @ r - (K.sum(axis=2)[:, :, None] + k_air) * r + k_air * r_air
        dx = np.zeros(X.shape)
        dx[..., :nz] = np.swapaxes(w * moved, 1, 2)
        return dx
