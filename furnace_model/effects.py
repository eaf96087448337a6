"""The unmodelled effects of CONTRACTS.md section 4, each written once.

An effect is a term added to the paper's model. The same object serves the plant simulator
(effect on, parameters from a scenario) and the diagnosis (effect on, parameters fitted), so
the physics lives here and nowhere else. An effect may

- add states and change the matrices of x' = A x + B u (`extend`),
- reshape the input levels before they become steps (`transform_levels`),
- add, scale or shift input steps per parameter set (`transform_drive`),
- add a term that is not linear in the state (`nonlinear_rhs`; radiation only),
- offset individual thermocouples (`sensor_offsets`).

Options (which zone, which sensor, which law) are chosen, not fitted; parameters are fitted
(radiation's exponent either: None leaves it to the fit).
Options that give a formulation different from the diagnosis's candidate (a second-order
lag, a radiation law that is no power of T, a burner curve of another shape, a wall of two
layers) exist so that the diagnosis can be tested on physics that is not its own.

Input channels: burners on in soak, heat, preheat (counts), then ambient temperature.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from . import SENSORS, ZONES
from .config import Node
from .lti import Drive
from .parameters import Param

U_BURNERS = slice(0, 3)
U_AIR = 3
N_INPUTS = 4
KELVIN = 273.15

Theta = dict[str, np.ndarray]
"""Parameter values by name, each an array over a batch of P parameter sets."""


class Effect:
    name: ClassVar[str]
    physics: ClassVar[str]
    linear: ClassVar[bool] = True
    option_kinds: ClassVar[dict[str, tuple]] = {}
    """Option name -> (default, checker) where checker reads the option from a YAML node."""

    def __init__(self, **options):
        self.options = {k: d for k, (d, _) in self.option_kinds.items()}
        unknown = set(options) - set(self.options)
        if unknown:
            raise ValueError(f"{self.name}: unknown option(s) {sorted(unknown)}")
        self.options.update(options)
        self.params: tuple[Param, ...] = self._params()

    def __repr__(self) -> str:
        opts = ", ".join(f"{k}={v!r}" for k, v in self.options.items())
        return f"{type(self).__name__}({opts})"

    def _params(self) -> tuple[Param, ...]:
        raise NotImplementedError

    # state added by the effect, and the zone whose temperature each such state starts at
    @property
    def state_zones(self) -> tuple[int, ...]:
        return ()

    def extend(self, A: np.ndarray, B: np.ndarray, C: np.ndarray, theta: Theta, first: int) -> None:
        """Change A (P,n,n), B (P,n,m) and C (P,3,n) in place; own states start at `first`."""

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
        """Additive error of each thermocouple (P, N, 6), or None."""
        return None

    def nonlinear_off(self, theta: Theta) -> np.ndarray:
        """Parameter sets (P,) whose `nonlinear_rhs` is zero at every state: the simulator
        takes those in closed form (a fit that drives the effect to its null value keeps
        evaluating it there, and its Jacobian's other columns stay there too)."""
        return np.zeros(next(iter(theta.values())).shape[0], dtype=bool)

    @classmethod
    def from_config(cls, node: Node) -> tuple[Effect, dict[str, float]]:
        """Read `effects.<name>` of a scenario: options and parameter values."""
        node.mapping()
        options = {}
        for key, (_default, read) in cls.option_kinds.items():
            if node.has(key):
                options[key] = read(node.child(key))
        effect = cls(**cls._infer_options(node, options))
        allowed = {"enabled", *cls.option_kinds, *(p.name for p in effect.params)}
        node.mapping(allowed)
        values = {}
        for p in effect.params:
            values[p.name] = node.get_number(p.name, p.default, lo=p.lo, hi=p.hi)
        return effect, values

    @classmethod
    def _infer_options(cls, node: Node, options: dict) -> dict:
        return options


def _zone_list(node: Node) -> tuple[int, ...]:
    names = [n.string(ZONES) for n in node.elements(min_len=1, max_len=3)]
    return tuple(sorted({ZONES.index(n) for n in names}))


class ZoneBurners(Effect):
    name = "zone_burners"
    physics = ("heating- and preheating-zone burners heat their own zone, with their own heat "
               "per burner, instead of counting as zone-1 input")

    def _params(self):
        return (
            Param("f_heat", 0.15, 1e-4, 10.0, unit="°C/min per burner",
                  doc="heating-zone rise rate per heating-zone burner on"),
            Param("f_preheat", 0.15, 1e-4, 10.0, unit="°C/min per burner",
                  doc="preheating-zone rise rate per preheating-zone burner on"),
        )

    def extend(self, A, B, C, theta, first):
        B[:, 0, 1:3] = 0.0
        B[:, 1, 1] = theta["f_heat"]
        B[:, 2, 2] = theta["f_preheat"]


class ZoneLosses(Effect):
    name = "zone_losses"
    physics = "a zone besides preheating loses heat to ambient through its walls"
    option_kinds = {"zones": (("soak", "heat"), lambda n: tuple(ZONES[i] for i in _zone_list(n)))}

    def _params(self):
        bad = [z for z in self.options["zones"] if z not in ("soak", "heat")]
        if bad:
            raise ValueError(f"zone_losses applies to soak and heat, not {bad}")
        return tuple(Param(f"g_{z}", 0.002, 1e-6, 1.0, doc=f"{z}-zone wall loss rate to ambient")
                     for z in self.options["zones"])

    @classmethod
    def _infer_options(cls, node, options):
        if "zones" not in options:
            given = tuple(z for z in ("soak", "heat") if node.has(f"g_{z}"))
            if given:
                options["zones"] = given
        return options

    def extend(self, A, B, C, theta, first):
        for z in self.options["zones"]:
            i, g = ZONES.index(z), theta[f"g_{z}"]
            A[:, i, i] -= g
            B[:, i, U_AIR] += g


class SensorLag(Effect):
    name = "sensor_lag"
    physics = "thermocouples read a first-order lag of the zone gas temperature"
    option_kinds = {"order": (1, lambda n: n.integer(lo=1, hi=4))}

    def _params(self):
        return (Param("tau_lag", 2.0, 0.01, 120.0, unit="min", doc="thermocouple time constant"),)

    @property
    def state_zones(self):
        return tuple(z for _ in range(self.options["order"]) for z in range(3))

    def extend(self, A, B, C, theta, first):
        # `order` cascaded stages (sheath, then junction) whose time constants add up to
        # tau_lag: the same mean delay, a sharper lag. Unequal stages keep A diagonalisable.
        order = self.options["order"]
        shares = np.arange(1, order + 1, dtype=float)
        shares /= shares.sum()
        for z in range(3):
            prev = z
            for k in range(order):
                i = first + 3 * k + z
                rate = 1.0 / (shares[k] * theta["tau_lag"])
                A[:, i, i] -= rate
                A[:, i, prev] += rate
                prev = i
            C[:, z, :] = 0.0
            C[:, z, prev] = 1.0


class DeadTime(Effect):
    name = "dead_time"
    physics = "burner heat reaches the zone only after a transport delay"

    def _params(self):
        return (Param("theta_dead", 5.0, 0.01, 240.0, unit="min", doc="transport delay"),)

    def transform_drive(self, theta, drive):
        P = theta["theta_dead"].shape[0]
        s = np.broadcast_to(drive.s, (P, drive.s.shape[-1]))
        du = np.broadcast_to(drive.du, (P,) + drive.du.shape[1:])
        burners = np.zeros(N_INPUTS)
        burners[U_BURNERS] = 1.0
        s_new = np.concatenate([s + theta["theta_dead"][:, None], s], axis=1)
        du_new = np.concatenate([du * burners, du * (1.0 - burners)], axis=1)
        return Drive(drive.t0, drive.u0, s_new, du_new)


class WallStorage(Effect):
    name = "wall_storage"
    physics = "the refractory wall of a zone stores heat: one more, slow state"
    option_kinds = {"zones": (ZONES, lambda n: tuple(ZONES[i] for i in _zone_list(n))),
                    "layers": (1, lambda n: n.integer(lo=1, hi=2))}
    """layers 2: a hot face and a slower back layer behind it, a wall of another order."""

    def _params(self):
        face = (Param("k_gw", 0.05, 1e-5, 10.0, doc="gas-to-wall exchange rate, seen from the gas"),
                Param("k_wg", 0.002, 1e-6, 1.0, doc="wall-to-gas exchange rate, seen from the wall"))
        if self.options["layers"] == 1:
            return face
        return face + (
            Param("k_wb", 0.005, 1e-6, 1.0, doc="hot face to back layer, seen from the face"),
            Param("k_bw", 0.001, 1e-6, 1.0, doc="back layer to hot face, seen from the back"))

    @property
    def state_zones(self):
        return tuple(ZONES.index(z) for z in self.options["zones"]) * self.options["layers"]

    def extend(self, A, B, C, theta, first):
        zones = [ZONES.index(z) for z in self.options["zones"]]
        for j, z in enumerate(zones):
            face = first + j
            _exchange(A, z, face, theta["k_gw"], theta["k_wg"])
            if self.options["layers"] == 2:
                _exchange(A, face, face + len(zones), theta["k_wb"], theta["k_bw"])


def _exchange(A: np.ndarray, i: int, j: int, k_ij: np.ndarray, k_ji: np.ndarray) -> None:
    """Heat exchange between states i and j, at rate k_ij seen from i and k_ji seen from j."""
    A[:, i, i] -= k_ij
    A[:, i, j] += k_ij
    A[:, j, j] -= k_ji
    A[:, j, i] += k_ji


class Radiation(Effect):
    name = "radiation"
    physics = "heat exchange grows with the fourth power of absolute temperature, not linearly"
    linear = False
    option_kinds = {
        "exponent": (4.0, lambda n: n.number(lo=1.5, hi=6.0)),
        "t_ref_c": (900.0, lambda n: n.number(lo=100.0, hi=2000.0)),
        "emissivity_slope": (0.0, lambda n: n.number(lo=-1.0, hi=1.0)),
    }

    def _params(self):
        share = Param("rad_share", 0.5, 0.0, 1.0, log=False, unit="-",
                      doc="share of each exchange that is radiative at the reference temperature")
        if self.options["exponent"] is not None:
            return (share,)
        # exponent None: the exponent fitted too (the diagnosis's further radiation law)
        return (share, Param("rad_exponent", 4.0, 1.5, 6.0, log=False, unit="-",
                             doc="effective exponent: a furnace's gas and walls set it, not "
                                 "only Stefan-Boltzmann"))

    def nonlinear_off(self, theta):
        return theta["rad_share"] == 0.0

    def nonlinear_rhs(self, theta, x, A, B, u):
        # Each linear exchange k (Tj - Ti) becomes k [(1-w)(Tj - Ti) + w (rho(Tj) - rho(Ti))]
        # with rho(T) = T_K^p / (p T_ref^(p-1)), whose slope is 1 at T_ref: the paper's model is
        # the linearisation of this one at the reference temperature. An emissivity that
        # changes with temperature, 1 + s (T_K / T_ref - 1), makes the law other than a power
        # of T (the furnace's own law, for the diagnosis's robustness check).
        p, tref = self.options["exponent"], self.options["t_ref_c"] + KELVIN
        s = self.options["emissivity_slope"]
        if p is None:
            p = theta["rad_exponent"][:, None]

        def excess(T):
            ratio = np.maximum(T + KELVIN, 1.0) / tref
            law = ratio ** p
            if s:  # the hot path of every radiation fit: no work for a power law
                law *= np.maximum(1.0 + s * (ratio - 1.0), 0.0)
            return tref / (p + s) * law - T

        w = theta["rad_share"][:, None]
        r = excess(x[:, :3])
        r_air = excess(u[:, U_AIR][:, None])
        K = A[:, :3, :3] * (1.0 - np.eye(3))
        k_air = B[:, :3, U_AIR]
        dx = np.zeros_like(x)
        dx[:, :3] = w * (np.einsum("pij,pj->pi", K, r) - K.sum(axis=2) * r + k_air * (r_air - r))
        return dx


class BurnerNonlinearity(Effect):
    name = "burner_nonlinearity"
    physics = "heat per burner falls (or rises) as more burners fire"
    option_kinds = {"form": ("linear", lambda n: n.string(("linear", "power", "exponential",
                                                           "quadratic")))}

    def _params(self):
        return (Param("k_nl", -0.01, -0.035, 0.1, log=False, unit="1/burner",
                      doc="relative change of heat per burner for each further burner on"),)

    def transform_levels(self, theta, u):
        k = theta["k_nl"][:, None]
        n = u[..., U_BURNERS].sum(axis=-1)  # (P|1, J)
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
        out[..., U_BURNERS] *= factor[..., None]
        return out


class FuelChange(Effect):
    name = "fuel_change"
    physics = "heat per burner changes at one instant (a fuel switch, e.g. natural gas to biogas)"

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
        du[..., U_BURNERS] *= np.where(s >= tc[:, None], rho[:, None], 1.0)[..., None]
        jump = np.zeros((P, 1, du.shape[-1]))
        jump[:, 0, U_BURNERS] = (rho - 1.0)[:, None] * u_at[:, U_BURNERS]
        return Drive(drive.t0, drive.u0, np.concatenate([s, tc[:, None]], axis=1),
                     np.concatenate([du, jump], axis=1))


class SensorDrift(Effect):
    name = "sensor_drift"
    physics = "one thermocouple of a pair drifts away from its partner"
    option_kinds = {"sensor": ("heat_2", lambda n: n.string(SENSORS))}

    def _params(self):
        return (
            Param("drift_rate", 0.01, -1.0, 1.0, log=False, unit="°C/min",
                  doc="rate at which the sensor's error grows"),
            Param("t_drift", 0.0, 0.0, 1e6, log=False, unit="min", doc="when the drift starts"),
        )

    def sensor_offsets(self, theta, t):
        P = theta["drift_rate"].shape[0]
        out = np.zeros((P, t.size, len(SENSORS)))
        ramp = np.maximum(t[None, :] - theta["t_drift"][:, None], 0.0)
        out[:, :, SENSORS.index(self.options["sensor"])] = theta["drift_rate"][:, None] * ramp
        return out


EFFECTS: dict[str, type[Effect]] = {cls.name: cls for cls in (
    ZoneBurners, ZoneLosses, SensorLag, DeadTime, WallStorage, Radiation,
    BurnerNonlinearity, FuelChange, SensorDrift)}
"""Every effect of the contract, by its contract name, in the contract's order."""

DRIVE_ORDER = ("fuel_change", "dead_time")
"""A fuel change acts at the burner; the transport delay then carries it to the zone."""
