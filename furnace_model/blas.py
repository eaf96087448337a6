"""One BLAS thread for the model's numerics.

The model's linear algebra is many small products (a few states, a few thousand samples,
a few dozen parameter sets) called in tight loops. OpenBLAS spreads any product above a
small size over every core and spins its threads between calls: on the 2-core gateway, and
under the diagnosis's own pool of one process per core, those threads only contend
(measured in docs/performance.md). threadpoolctl finds whichever BLAS the installed numpy
and scipy carry and sets its thread count while the block runs; the caller's setting is
restored after. Entering it also sets the C allocator for the numerics' large temporaries
(`furnace_model.allocator`), once per process.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import ParamSpec, TypeVar

from .allocator import keep_freed_blocks

P = ParamSpec("P")
R = TypeVar("R")

_held = 0
"""Nesting depth of `one_thread` in this process: only the outermost call sets the limit
(a fit inside a diagnosis inside a selfcheck pays it once). Forked workers inherit both
the limit and the depth."""


@contextmanager
def one_thread() -> Iterator[None]:
    global _held
    if _held:
        yield
        return
    from threadpoolctl import threadpool_limits

    keep_freed_blocks()
    with threadpool_limits(limits=1, user_api="blas"):
        _held += 1
        try:
            yield
        finally:
            _held -= 1


def held() -> bool:
    """Whether this process's BLAS is held to one thread (inside `one_thread`)."""
    return _held > 0


def on_one_thread(f: Callable[P, R]) -> Callable[P, R]:
    """`f` run inside `one_thread`."""

    @functools.wraps(f)
    def run(*args: P.args, **kwargs: P.kwargs) -> R:
        with one_thread():
            return f(*args, **kwargs)

    return run
