"""Parameters of the paper's model (eq. 11) and their physical R/C reading (eq. 10)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Param:
    """One identifiable parameter: where a search may look for it, and on what scale.

    Rate constants are positive and span decades between furnaces, so they are searched on a
    log scale; signed or bounded quantities (a fraction, a time) are searched linearly.
    """

    name: str
    default: float
    lo: float
    hi: float
    log: bool = True
    unit: str = "1/min"
    doc: str = ""


BASELINE = (
    Param("a", 0.020121, 1e-4, 1.0, doc="1/(R1 C1): soaking-zone exchange with the heating zone"),
    Param("b", 0.299049, 1e-3, 10.0, doc="1/(R1 C2): heating zone fed by the soaking zone"),
    Param("c", 0.061544, 1e-4, 10.0, doc="1/(R2 C2): heating zone exchange with the preheating zone"),
    Param("d", 0.873573, 1e-3, 50.0, doc="1/(R2 C3): preheating zone fed by the heating zone"),
    Param("e", 0.727504, 1e-3, 50.0, doc="1/(R3 C3): preheating zone loss to ambient"),
    Param("f", 0.224131, 1e-3, 10.0, unit="°C/min per burner",
          doc="1/C1 in the paper's units: soaking-zone heating rate per burner on"),
)
"""a..f with the paper's 'genetic mean parameter' (Table V) as defaults."""

PAPER_TABLE_V = {p.name: p.default for p in BASELINE}


@dataclass(frozen=True)
class ThermalRC:
    """The same model as capacities and resistances (eq. 10).

    With q1 measured in burners the capacities come out in burner-minutes per kelvin: the
    data fix only ratios, so C1 = 1/f sets the scale and the rest follow.
    """

    C1: float
    C2: float
    C3: float
    R1: float
    R2: float
    R3: float

    @classmethod
    def from_params(cls, p: dict[str, float]) -> ThermalRC:
        C1 = 1.0 / p["f"]
        R1 = 1.0 / (p["a"] * C1)
        C2 = 1.0 / (p["b"] * R1)
        R2 = 1.0 / (p["c"] * C2)
        C3 = 1.0 / (p["d"] * R2)
        R3 = 1.0 / (p["e"] * C3)
        return cls(C1, C2, C3, R1, R2, R3)

    def to_params(self) -> dict[str, float]:
        return {
            "a": 1 / (self.R1 * self.C1), "b": 1 / (self.R1 * self.C2),
            "c": 1 / (self.R2 * self.C2), "d": 1 / (self.R2 * self.C3),
            "e": 1 / (self.R3 * self.C3), "f": 1 / self.C1,
        }
