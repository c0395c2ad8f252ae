"""The Kalman filter's covariance steps by the structure of their matrices (issue 31). Pure.

:class:`daemon.model.observer.IrObserver` propagates and updates a covariance over its whole
state (the nodes, one offset per region, the adapted log factors): 88 states for a UR5e's
model with the links' bending (75 nodes, 6 joint offsets, 7 factors). Written densely, each
step is four products of that size; the matrices involved are mostly identity or of low rank,
and these functions use that. Same algebra, other rounding: tests/test_arm_bending_fast.py
holds them to the dense formulas within 1e-12 of the covariance's scale, step by step and
over a followed run.
"""

from __future__ import annotations

import numpy as np

from daemon.model.network import FloatArray


def propagate_nodes(
    p: FloatArray, nodes: int, a: FloatArray, b: FloatArray, noise: FloatArray
) -> FloatArray:
    """``J P J^T + diag(noise)`` for ``J = [[a, b], [0, I]]``: the first ``nodes`` states move
    (``a``: their own step, ``b``: their response to the other states), the rest are constant
    (offsets, log factors: the EKF's Jacobian, daemon.model.adaptation). With ``P`` split the
    same way, the nodes' block is ``(a Pnn + b Prn) a^T + (a Pnr + b Prr) b^T``, the cross
    block ``a Pnr + b Prr``, the constants' block unchanged: two products of the nodes' size
    and a few of width the constants', instead of two of the whole state's."""
    n = nodes
    pnn, pnr, prr = p[:n, :n], p[:n, n:], p[n:, n:]
    cross = a @ pnr + b @ prr
    result = np.empty_like(p)
    result[:n, :n] = (a @ pnn + b @ pnr.T) @ a.T + cross @ b.T
    result[:n, n:] = cross
    result[n:, :n] = cross.T
    result[n:, n:] = prr
    result[np.diag_indices_from(result)] += noise
    return result


def joseph_update(
    p: FloatArray, gain: FloatArray, h: FloatArray, hp: FloatArray, noise: FloatArray
) -> FloatArray:
    """The Joseph form ``(I - K H) P (I - K H)^T + K R K^T`` (``hp = H P``, ``R = diag(noise)``)
    in the same order as written, each factor ``I - K H`` applied as a correction of rank m
    (the readings): ``L = P - K hp``, then ``L - (L H^T) K^T + K R K^T``. Four products of
    rank m instead of two of the whole state's size, and the Joseph form's order kept: an
    expansion ``P - K hp - (K hp)^T + K S K^T``, the same algebra, subtracts terms of the
    prior's size to leave the posterior's, and gave a negative innovation variance in
    tests/test_observer.py (a 2 degC offset prior against 0.05 degC noise). It holds
    for ANY gain ``K``, as the Joseph form does."""
    left = p - gain @ hp
    result: FloatArray = left - (left @ h.T) @ gain.T + (gain * noise) @ gain.T
    return result


__all__ = ["joseph_update", "propagate_nodes"]
