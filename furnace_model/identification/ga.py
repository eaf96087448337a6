"""A real-coded genetic algorithm over a batched objective: the paper's search method.

The paper tunes two knobs, population size and number of generations (its 'GA cycles');
so does this. Genes are real numbers in a box (the fit hands it log-parameters for positive
quantities, so one mutation size suits values that span decades). Each generation is scored
in one call of the objective on the whole population, which is what makes the batched exact
simulator pay off. Operators are the textbook ones: binary tournament, blend crossover
(BLX-0.5), Gaussian mutation shrinking over the run, and elitism.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass
class GAResult:
    best: np.ndarray  # (n,)
    best_f: float
    population: np.ndarray  # (P, n) final generation, best first
    fitness: np.ndarray  # (P,)
    generations: int  # generations actually run
    evaluations: int


def genetic_search(objective: Callable[[np.ndarray], np.ndarray], lo: np.ndarray, hi: np.ndarray,
                   *, population: int, generations: int, rng: np.random.Generator,
                   start: np.ndarray | None = None, spread: float | np.ndarray = 1.0,
                   elite: int = 2,
                   crossover: float = 0.9, progress: Callable[[float], None] | None = None,
                   deadline: float | None = None) -> GAResult:
    """Minimise objective((P, n) genes) -> (P,) over the box [lo, hi].

    With `start`, the first population is drawn around it (sd `spread` times the box width,
    per gene if an array; one member exactly at it) instead of uniformly over the box: a
    warm start.
    `deadline` is a time.perf_counter() value after which the search returns what it has.
    """
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    n, P = lo.size, max(int(population), 4)
    width = hi - lo
    if start is None:
        pop = lo + rng.random((P, n)) * width
    else:
        pop = _reflect(start + rng.normal(0.0, 1.0, (P, n)) * np.asarray(spread) * width, lo, hi)
        pop[0] = np.clip(start, lo, hi)
    fit = _score(objective, pop)
    evals = P
    p_mut = max(1.0 / n, 0.1)
    done = 0
    for g in range(int(generations)):
        if deadline is not None and time.perf_counter() > deadline:
            break
        order = np.argsort(fit)
        pop, fit = pop[order], fit[order]
        sigma = width * (0.1 * (1.0 - g / max(generations, 1)) + 0.005)
        parents = _tournament(fit, 2 * (P - elite), rng)
        pa, pb = pop[parents[0::2]], pop[parents[1::2]]
        u = rng.random(pa.shape) * 2.0 - 0.5  # BLX-0.5: anywhere on the segment, extended by half
        kids = np.where(rng.random((P - elite, 1)) < crossover, pa + u * (pb - pa), pa)
        mutate = rng.random(kids.shape) < p_mut
        kids = kids + mutate * rng.normal(0.0, 1.0, kids.shape) * sigma
        kids = _reflect(kids, lo, hi)
        kfit = _score(objective, kids)
        evals += kids.shape[0]
        pop = np.concatenate([pop[:elite], kids])
        fit = np.concatenate([fit[:elite], kfit])
        done = g + 1
        if progress is not None:
            progress(done / generations)
    order = np.argsort(fit)
    pop, fit = pop[order], fit[order]
    return GAResult(pop[0].copy(), float(fit[0]), pop, fit, done, evals)


def _score(objective, pop: np.ndarray) -> np.ndarray:
    f = np.asarray(objective(pop), dtype=float)
    return np.where(np.isfinite(f), f, np.inf)


def _tournament(fit: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    a, b = rng.integers(0, fit.size, k), rng.integers(0, fit.size, k)
    return np.where(fit[a] <= fit[b], a, b)


def _reflect(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Fold genes that left the box back inside (keeps diversity at the edges, unlike clip)."""
    x = np.where(x < lo, 2 * lo - x, x)
    x = np.where(x > hi, 2 * hi - x, x)
    return np.clip(x, lo, hi)
