"""The linear thermal network of a furnace description: its parameters and its matrices.

One temperature per zone. A link between zones i and j carries heat both ways, and each
side has its own rate: zone i's temperature moves at k_ij (T_j - T_i) (k_ij = 1/(R_ij C_i)),
zone j's at k_ji (T_i - T_j). An ambient zone loses heat at loss_i (T_air - T_i), and a
heated zone gains gain_i per burner firing (1/C_i in burner units). The paper's eq. 11 is
the three-zone chain of this network, and its parameters keep their names a..f.

Naming rule for any other furnace: `k_<to>_<from>` for the exchange rate of zone <to> from
zone <from>, `loss_<zone>`, `gain_<zone>`; in that order (each link's two sides in the
order the link is written, then the losses, then the gains, zones in their order).
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


@dataclass(frozen=True)
class Term:
    """Where one parameter enters: `kind` exchange (zone `to` from zone `src`), loss (zone
    `to` to ambient) or gain (zone `to` per burner)."""

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
    return tuple(out)


def parameter_names(furnace: Furnace) -> list[str]:
    return [t.name for t in terms(furnace)]


def parameters(furnace: Furnace) -> tuple[Param, ...]:
    """The network's parameters with their defaults and search boxes: the paper's a..f
    (Table V defaults) for its structure, generic ones otherwise."""
    if furnace.paper_structure:
        return BASELINE
    proto = {"exchange": EXCHANGE, "loss": LOSS, "gain": GAIN}
    out = []
    for t in terms(furnace):
        p = proto[t.kind]
        what = {"exchange": f"zone {furnace.zones[t.to]} from zone "
                            f"{furnace.zones[t.src] if t.src >= 0 else ''}",
                "loss": f"zone {furnace.zones[t.to]} to ambient",
                "gain": f"zone {furnace.zones[t.to]} per burner"}[t.kind]
        out.append(Param(t.name, p.default, p.lo, p.hi, p.log, p.unit, f"{p.doc}: {what}"))
    return tuple(out)


def fill(furnace: Furnace, A: np.ndarray, B: np.ndarray, theta: dict[str, np.ndarray]) -> None:
    """Write the network into A (P, n, n) and B (P, n, m), zeros on entry; inputs are the
    burner counts per zone, then ambient (m >= n_zones + 1).

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
        elif furnace.burner_heat == "first_zone":
            B[:, t.to, :nz] = v[:, None]
        else:
            B[:, t.to, t.to] = v


def equation_error(furnace: Furnace, records: list) -> dict[str, float]:
    """Parameter values from the records by linear least squares on the integrated
    equations: where a fit of a many-zone network starts.

    Every zone is measured, so each zone's equation is linear in its own parameters:
    T_i(t) = T_i(t0) + sum_j k_ij int (T_j - T_i) + loss_i int (T_air - T_i) + gain_i int q.
    The integrals of the measured temperatures average their noise away, and a term in t
    per record and zone takes up the thermocouples' constant offsets (which enter the
    integrals as offset x time). A genetic search in twenty-odd dimensions finds the basin
    far less surely, and far more slowly, than this one solve. `records` are Experiments
    of this furnace; values outside a parameter's box come back clipped to it."""
    params = {p.name: p for p in parameters(furnace)}
    rows: dict[int, list] = {i: [] for i in range(furnace.n_zones)}
    own = terms(furnace)
    for r in records:
        t = np.asarray(r.t_min, dtype=float)
        y = _filled(r.zone_temp, t)
        dt = np.diff(t)

        def integral(v: np.ndarray, dt: np.ndarray = dt) -> np.ndarray:  # trapezoid
            return np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)))

        def held(v: np.ndarray, dt: np.ndarray = dt) -> np.ndarray:  # inputs hold
            return np.concatenate(([0.0], np.cumsum(v[:-1] * dt)))

        for i in range(furnace.n_zones):
            cols = []
            for term in own:
                if term.to != i:
                    continue
                if term.kind == "exchange":
                    cols.append(integral(y[:, term.src] - y[:, i]))
                elif term.kind == "loss":
                    cols.append(integral(r.t_air - y[:, i]))
                elif furnace.burner_heat == "first_zone":
                    cols.append(held(r.burners.sum(axis=1).astype(float)))
                else:
                    cols.append(held(r.burners[:, i].astype(float)))
            rows[i].append((np.column_stack(cols) if cols else np.zeros((t.size, 0)),
                            t - t[0], y[:, i]))
    out = {}
    for i in range(furnace.n_zones):
        names = [term.name for term in own if term.to == i]
        if not names:
            continue
        blocks = rows[i]
        m = sum(b[0].shape[0] for b in blocks)
        X = np.zeros((m, len(names) + 2 * len(blocks)))
        b = np.zeros(m)
        at = 0
        for j, (cols, tt, yy) in enumerate(blocks):
            n = tt.size
            X[at:at + n, :len(names)] = cols
            X[at:at + n, len(names) + 2 * j] = 1.0
            X[at:at + n, len(names) + 2 * j + 1] = tt
            b[at:at + n] = yy
            at += n
        scale = np.maximum(np.abs(X).max(axis=0), 1e-300)
        coef = np.linalg.lstsq(X / scale, b, rcond=None)[0] / scale
        for name, v in zip(names, coef[:len(names)], strict=True):
            p = params[name]
            out[name] = float(np.clip(v, p.lo, p.hi)) if np.isfinite(v) else p.default
    return out


def _filled(y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Zone temperatures with missing readings interpolated in time (held at the ends)."""
    y = np.array(y, dtype=float)
    for i in range(y.shape[1]):
        ok = np.isfinite(y[:, i])
        if ok.any() and not ok.all():
            y[:, i] = np.interp(t, t[ok], y[ok, i])
    return y
