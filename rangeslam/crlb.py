"""Cramer-Rao lower bounds for range measurements with i.i.d. Gaussian noise. Pure numpy.

For a point x observed through ranges r_m = ||x - a_m|| + e_m, e_m ~ N(0, sigma_m^2), the Fisher
information is F = sum_m u_m u_m^T / sigma_m^2 with u_m = (x - a_m) / ||x - a_m||, and any
unbiased estimator has covariance >= F^-1. The bound on the RMSE is sqrt(trace F^-1).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ._validation import as_mask, as_point, as_points, shape_str
from .errors import DegenerateGeometryError, InvalidInputError

__all__ = ["multilateration_crlb"]


def multilateration_crlb(
    anchors: ArrayLike,
    point: ArrayLike,
    sigma: float | ArrayLike,
    *,
    mask: ArrayLike | None = None,
) -> np.ndarray:
    """(d, d) CRLB covariance of a point located from ranges to known anchors (M, d).

    ``sigma`` is the range noise standard deviation in metres, a scalar or one per anchor (M,).
    ``sqrt(trace(result))`` bounds the RMSE of any unbiased estimator.
    """
    a = as_points(anchors, "anchors")
    m, d = a.shape
    x = as_point(point, "point", dim=d)
    observed = as_mask(mask, "mask", shape=(m,))
    s = (
        np.broadcast_to(np.asarray(sigma, dtype=float), (m,))
        if np.ndim(sigma) == 0
        else np.asarray(sigma, float)
    )
    if s.shape != (m,):
        raise InvalidInputError(
            f"sigma must be a scalar or have shape ({m},); got {shape_str(s.shape)}"
        )
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise InvalidInputError(
            "sigma must be positive and finite (the bound is infinite information at 0)"
        )
    diff = x - a[observed]
    dist = np.linalg.norm(diff, axis=1)
    if np.any(dist == 0):
        raise DegenerateGeometryError(
            "point coincides with an anchor: the range gradient is undefined there"
        )
    u = diff / dist[:, None] / s[observed][:, None]
    fisher = u.T @ u
    eig = np.linalg.eigvalsh(fisher)
    if eig[0] <= 1e-12 * eig[-1]:
        raise DegenerateGeometryError(
            "the Fisher information is singular: the anchors' directions from the point do not span R^d"
        )
    return np.linalg.solve(fisher, np.eye(d))
