"""Rigid (and similarity) alignment of an estimate to a reference, and errors after alignment.

Umeyama (1991), "Least-squares estimation of transformation parameters between two point
patterns": the rotation from an SVD of the cross-covariance, with the sign fix that excludes
reflections unless they are allowed. Points are rows (N, d).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_flag, as_points, frozen, shape_str
from rangeslam.errors import DegenerateGeometryError, InvalidInputError

__all__ = ["Alignment", "align"]


@dataclass(frozen=True)
class Alignment:
    """The transform x -> scale * R x + t that best maps an estimate onto a reference.

    Attributes:
        rotation: (d, d) orthogonal matrix (det -1 only when reflections were allowed and needed).
        translation: (d,) metres.
        scale: 1.0 unless scale estimation was asked for.
        aligned: (N, d) the estimate after the transform.
        errors: (N,) Euclidean distance of each aligned point to its reference, metres.
        rmse: root mean square of ``errors``.
    """

    rotation: np.ndarray
    translation: np.ndarray
    scale: float
    aligned: np.ndarray
    errors: np.ndarray
    rmse: float

    @property
    def reflected(self) -> bool:
        return bool(np.linalg.det(self.rotation) < 0)

    def apply(self, points: ArrayLike) -> np.ndarray:
        """Map further points (N, d) of the estimate's frame into the reference frame."""
        p = as_points(points, "points", dim=self.rotation.shape[0])
        return self.scale * p @ self.rotation.T + self.translation


def align(
    estimate: ArrayLike,
    reference: ArrayLike,
    *,
    reflection: bool = False,
    scale: bool = False,
) -> Alignment:
    """Best rigid motion (optionally with reflection and scale) taking ``estimate`` onto ``reference``.

    Both (N, d) with the same N; minimises sum ||reference_i - (c R estimate_i + t)||^2.
    """
    x = as_points(estimate, "estimate", min_points=1)
    y = as_points(reference, "reference", dim=x.shape[1], min_points=1)
    reflection, scale = as_flag(reflection, "reflection"), as_flag(scale, "scale")
    if x.shape != y.shape:
        raise InvalidInputError(
            f"estimate and reference must have the same shape; got {shape_str(x.shape)} and {shape_str(y.shape)}"
        )
    n, d = x.shape
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    var_x = float(np.sum(xc**2)) / n
    cov = yc.T @ xc / n
    u, s, vt = np.linalg.svd(cov)
    sign = np.ones(d)
    if not reflection and np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[-1] = -1.0
    rot = (u * sign) @ vt
    if scale:
        if var_x <= np.finfo(float).eps * max(1.0, float(np.abs(x).max())) ** 2:
            raise DegenerateGeometryError(
                "estimate points all coincide: the scale cannot be estimated"
            )
        c = float(np.sum(s * sign)) / var_x
    else:
        c = 1.0
    t = my - c * rot @ mx
    aligned = c * x @ rot.T + t
    errors = np.linalg.norm(aligned - y, axis=1)
    return Alignment(
        rotation=frozen(rot),
        translation=frozen(t),
        scale=c,
        aligned=frozen(aligned),
        errors=frozen(errors),
        rmse=float(np.sqrt(np.mean(errors**2))),
    )
