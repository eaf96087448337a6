"""What an effect is: a term added to the paper's model, with everything the rest of the
package needs to know about it in one class.

The same object serves the plant simulator (effect on, parameters from a scenario) and the
diagnosis (effect on, parameters fitted), so the physics lives in the effect's class and
nowhere else. Its physics hooks may

- add states and change the matrices of x' = A x + B u (`extend`),
- reshape the input levels before they become steps (`transform_levels`),
- add, scale or shift input steps per parameter set (`transform_drive`),
- add a term that is not linear in the state (`nonlinear_rhs`; radiation),
- offset individual thermocouples (`sensor_offsets`).

Beside the physics, a class says how the diagnosis tries it (`null`, `candidate_options`,
`further_laws`, `blends`, `trial`, `search_bounds`), how the selfcheck draws it at random
in the candidate's form and in another one (`ranges`, `draw`), and its words (`physics`).
The diagnosis, the plant simulator, the scenario loader and the selfcheck loop over the
registered effects (`registry.EFFECTS`) and never name one: a furnace's own physics is one
class in one file, ours or the user's.

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
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from ..simulation.furnace import PAPER, Furnace
from ..simulation.lti import Drive
from ..simulation.parameters import Param

if TYPE_CHECKING:
    from ..experiment import Experiment

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


@dataclass
class Clues:
    """What the diagnosis has read off the data before it tries the candidates: an effect
    may start its search from them (a drifting thermocouple's onset) or choose its form."""

    fit_data: list[Experiment]
    records: list[Experiment]
    """The fitted records, then the held-out ones."""
    faults: list = field(default_factory=list)
    """Thermocouples found departing from their partner (residuals.SensorFault)."""
    bent: bool = False
    """The baseline fits the fitted data worse than their noise allows: it has bent to
    absorb something, and a warm start from it may sit in a side valley."""
    baseline_on: Callable[[list[Experiment]], dict[str, float]] | None = None
    """The baseline fitted on other records (parts of these), with what they determine."""
    residuals: list[np.ndarray] = field(default_factory=list)
    """The baseline's zone residuals on `records` (N, zones) each."""
    furnace: Furnace = field(kw_only=True)


@dataclass
class Trial:
    """How the diagnosis tries an effect: in which form, and from where."""

    options: dict[str, Any] = field(default_factory=dict)
    start: dict[str, float] = field(default_factory=dict)
    """Starting values of parameters, over the fitted baseline's."""
    from_baseline: bool = True
    """False: start from `start` alone, the rest of the parameters searched."""


class Effect:
    name: ClassVar[str]
    """Its name in scenarios, the CLI, and the diagnosis's JSON."""
    physics: ClassVar[str]
    """What it is, in a plant engineer's words: the verdict says it."""
    linear: ClassVar[bool] = True
    """False when `nonlinear_rhs` is used: the model is integrated, not solved in closed form."""
    option_specs: ClassVar[dict[str, Option]] = {}
    null: ClassVar[dict[str, float]] = {}
    """Strength parameters and the value at which the effect vanishes (NaN: the parameter
    must merely be determined, either because the baseline is not nested in the extension
    or because it is felt only where the effect is). A candidate earns credit only when one
    of them is determined away from its null."""
    candidate_options: ClassVar[dict[str, Any]] = {}
    """The diagnosis's own formulation (its first law)."""
    further_laws: ClassVar[tuple[dict[str, Any], ...]] = ()
    """Other forms the diagnosis fits when the first law removes part of the gap."""
    zone_affine: ClassVar[bool] = False
    """Its parameters enter the zones' equations linearly and it adds no state, no input
    change and no sensor error: the integrated equations' least squares (equationerror)
    estimate them with the network's."""
    one_place_at_a_time: ClassVar[bool] = False
    """On any network but eq. 11's, the further laws put the effect in one place at a time
    (one zone of its `zones` option, unless `laws_for` says otherwise) and are fitted even
    when the first law, the effect everywhere at once, does not help: on a network of many
    zones an effect in one of them may leave the candidate no better than the baseline."""
    blends: ClassVar[bool] = False
    """The further laws lie on one scale, so that a blend of two stands for a law between."""
    drive_stage: ClassVar[int] = 0
    """Order among effects that transform the drive: lower acts first (nearer the burner)."""
    ranges: ClassVar[dict[str, tuple[float, float]]] = {}
    """Ranges the selfcheck draws strengths and timings from (`draw`)."""

    def __init__(self, *, furnace: Furnace | None = None, **options: Any):
        if furnace is None:  # a plug-in written when every effect was of the paper's furnace
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
    def candidate_for(cls, furnace: Furnace) -> dict[str, Any]:
        """The diagnosis's own formulation on this furnace (`candidate_options`)."""
        return dict(cls.candidate_options)

    @classmethod
    def laws_for(cls, furnace: Furnace) -> tuple[dict[str, Any], ...]:
        """The further laws on this furnace: `further_laws`, or with `one_place_at_a_time`
        on a network other than eq. 11's, each zone of the `zones` option's default."""
        if furnace.paper_structure or not cls.one_place_at_a_time:
            return cls.further_laws
        return tuple({"zones": (z,)} for z in cls.specs(furnace)["zones"].default)

    @classmethod
    def laws_always(cls, furnace: Furnace) -> bool:
        """Whether the further laws are fitted even when the first law does not help: where
        each puts the effect somewhere else (one zone's wall, one thermocouple), not in
        another form, the first law need not show it at all."""
        return cls.one_place_at_a_time and not furnace.paper_structure

    @classmethod
    def physics_for(cls, furnace: Furnace) -> str:
        """`physics` in this furnace's words."""
        return cls.physics

    def starts(self, given: dict[str, float], bounds: dict[str, tuple[float, float]]
               ) -> list[dict[str, float]]:
        """Further starts of this form's own parameters where the data leave them ambiguous
        (an onset nothing places has a side valley wherever it meets a step of the record);
        `given`: the start the diagnosis has (what the data placed, or a fit's values),
        `bounds`: the search box. The candidate is polished from each too and the best fit
        kept."""
        return []

    @property
    def nulls(self) -> dict[str, float]:
        """`null` for this effect's own parameters (their names may follow its zones)."""
        return type(self).null

    @property
    def n_zones(self) -> int:
        return self.furnace.n_zones

    @property
    def u_burners(self) -> slice:
        """The input channels of the burner counts, one per zone."""
        return slice(0, self.furnace.n_zones)

    @property
    def u_air(self) -> int:
        return self.furnace.n_zones

    @property
    def n_inputs(self) -> int:
        return self.furnace.n_zones + 1

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

    def nonlinear_rhs(self, theta: Theta, x: np.ndarray, A: np.ndarray, B: np.ndarray,
                      u: np.ndarray) -> np.ndarray:
        """Extra dx/dt (P, n) for state x (P, n) and input u (P, m)."""
        return np.zeros_like(x)

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

    # -- diagnosis -----------------------------------------------------------------------------
    @classmethod
    def trial(cls, clues: Clues) -> Trial:
        """How the diagnosis tries the effect on these data."""
        return Trial(cls.candidate_for(clues.furnace))

    @classmethod
    def search_bounds(cls, fit_data: Sequence[Experiment]) -> dict[str, tuple[float, float]]:
        """Search boxes narrower than the parameters' own, where the data set them (a time
        within the fitted records, not 0-1e6 min)."""
        return {}

    # -- selfcheck -----------------------------------------------------------------------------
    @classmethod
    def draw(cls, rng: np.random.Generator, form: str, duration_min: float,
             furnace: Furnace) -> tuple[Effect, dict[str, float]]:
        """A furnace with the effect, at random: the effect (in the diagnosis's form, or with
        form "other" in a formulation its candidate does not use) and its parameter values,
        drawn from `ranges`; times within a heat-up of `duration_min`."""
        raise NotImplementedError(f"{cls.name} has no random draw for the selfcheck")

    @classmethod
    def check_furnace(cls, furnace: Furnace) -> Furnace:
        """The furnace the selfcheck diagnoses this effect on, given the one it checks: the
        same, unless the effect is the other side of a convention the description fixes
        (zone_burners on a furnace whose burners heat their own zones)."""
        return furnace

    @classmethod
    def uniform(cls, rng: np.random.Generator, key: str) -> float:
        lo, hi = cls.ranges[key]
        return float(rng.uniform(lo, hi))
