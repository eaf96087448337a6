"""Heat per burner changes with the number of burners firing (air supply, flue losses)."""

from __future__ import annotations

import numpy as np

from ..simulation.parameters import Param
from .base import Effect, Option
from .drawn import Drawn
from .tried import Tried

FORMS = ("linear", "power", "exponential", "quadratic")


class DrawnBurnerNonlinearity(Drawn):
    def draw(self, rng, form, duration_min, furnace):
        effect = self.effect(form="quadratic" if form == "other" else "linear", furnace=furnace)
        sign = -1.0 if rng.uniform() < 0.75 else 1.0
        return effect, {"k_nl": sign * self.uniform(rng, "k_nl")}


class BurnerNonlinearity(Effect):
    name = "burner_nonlinearity"
    physics = "heat per burner falls (or rises) as more burners fire"
    option_specs = {"form": Option("linear", "choice", choices=FORMS,
                                       doc="the curve of heat per burner against burners on")}
    # A burner curve fitted on few burners is extrapolated to the held-out data's many,
    # where the laws part (seen: 3 °C held out against a floor of 1 after a straight-line
    # fit to a power-law furnace): further laws, and a blend of two.
    tried = Tried(null={"k_nl": 0.0}, candidate_options={"form": "linear"},
                  further_laws=({"form": "power"}, {"form": "exponential"}), blends=True)
    drawn = DrawnBurnerNonlinearity(ranges={"k_nl": (0.01, 0.03)})
    """`k_nl` is drawn as a magnitude; its sign is drawn (mostly falling)."""

    def _params(self):
        return (Param("k_nl", -0.01, -0.035, 0.1, log=False, unit="1/burner",
                      doc="relative change of heat per burner for each further burner on"),)

    def transform_levels(self, theta, u):
        k = theta["k_nl"][:, None]
        # Burners firing, a modulated zone's rate counted as the burners it stands for.
        n = u[..., self.u_burners] @ self.furnace.burner_equivalents  # (P|1, J)
        # Curves of the same trend: a straight line, a power of n (steepest at few burners),
        # the same fraction lost (or gained) with each further burner, and the square of a
        # straight line of half the slope (between the first and the third).
        form = self.options["form"]
        if form == "linear":
            factor = 1.0 + k * n
        elif form == "power":
            factor = np.where(n > 0, np.maximum(n, 1e-9) ** (10.0 * k), 1.0)
        elif form == "exponential":
            factor = np.exp(k * n)
        else:
            factor = np.maximum(1.0 + 0.5 * k * n, 0.0) ** 2
        out = np.array(np.broadcast_to(u, (k.shape[0],) + u.shape[1:]))
        out[..., self.u_burners] *= factor[..., None]
        return out
