"""The exact Jacobian (closed-form sensitivities) against forward-mode automatic
differentiation of the same zero-order-hold response with JAX, on the paper's two
heat-ups: the measurement behind the choice of the closed form (README, Dependencies).

JAX is not a dependency of the project; the bench runs where it is installed beside the
project's own packages:

    python3 -m venv /tmp/jaxenv
    /tmp/jaxenv/bin/pip install jax numpy scipy pandas pyyaml threadpoolctl
    PYTHONPATH=. /tmp/jaxenv/bin/python bench/bench_autodiff.py [--repeat 7]

The differentiated function is the baseline's residuals as a JAX program: the network's
matrices from the parameters (linear in them, so a sum of constant matrices), the
zero-order-hold step over one sample from the matrix exponential of [[A, B], [0, 0]], and a
scan over the samples. It is checked against the project's residuals and Jacobian before
anything is timed. Both on one thread (XLA's and OpenBLAS's), CPU time of this process.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable

import numpy as np
from bench_diagnose import paper_pair
from bench_jacobian import cpu

from furnace_model.blas import one_thread
from furnace_model.identification.jacobian import jacobian
from furnace_model.identification.problem import Problem
from furnace_model.simulation.structure import ModelStructure

# before jax is imported: one thread, as the project's BLAS is held to one
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false "
                                   "intra_op_parallelism_threads=1")
try:
    import jax
    import jax.numpy as jnp
except ImportError:
    print("bench_autodiff: skipped, jax is not installed here (it is no dependency of the "
          "project; this script's docstring says how to run it)", file=sys.stderr)
    sys.exit(0)

jax.config.update("jax_enable_x64", True)


def jax_residuals(prob: Problem) -> Callable:
    """The problem's residuals (one record, no offsets) as a function JAX can differentiate."""
    structure, (r,) = prob.structure, prob.records
    k, n = prob.k, structure.n_states
    h = np.diff(r.t)
    if not np.allclose(h, h[0]):
        raise SystemExit("the JAX program steps on a uniform grid; this record's is not")
    unit = {name: np.eye(k)[i] for i, name in enumerate(prob.names)}
    units = structure.theta(unit)
    network = structure.system(units)  # A and B are linear in the rates
    EA, EB = jnp.asarray(network.A), jnp.asarray(network.B)
    C = jnp.asarray(network.C[0])
    m = EB.shape[2]
    drive = structure.drive(units, r.inputs)
    U = jnp.asarray(drive.levels_at(r.t)[0])  # (N, m): the input held from each sample on
    y, mask, log = jnp.asarray(r.y), np.asarray(r.mask), jnp.asarray(prob.log)

    def residuals(z):
        theta = jnp.where(log, jnp.exp(z[:k]), z[:k])
        M = jnp.zeros((n + m, n + m))
        M = M.at[:n, :n].set(jnp.tensordot(theta, EA, 1)).at[:n, n:].set(
            jnp.tensordot(theta, EB, 1))
        E = jax.scipy.linalg.expm(M * h[0])
        Ad, Bd = E[:n, :n], E[:n, n:]

        def step(x, u):
            return Ad @ x + Bd @ u, x

        _, X = jax.lax.scan(step, z[k:k + n], U)
        return ((X @ C.T) - y)[mask]
    return residuals


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    print(f"jax {jax.__version__}, {jax.devices()[0].platform}; one thread each\n")
    print("| record | samples | exact (ms) | JAX jacfwd, compiled (ms) | JAX / exact "
          "| JAX's first call: trace and compile (s) | largest difference (share of its column) |")
    print("|---|---|---|---|---|---|---|")
    with one_thread():
        for record in paper_pair():
            structure = ModelStructure(furnace=record.furnace)
            prob = Problem([record], structure, {}, {})
            z = prob.start(prob.to_z(np.array([structure.defaults()[n] for n in prob.names])))
            f = jax_residuals(prob)
            gap = np.max(np.abs(np.asarray(f(jnp.asarray(z))) - prob.fun(z)))
            if gap > 1e-8 * np.max(np.abs(prob.fun(z))):
                raise SystemExit(f"the JAX residuals are not the project's: {gap:.3g} °C apart")
            jac = jax.jit(jax.jacfwd(f))
            t = time.process_time()
            J_ad = np.asarray(jac(jnp.asarray(z)).block_until_ready())
            first = time.process_time() - t
            J = jacobian(prob, z)
            diff = np.max(np.abs(J_ad - J) / np.maximum(np.abs(J).max(axis=0), 1e-300))
            if diff > 1e-6:
                raise SystemExit(f"the JAX Jacobian is not the project's: {diff:.3g} of a "
                                 "column apart")
            zj = jnp.asarray(z)
            t_ad = 1e3 * cpu(lambda jac=jac, zj=zj: jac(zj).block_until_ready(),
                             args.repeat, 20)
            t_exact = 1e3 * cpu(lambda prob=prob, z=z: jacobian(prob, z), args.repeat, 20)
            print(f"| {record.name} | {len(record)} | {t_exact:.2f} | {t_ad:.2f} | "
                  f"{t_ad / t_exact:.1f} | {first:.2f} | {diff:.1e} |", flush=True)


if __name__ == "__main__":
    main()
