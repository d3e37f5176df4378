"""Rigid motions: the gauge of every unfolding.

Ranges determine points only up to a rigid motion (and a reflection); the infinitesimal rigid
motions span the null space of the range Jacobian that every Cramer-Rao bound and covariance has
to remove.
"""

from __future__ import annotations

import numpy as np

__all__ = ["receiver_gauge_projection", "rigid_motion_basis"]


def rigid_motion_basis(points: np.ndarray) -> np.ndarray:
    """(N d, d(d+1)/2) orthonormal basis of the infinitesimal rigid motions of points (N, d).

    Columns: d translations, then the rotations about the centroid (1 in 2-D, 3 in 3-D).
    """
    n, d = points.shape
    c = points - points.mean(axis=0)
    cols = [np.tile(np.eye(d)[i], n) for i in range(d)]
    if d == 2:
        cols.append(np.column_stack([-c[:, 1], c[:, 0]]).ravel())
    else:
        for axis in np.eye(3):
            cols.append(np.cross(axis, c).ravel())
    q, _ = np.linalg.qr(np.column_stack(cols))
    return q


def receiver_gauge_projection(receivers: np.ndarray, sources: np.ndarray) -> np.ndarray:
    """((M + K) d, (M + K) d) P = I - T (T_r^T T_r)^-1 T_r^T S_r: removes from a perturbation of the
    stacked points the rigid motion (basis T) least-squares fitted to its receiver rows. An error
    or covariance C in any gauge maps to the receiver gauge as P C P^T."""
    m, d = receivers.shape
    basis = rigid_motion_basis(np.vstack([receivers, sources]))
    t_r = basis[: m * d]
    fit = np.linalg.solve(t_r.T @ t_r, t_r.T)
    proj = np.eye(basis.shape[0])
    proj[:, : m * d] -= basis @ fit
    return proj
