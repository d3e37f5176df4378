"""Starting values for a range-aided SLAM problem: dead reckoning per robot, landmarks from
the observations or the ranges. Pure numpy; the reference (truth) values are never read here.

The odometry start: each robot's trajectory is its odometry chain composed from a first pose,
(R, 3) / (R, 7) rows the caller gives: the data's own placement
(:func:`rangeslam.rangeaided.placement.place_robots`), or first poses a user knows.
"""

from __future__ import annotations

import itertools

import numpy as np

from rangeslam.errors import InvalidInputError
from rangeslam.rangeaided.poses import dead_reckoning, positions, transform_points
from rangeslam.rangeaided.problem import RangeAidedProblem, pose_width

__all__ = ["first_poses", "identity_pose", "landmark_start", "located_landmarks", "odometry_start"]


def identity_pose(dim: int) -> np.ndarray:
    """(3,) or (7,) the identity pose: (0, 0, 0) in 2-D, (0, 0, 0, 0, 0, 0, 1) in 3-D."""
    out = np.zeros(pose_width(dim))
    if dim == 3:
        out[6] = 1.0
    return out


def first_poses(problem: RangeAidedProblem, given) -> np.ndarray:
    """(R, 3) or (R, 7) each robot's first pose ``given`` (validated: finite, one row a robot;
    2-D (x [m], y [m], theta [rad]), 3-D (x, y, z [m], qx, qy, qz, qw))."""
    shape = (len(problem.robots), pose_width(problem.dim))
    arr = np.asarray(given, dtype=float)
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"first_poses must be finite with shape {shape}; got {arr.shape}")
    return arr


def odometry_start(problem: RangeAidedProblem, first, steps=None) -> tuple[np.ndarray, int]:
    """((P, 3) or (P, 7) poses, gaps): each robot's odometry steps (pose k to pose k + 1 of its
    trajectory) composed from its first pose ``first`` ((R, w), :func:`first_poses`). A step
    missing from the chain (``gaps`` counts them) holds the pose (a zero step). ``steps``: (M, w)
    relative poses to use instead of ``problem.odometry.values`` (a perturbed start)."""
    start = first_poses(problem, first)
    o = problem.odometry
    values = o.values if steps is None else np.asarray(steps, dtype=float)
    step_of = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(o.pose_a, o.pose_b, strict=True))}
    zero = identity_pose(problem.dim)
    out = np.empty((problem.n_poses, pose_width(problem.dim)))
    gaps = 0
    for r in range(len(problem.robots)):
        rows = problem.robot_rows(r)
        steps_ = np.empty((len(rows) - 1, len(zero)))
        for i, (a, b) in enumerate(itertools.pairwise(rows)):
            k = step_of.get((int(a), int(b)))
            gaps += k is None
            steps_[i] = zero if k is None else values[k]
        out[rows] = dead_reckoning(start[r : r + 1], steps_)
    return out, gaps


def _multilaterate(anchors: np.ndarray, ranges: np.ndarray) -> np.ndarray | None:
    """The point at ``ranges`` (n,) from ``anchors`` (n, d) by linear least squares on the
    differences of squared ranges; None when the anchors do not span the space."""
    if len(anchors) < anchors.shape[1] + 1:
        return None
    a0, r0 = anchors.mean(axis=0), np.mean(ranges**2)
    design = 2 * (anchors - a0)
    rhs = (np.sum(anchors**2, axis=1) - np.sum(a0**2)) - (ranges**2 - r0)
    rhs -= np.mean(rhs)  # |x - a_i|^2 = r_i^2 minus its mean over i: linear in x
    sol, _, rank, _ = np.linalg.lstsq(design, rhs, rcond=None)
    if rank < anchors.shape[1]:
        return None
    return sol


def landmark_start(problem: RangeAidedProblem, poses: np.ndarray) -> np.ndarray:
    """(L, d) landmarks [m] from ``poses`` (P, w): :func:`located_landmarks` with every pose,
    and a landmark it cannot locate at the mean of the positions that ranged to it, else its
    prior, else the origin. The reference is not used."""
    out, known = located_landmarks(problem, poses, np.ones(problem.n_poses, bool))
    r = problem.ranges
    pos = positions(poses)
    for j in np.flatnonzero(~known):
        ranged = r.to_landmark & (r.other == j)
        if np.any(ranged):
            out[j] = pos[r.pose[ranged]].mean(axis=0)
    return out


def located_landmarks(
    problem: RangeAidedProblem, poses: np.ndarray, placed: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """((L, d) landmarks [m], (L,) located) from the poses ``placed`` ((P,) bool) of ``poses``
    (P, w): the mean of their relative observations moved into the world, else linear
    multilateration from their positions that ranged to it (d + 1 ranges at least, anchors that
    span the space; a straight path leaves a mirror choice, taken as lstsq gives it), else the
    problem's prior on it. Landmarks none of these locate are at the origin, ``located`` False."""
    d = problem.dim
    out = np.zeros((problem.n_landmarks, d))
    known = np.zeros(problem.n_landmarks, bool)
    s, r, lp = problem.landmark_observations, problem.ranges, problem.landmark_priors
    seen = transform_points(poses[s.pose], s.values) if len(s.time) else np.zeros((0, d))
    pos = positions(poses)
    for j in range(problem.n_landmarks):
        mine = (s.landmark == j) & placed[s.pose]
        ranged = r.to_landmark & (r.other == j) & placed[r.pose]
        point = _multilaterate(pos[r.pose[ranged]], r.ranges[ranged]) if np.any(ranged) else None
        if np.any(mine):
            out[j], known[j] = seen[mine].mean(axis=0), True
        elif point is not None:
            out[j], known[j] = point, True
        elif np.any(lp.landmark == j):
            out[j], known[j] = lp.values[np.argmax(lp.landmark == j)], True
    return out, known
