"""The slowest and fastest decay rates of a thermal network (eigenvalues of ``C^-1 K``) on
large networks, where a dense eigen-solver is out of reach. Pure code: matrices in, numbers
out.

``C^-1 K`` is self-adjoint in the inner product weighted by ``C``, so it shares its spectrum
with the symmetric positive definite ``S = C^-1/2 K C^-1/2`` (DESIGN.md "Eq. 5.1").

- The slowest rate, the smallest eigenvalue of ``S``: shift-invert Lanczos about 0
  (``scipy.sparse.linalg.eigsh(sigma=0)``): one sparse factorisation of ``S``, and the
  smallest eigenvalues become the largest of ``S^-1``, well separated; milliseconds at
  10,000 nodes.
- The fastest rate, the largest eigenvalue: plain Lanczos (``which="LA"``) needs thousands of
  iterations there (the top of a long bar's spectrum is a near-continuum: 491 s and 105 s of
  CPU for a 10,000-node bar at a 1e-6 tolerance), and shift-invert about an upper bound
  converges no faster. It is found instead by bisection on Sylvester's law of inertia: the
  number of negative pivots of the symmetric factorisation ``S - s I = L D L^T`` is the
  number of eigenvalues below ``s``. Between the largest diagonal entry (a Rayleigh
  quotient, so a lower bound) and the Gershgorin bound, ~40 sparse factorisations (SuperLU
  with diagonal pivots and a symmetric ordering) give it to 1e-12 relative, from above.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import eigsh, splu

#: relative width at which the bisection of the largest eigenvalue stops
RELATIVE_TOLERANCE = 1e-12
#: at most this many factorisations (the bracket halves each time: 2^-60 < 1e-18)
_MAX_BISECTIONS = 60


class SpectrumError(ArithmeticError):
    """The inertia of a shifted matrix could not be read (a pivot needed off the diagonal)."""


def smallest_eigenvalue(symmetric: sp.spmatrix | sp.sparray) -> float:
    """The smallest eigenvalue of a sparse symmetric positive definite matrix."""
    value = eigsh(sp.csc_matrix(symmetric), k=1, sigma=0.0, which="LM", return_eigenvectors=False)
    return float(value[0])


def count_below(symmetric: sp.csc_matrix, shift: float) -> int:
    """How many eigenvalues of the sparse symmetric ``symmetric`` lie below ``shift``: the
    negative pivots of ``symmetric - shift I = P^T L D L^T P`` (Sylvester's law of inertia;
    a symmetric permutation keeps it)."""
    shifted = sp.csc_matrix(symmetric - shift * sp.identity(symmetric.shape[0], format="csc"))
    try:
        factors = splu(
            shifted,
            permc_spec="MMD_AT_PLUS_A",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
    except RuntimeError as err:  # an exactly singular shift: the caller moves it
        raise SpectrumError(f"singular at shift {shift!r}") from err
    if not np.array_equal(factors.perm_r, factors.perm_c):
        raise SpectrumError("the factorisation pivoted off the diagonal")
    pivots: NDArray[np.float64] = factors.U.diagonal()
    return int(np.count_nonzero(pivots < 0.0))


def largest_eigenvalue(symmetric: sp.spmatrix | sp.sparray) -> float:
    """The largest eigenvalue of a sparse symmetric matrix, from above to 1e-12 relative
    (module docstring)."""
    matrix = sp.csc_matrix(symmetric)
    size = matrix.shape[0]
    low = float(matrix.diagonal().max())  # e_i' S e_i: a Rayleigh quotient
    high = float(abs(matrix).sum(axis=1).max())  # Gershgorin
    high = max(high, low) * (1.0 + 4 * RELATIVE_TOLERANCE)
    for _ in range(_MAX_BISECTIONS):
        if high - low <= RELATIVE_TOLERANCE * abs(high):
            break
        middle = 0.5 * (low + high)
        try:
            below = count_below(matrix, middle)
        except SpectrumError:
            middle = low + 0.5001 * (high - low)  # off an eigenvalue, still inside
            below = count_below(matrix, middle)
        if below >= size:
            high = middle
        else:
            low = middle
    return high
