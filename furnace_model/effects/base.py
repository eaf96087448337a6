"""What an effect is: a term added to the paper's model, with everything the rest of the
package needs to know about it in one class.

The same object serves the plant simulator (effect on, parameters from a scenario) and the
diagnosis (effect on, parameters fitted), so the physics lives in the effect's class and
nowhere else. Its physics hooks may

- add states and change the matrices of x' = A x + B u (`extend`),
- reshape the input levels before they become steps (`transform_levels`),
- add, scale or shift input steps per parameter set (`transform_drive`), saying how far
  back in time the inputs then act (`reach_back_min`),
- add a term that is not linear in the state (`nonlinear_rhs`; radiation),
- offset individual thermocouples (`sensor_offsets`).

Beside the physics and its words (`physics`), a class has two optional parts, each with a
default: how the diagnosis tries it (`tried`, a `tried.Tried`: the strengths that vanish
with it, its first form and further laws, where the search starts) and how the selfcheck
draws it at random in the candidate's form and in another one (`drawn`, a `drawn.Drawn`).
The diagnosis and the selfcheck ask the part, so that the effect says what it is and the
parts say how it is tried and drawn. A class that keeps those attributes on itself
(`null`, `ranges`, `draw`, ...), as the plug-in API also allows, gets parts made from them
(`legacy`). The diagnosis, the plant simulator, the scenario loader and the selfcheck loop
over the registered effects (`registry.EFFECTS`) and never name one: a furnace's own
physics is one class in one file, ours or the user's.

Options (which zone, which sensor, which law) are chosen, not fitted, and declared as
`Option`s, which the scenario loader reads from YAML; parameters are fitted. Options that
give a formulation different from the diagnosis's candidate (a second-order lag, a
radiation law that is no power of T) exist so that the diagnosis can be tested on physics
that is not its own.

An effect knows the furnace it extends (`Effect(furnace=...)`, always named): its zone and
sensor options range over that furnace's zones and thermocouples (`specs`), and its physics
reads the input channels as one burner count per zone, in the furnace's zone order, then
ambient temperature (`u_burners`, `u_air`). Where an effect's forms differ on eq. 11's
network from a larger one, it asks the description (`Furnace.paper_structure`), so that a
three-zone chain named otherwise behaves as the paper's does. An effect that cannot apply
to a furnace says why (`refusal`), and making it there is a ValueError with that reason.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..simulation.furnace import PAPER, Furnace
from ..simulation.lti import Drive
from ..simulation.parameters import Param
from .drawn import Drawn
from .legacy import old_part
from .part import Part
from .tried import Clues, Trial, Tried

__all__ = ["KELVIN", "Clues", "Drawn", "Effect", "Option", "Theta", "Trial", "Tried"]

KELVIN = 273.15

Theta = dict[str, np.ndarray]
"""Parameter values by name, each an array over a batch of P parameter sets."""


@dataclass(frozen=True)
class Option:
    """A chosen (not fitted) setting of an effect, declared so that a scenario file can set it
    and be checked: `kind` is "number" or "integer" (within lo..hi), "choice" (one of
    `choices`), or "choices" (a list of 1..len(choices) distinct ones, kept in their order)."""

    default: Any
    kind: str
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] = ()
    doc: str = ""


class Effect:
    name: ClassVar[str]
    """Its name in scenarios, the CLI, and the diagnosis's JSON."""
    physics: ClassVar[str]
    """What it is, in a plant engineer's words: the verdict says it."""
    linear: ClassVar[bool] = True
    """False when `nonlinear_rhs` is used: the model is integrated, not solved in closed form."""
    option_specs: ClassVar[dict[str, Option]] = {}
    drive_stage: ClassVar[int] = 0
    """Order among effects that transform the drive: lower acts first (nearer the burner)."""
    tried: ClassVar[Tried] = Tried()
    """How the diagnosis tries it; by default in its first form from the fitted baseline."""
    drawn: ClassVar[Drawn] = Drawn()
    """How the selfcheck draws it; by default it cannot."""
    told: ClassVar[tuple[str, ...]] = ()
    """The parameters `found_within` gives with their 95% intervals: a user acts on them, so
    the diagnosis profiles their intervals on the model it keeps (an onset and the slope or
    step it trades with are far from the quadratic a linearised interval assumes)."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Bind each part to the class; one the class does not declare is made from the
        attributes it has of the API before the parts (`legacy.old_part`), else inherited."""
        super().__init_subclass__(**kwargs)
        for slot in ("tried", "drawn"):
            part = vars(cls).get(slot)
            if part is None:
                part = old_part(cls, slot)
            if part is None:
                part = getattr(cls, slot)
            if isinstance(part, Part):  # anything else is refused by plugins.check
                setattr(cls, slot, part.bound(cls))

    def __init__(self, *, furnace: Furnace | None = None, **options: Any):
        if furnace is None:  # a plug-in that names no furnace knows only the paper's
            warnings.warn(f"{type(self).__name__}() without a furnace is the paper's furnace's "
                          "effect; pass furnace=", DeprecationWarning, stacklevel=2)
            furnace = PAPER
        why = self.refusal(furnace)
        if why:
            raise ValueError(f"{self.name} does not apply to furnace '{furnace.name}': {why}")
        self.furnace = furnace
        specs = self.specs(furnace)
        self.options = {k: o.default for k, o in specs.items()}
        unknown = set(options) - set(self.options)
        if unknown:
            raise ValueError(f"{self.name}: unknown option(s) {sorted(unknown)}")
        self.options.update(options)
        self.params: tuple[Param, ...] = self._params()

    # -- the furnace ---------------------------------------------------------------------------
    @classmethod
    def refusal(cls, furnace: Furnace) -> str | None:
        """Why the effect cannot extend this furnace, in words; None when it can."""
        return None

    @classmethod
    def specs(cls, furnace: Furnace) -> dict[str, Option]:
        """The options on this furnace: zone and sensor choices are its zones and sensors."""
        return cls.option_specs

    @classmethod
    def physics_for(cls, furnace: Furnace) -> str:
        """`physics` in this furnace's words."""
        return cls.physics

    @classmethod
    def found(cls, params: dict[str, float], options: dict[str, Any]) -> str:
        """What the fitted values say the plant has, in words, where a user acts on them (a
        thermocouple to replace, from when); empty where the effect's name says it all."""
        return ""

    @classmethod
    def found_within(cls, params: dict[str, float], options: dict[str, Any],
                     ci95: dict[str, tuple[float, float]]) -> str:
        """`found` with the fitted values' 95% intervals, where the verdict has them: a
        user who replaces a thermocouple or calls the fuel supplier acts on how sure the
        numbers are. An effect without its own says what `found` says."""
        return cls.found(params, options)

    @property
    def n_zones(self) -> int:
        return self.furnace.n_zones

    @property
    def u_burners(self) -> slice:
        """The input channels of the zones' heat inputs, one per zone (burners on, or a
        rate: `Furnace.burner_equivalents` reads a rate in burners)."""
        return slice(0, self.furnace.n_zones)

    @property
    def u_air(self) -> int:
        return self.furnace.n_zones

    @property
    def n_inputs(self) -> int:
        """Heat inputs, ambient, then the furnace's measured disturbances."""
        return self.furnace.n_inputs

    def __repr__(self) -> str:
        opts = ", ".join(f"{k}={v!r}" for k, v in self.options.items())
        return f"{type(self).__name__}({opts})"

    def _params(self) -> tuple[Param, ...]:
        raise NotImplementedError

    # -- physics -------------------------------------------------------------------------------
    @property
    def state_zones(self) -> tuple[int, ...]:
        """States added by the effect, as the zone each starts at."""
        return ()

    def extend(self, A: np.ndarray, B: np.ndarray, C: np.ndarray, theta: Theta, first: int) -> None:
        """Change A (P,n,n), B (P,n,m) and C (P,zones,n) in place; own states start at
        `first`."""

    def transform_levels(self, theta: Theta, u: np.ndarray) -> np.ndarray:
        """Input levels (P|1, J, m) -> levels; for effects that act on the burner count."""
        return u

    def transform_drive(self, theta: Theta, drive: Drive) -> Drive:
        return drive

    def reach_back_min(self, theta: Theta) -> float:
        """How long before an instant the inputs still act after it, other than through the
        state and the input then in force (a transport delay's length, in minutes). A plant
        stepped one control period at a time simulates each period from the inputs this far
        back only, so that a long run costs its periods, not their square. An effect with a
        `transform_drive` of its own may move steps in time: unless it says how far, the
        whole past is kept (inf)."""
        if type(self).transform_drive is Effect.transform_drive:
            return 0.0
        return float("inf")

    def nonlinear_rhs(self, theta: Theta, x: np.ndarray, A: np.ndarray, B: np.ndarray,
                      u: np.ndarray) -> np.ndarray:
        """Extra dx/dt (P, n) for state x (P, n) and input u (P, m)."""
        return np.zeros_like(x)

    def nonlinear_rhs_over(self, theta: Theta, X: np.ndarray, A: np.ndarray, B: np.ndarray,
                           U: np.ndarray) -> np.ndarray:
        """Extra dx/dt (P, S, n) at S states X (P, S, n) of each parameter set under the
        inputs U (P, S, m): `nonlinear_rhs` row by row, each set's parameters and matrices
        repeated S times. The simulators call this; an effect that broadcasts over the S
        states itself (radiation) saves those copies, which dominate a nonlinear fit."""
        P, S, n = X.shape
        flat = self.nonlinear_rhs({k: np.repeat(v, S) for k, v in theta.items()},
                                  X.reshape(P * S, n), np.repeat(A, S, axis=0),
                                  np.repeat(B, S, axis=0),
                                  np.broadcast_to(U, (P, S, U.shape[-1])).reshape(P * S, -1))
        return flat.reshape(P, S, n)

    def sensor_offsets(self, theta: Theta, t: np.ndarray) -> np.ndarray | None:
        """Additive error of each thermocouple (P, N, thermocouples), or None."""
        return None

    def nonlinear_off(self, theta: Theta) -> np.ndarray:
        """Parameter sets (P,) whose `nonlinear_rhs` is zero at every state: the simulator
        takes those in closed form (a fit that drives the effect to its null value keeps
        evaluating it there, and its Jacobian's other columns stay there too)."""
        return np.zeros(next(iter(theta.values())).shape[0], dtype=bool)

    # -- scenarios -----------------------------------------------------------------------------
    @classmethod
    def options_from_params(cls, given: set[str]) -> dict[str, Any]:
        """Options implied by which parameters a scenario sets (a loss rate named for a zone
        says which zones lose heat), where the options themselves are not given."""
        return {}

    # -- the selfcheck ------------------------------------------------------------------------
    @classmethod
    def uniform(cls, rng: np.random.Generator, key: str) -> float:
        """A value from `drawn.ranges[key]`: for a `draw` written on the class itself."""
        return cls.drawn.uniform(rng, key)


PINNED_HALF_WIDTH = 0.5
"""A fitted value is pinned down by the record when its 95% interval's half-width is at most
this share of the value: wider, the verdict gives the interval instead of the number as
found (a drift's rate from an hour of it trades with its onset)."""


def within(value: float, ci: tuple[float, float] | None, fmt: str, unit: str = "") -> str:
    """value in fmt, with its 95% interval where it has one: '-1.40 °C/h (95% interval -1.62
    to -1.18)'."""
    said = f"{fmt.format(value)}{unit}"
    return f"{said} ({span(ci, fmt)})" if span(ci, fmt) else said


def span(ci: tuple[float, float] | None, fmt: str) -> str:
    """'95% interval a to b' in fmt; empty without a finite interval."""
    if ci is None or not all(np.isfinite(ci)):
        return ""
    return f"95% interval {fmt.format(ci[0])} to {fmt.format(ci[1])}"


def pinned(value: float, ci: tuple[float, float] | None) -> bool:
    """Whether the record pins the value down (`PINNED_HALF_WIDTH`); without an interval the
    verdict cannot say otherwise."""
    if ci is None or not all(np.isfinite(ci)):
        return True
    return (ci[1] - ci[0]) / 2.0 <= PINNED_HALF_WIDTH * abs(value)
