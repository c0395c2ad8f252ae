"""One BLAS thread for the small dense algebra of a control step (issue 31). Pure.

OpenBLAS runs a matrix product on several threads once its size passes a threshold, and
that threshold lies inside the observers' sizes: on this project's 2-core machine under load
an 88 x 88 product ``A @ B.T`` took ~16 ms of CPU on two threads against ~40 us on one (the
waiting thread spins until its helper is scheduled). ``A @ B`` of that size stayed on one
thread; of the sizes tried, 82 x 82 was the smallest threaded ``A @ B.T`` (80 x 80 was not),
128 x 128 the smallest threaded ``A @ B`` (100 x 100 was not). The UR's followed model with
the links' bending has an 88-state Kalman filter (75 nodes, 6 joint offsets, 7 adapted
factors): its step cost 29.9 ms of CPU instead of ~1.6 ms on one thread, nearly all of it in
those products (issue 31, docs/how-to/universal-robots.md).

:func:`one_blas_thread` limits BLAS to one thread for a block of such work. The controller
of the loaded BLAS libraries is found once (threadpoolctl's ``threadpool_limits`` looks for
them on every call: ~1.1 ms each, as much as the work it would save); entering and leaving
the limit then costs ~40 us. The limit is process-wide while the block runs (BLAS has no
per-thread setting): another thread's product in that window runs on one thread too, which
changes its speed, never its result.
"""

from __future__ import annotations

import contextlib
import functools
from contextlib import AbstractContextManager

from threadpoolctl import ThreadpoolController


@functools.cache
def _blas() -> ThreadpoolController:
    """The process's BLAS libraries, found on first use (numpy's and scipy's are loaded by
    then: this module's callers import numpy). Two threads' first calls may both look: the
    same libraries, found twice."""
    return ThreadpoolController().select(user_api="blas")


#: Below this matrix size no product was seen on OpenBLAS's threaded path (82 x 82 was the
#: smallest, ``A @ B.T``): :func:`one_blas_thread` then leaves BLAS as it is, and a small
#: filter (a two-link model's, every 20 ms) does not pay the limit's ~40 us.
THREADED_FROM_SIZE = 64


def one_blas_thread(size: int | None = None) -> AbstractContextManager[object]:
    """A context in which BLAS runs on one thread (module docstring); with ``size`` (the
    largest matrix dimension of the work) below THREADED_FROM_SIZE, nothing to limit."""
    if size is not None and size < THREADED_FROM_SIZE:
        return contextlib.nullcontext()
    limiter: AbstractContextManager[object] = _blas().limit(limits=1)
    return limiter


__all__ = ["THREADED_FROM_SIZE", "one_blas_thread"]
