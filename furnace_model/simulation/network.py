"""The linear thermal network of a furnace description: its parameters and its matrices.

One temperature per zone. A link between zones i and j carries heat both ways, and each
side has its own rate: zone i's temperature moves at k_ij (T_j - T_i) (k_ij = 1/(R_ij C_i)),
zone j's at k_ji (T_i - T_j). An ambient zone loses heat at loss_i (T_air - T_i), and a
heated zone gains gain_i per unit of its heat input (per burner firing: 1/C_i in burner
units). A measured disturbance d enters each zone it names with a gain of its own sign
(a throughput of cold slabs cools, a hot charge heats). The paper's eq. 11 is the
three-zone chain of this network, and its parameters keep their names a..f.

Naming rule for any other furnace: `k_<to>_<from>` for the exchange rate of zone <to> from
zone <from>, `loss_<zone>`, `gain_<zone>`, `gain_<disturbance>_<zone>`; in that order (each
link's two sides in the order the link is written, then the losses, then the gains, zones
in their order, then each disturbance's gains, disturbances in their order).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .furnace import Furnace
from .parameters import BASELINE, Param

EXCHANGE = Param("k", 0.05, 1e-4, 50.0, doc="exchange rate of a zone from a linked zone")
LOSS = Param("loss", 0.01, 1e-5, 50.0, doc="loss rate of a zone to ambient")
GAIN = Param("gain", 0.1, 1e-4, 10.0, unit="°C/min per burner",
             doc="heating rate of a zone per burner firing")
DISTURBANCE_RATE = 100.0
"""°C/min: the largest heating or cooling rate a disturbance at its largest declared value
can bring a zone, which bounds its gain's search box."""


@dataclass(frozen=True)
class Term:
    """Where one parameter enters: `kind` exchange (zone `to` from zone `src`), loss (zone
    `to` to ambient), gain (zone `to` per unit of heat input) or disturbance (zone `to` per
    unit of disturbance `src`)."""

    name: str
    kind: str
    to: int
    src: int = -1


def terms(furnace: Furnace) -> tuple[Term, ...]:
    """The network's parameters in order; eq. 11's names for the paper's structure."""
    z = furnace.zones
    out = []
    for i, j in furnace.links:
        out.append(Term(f"k_{z[i]}_{z[j]}", "exchange", i, j))
        out.append(Term(f"k_{z[j]}_{z[i]}", "exchange", j, i))
    out += [Term(f"loss_{z[i]}", "loss", i) for i in furnace.ambient]
    out += [Term(f"gain_{z[i]}", "gain", i) for i in furnace.heated]
    if furnace.paper_structure:
        out = [Term(p.name, t.kind, t.to, t.src) for p, t in zip(BASELINE, out, strict=True)]
    out += [Term(f"gain_{d.name}_{z[i]}", "disturbance", i, k)
            for k, d in enumerate(furnace.disturbances) for i in d.zones]
    return tuple(out)


def parameter_names(furnace: Furnace) -> list[str]:
    return [t.name for t in terms(furnace)]


def parameters(furnace: Furnace) -> tuple[Param, ...]:
    """The network's parameters with their defaults and search boxes: the paper's a..f
    (Table V defaults) for its structure, generic ones otherwise. A gain per unit of a rate
    is searched in the box of a gain per burner scaled to the rate's maximum; a disturbance's
    gain around zero (either sign), in a box scaled to the disturbance's declared range."""
    out = list(BASELINE) if furnace.paper_structure else []
    proto = {"exchange": EXCHANGE, "loss": LOSS, "gain": GAIN}
    for t in terms(furnace)[len(out):]:
        if t.kind == "disturbance":
            d = furnace.disturbances[t.src]
            box = DISTURBANCE_RATE / d.scale
            out.append(Param(t.name, 0.0, -box, box, log=False,
                             unit=f"°C/min per {d.unit}",
                             doc=f"heating rate of zone {furnace.zones[t.to]} per {d.unit} "
                                 f"of {d.name}"))
            continue
        p = proto[t.kind]
        heat = furnace.heat_inputs[t.to]
        if t.kind == "gain" and heat.kind == "rate":
            per = furnace.burners[t.to] / heat.max  # burners one unit stands for
            out.append(Param(t.name, p.default * per, p.lo * per, p.hi * per, p.log,
                             f"°C/min per {heat.unit}",
                             f"heating rate of a zone per {heat.unit} of its firing: zone "
                             f"{furnace.zones[t.to]}"))
            continue
        what = {"exchange": f"zone {furnace.zones[t.to]} from zone "
                            f"{furnace.zones[t.src] if t.src >= 0 else ''}",
                "loss": f"zone {furnace.zones[t.to]} to ambient",
                "gain": f"zone {furnace.zones[t.to]} per burner"}[t.kind]
        out.append(Param(t.name, p.default, p.lo, p.hi, p.log, p.unit, f"{p.doc}: {what}"))
    return tuple(out)


def fill(furnace: Furnace, A: np.ndarray, B: np.ndarray, theta: dict[str, np.ndarray]) -> None:
    """Write the network into A (P, n, n) and B (P, n, m), zeros on entry; inputs are the
    heat inputs per zone, then ambient, then the disturbances (m = `furnace.n_inputs`).

    Each rate is added where it acts and subtracted from its own zone's diagonal, in the
    order of `terms`: for the paper's structure this is eq. 11 to the last bit."""
    nz = furnace.n_zones
    air = nz
    for t in terms(furnace):
        v = theta[t.name]
        if t.kind == "exchange":
            A[:, t.to, t.src] += v
            A[:, t.to, t.to] -= v
        elif t.kind == "loss":
            A[:, t.to, t.to] -= v
            B[:, t.to, air] += v
        elif t.kind == "disturbance":
            B[:, t.to, air + 1 + t.src] = v
        elif furnace.burner_heat == "first_zone":
            B[:, t.to, :nz] = v[:, None]
        else:
            B[:, t.to, t.to] = v

