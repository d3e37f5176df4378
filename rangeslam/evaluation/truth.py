"""Errors of a map against a true one where the estimate's walls and landmarks come unlabelled:
walls of any convex room matched by their normals, landmarks matched to the nearest true one.

Pure numpy, like :mod:`rangeslam.evaluation.metrics` (whose :func:`shoebox_wall_errors` is the
shoebox case of :func:`matched_wall_errors`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_float_array, as_points, shape_str
from rangeslam.errors import InvalidInputError
from rangeslam.geometry.alignment import Alignment
from rangeslam.geometry.room import Room

__all__ = ["landmark_errors", "matched_wall_errors", "walk_plane"]


def matched_wall_errors(
    wall_normals: ArrayLike,
    wall_offsets: ArrayLike,
    room: Room,
    *,
    max_angle: float = 25.0,
) -> np.ndarray:
    """(W,) metres: for each wall k of the true ``room`` (its order), the distance from the true
    wall's centroid to the estimated plane whose normal is nearest (n . p_k - o); inf when no
    estimated normal is within ``max_angle`` degrees (the wall was not found).

    ``wall_normals`` (K, 3) outward unit normals and ``wall_offsets`` (K,) of the estimate, in any
    order; K may differ from W.
    """
    normals = as_points(wall_normals, "wall_normals", dim=room.dim)
    offsets = as_float_array(wall_offsets, "wall_offsets")
    if offsets.shape != (len(normals),):
        raise InvalidInputError(
            f"wall_offsets must have shape ({len(normals)},); got {shape_str(offsets.shape)}"
        )
    out = np.full(room.n_walls, np.inf)
    for k, (n_true, p) in enumerate(zip(room.normals, room.wall_centroids, strict=True)):
        cos = normals @ n_true
        j = int(np.argmax(cos))
        if cos[j] > np.cos(np.radians(max_angle)):
            out[k] = abs(normals[j] @ p - offsets[j])
    return out


def walk_plane(trajectory: ArrayLike, *, rtol: float = 1e-6) -> tuple[np.ndarray, float] | None:
    """(unit normal (3,), offset) of the plane a 3-D trajectory (M, 3) lies in, or None when it
    is not planar (its third singular value above ``rtol`` times its first)."""
    traj = as_points(trajectory, "trajectory", min_points=3)
    if traj.shape[1] != 3:
        return None
    centre = traj.mean(axis=0)
    _, sv, vt = np.linalg.svd(traj - centre, full_matrices=False)
    if sv[-1] > rtol * sv[0]:
        return None
    return vt[-1], float(vt[-1] @ centre)


def landmark_errors(
    landmarks: ArrayLike,
    true_landmarks: ArrayLike,
    alignment: Alignment,
    *,
    plane: tuple[np.ndarray, float] | None = None,
) -> np.ndarray:
    """(K,) metres: each estimated landmark (K, d) moved by ``alignment`` (the trajectory's, onto
    the truth), to the nearest of ``true_landmarks`` (J, d). A walk in a ``plane`` (normal,
    offset) hears a point and its mirror image in that plane alike, so each landmark is taken up
    to that mirror image (as :func:`rangeslam.evaluation.metrics.planar_source_error`)."""
    got = alignment.apply(landmarks)
    truth = as_points(true_landmarks, "true_landmarks", dim=got.shape[1])
    candidates = [got]
    if plane is not None:
        n, o = np.asarray(plane[0], dtype=float), float(plane[1])
        candidates.append(got - 2.0 * np.outer(got @ n - o, n))
    dist = [
        np.linalg.norm(g[:, None, :] - truth[None, :, :], axis=2).min(axis=1) for g in candidates
    ]
    return np.min(dist, axis=0)
