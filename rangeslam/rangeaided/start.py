"""Starting values for a range-aided SLAM problem: dead reckoning per robot, landmarks from
the observations or the ranges. Pure numpy.

The odometry start: each robot's trajectory is its odometry chain composed from a first pose.
Nothing in the measurements places one robot relative to another before solving, so the first
poses are an input: by default the problem's reference first pose of each robot (the usual
protocol of the CORA benchmark's odometry initialisation; the only use of the reference), or any
(R, 3) / (R, 7) the caller gives.
"""

from __future__ import annotations

import itertools

import numpy as np

from rangeslam.errors import InvalidInputError
from rangeslam.rangeaided.poses import dead_reckoning, positions, transform_points
from rangeslam.rangeaided.problem import RangeAidedProblem, pose_width

__all__ = ["first_poses", "landmark_start", "odometry_start"]


def first_poses(problem: RangeAidedProblem, given=None) -> np.ndarray:
    """(R, 3) or (R, 7) each robot's first pose: ``given``, else the reference's."""
    shape = (len(problem.robots), pose_width(problem.dim))
    if given is None:
        if problem.truth_poses is None:
            raise InvalidInputError(
                "first_poses: the problem has no reference poses; give each robot's first pose"
            )
        return np.array([problem.truth_poses[problem.robot_rows(r)[0]] for r in range(shape[0])])
    arr = np.asarray(given, dtype=float)
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"first_poses must be finite with shape {shape}; got {arr.shape}")
    return arr


def odometry_start(problem: RangeAidedProblem, first=None) -> tuple[np.ndarray, int]:
    """((P, 3) or (P, 7) poses, gaps): each robot's odometry steps (pose k to pose k + 1 of its
    trajectory) composed from its first pose (:func:`first_poses`). A step missing from the
    chain (``gaps`` counts them) holds the pose (a zero step)."""
    start = first_poses(problem, first)
    o = problem.odometry
    step_of = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(o.pose_a, o.pose_b, strict=True))}
    zero = np.zeros(pose_width(problem.dim))
    if problem.dim == 3:
        zero[6] = 1.0
    out = np.empty((problem.n_poses, pose_width(problem.dim)))
    gaps = 0
    for r in range(len(problem.robots)):
        rows = problem.robot_rows(r)
        steps = np.empty((len(rows) - 1, len(zero)))
        for i, (a, b) in enumerate(itertools.pairwise(rows)):
            k = step_of.get((int(a), int(b)))
            gaps += k is None
            steps[i] = zero if k is None else o.values[k]
        out[rows] = dead_reckoning(start[r : r + 1], steps)
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
    """(L, d) landmarks from ``poses``: the mean of the relative observations moved into the
    world, else linear multilateration from the positions that ranged to it (the anchors must
    span the space; a straight path leaves a mirror choice, taken as lstsq gives it), else the
    mean of those positions, else the prior, else the origin. The reference is not used."""
    d = problem.dim
    out = np.zeros((problem.n_landmarks, d))
    s, r, lp = problem.landmark_observations, problem.ranges, problem.landmark_priors
    seen = transform_points(poses[s.pose], s.values) if len(s.time) else np.zeros((0, d))
    pos = positions(poses)
    for j in range(problem.n_landmarks):
        mine = s.landmark == j
        ranged = r.to_landmark & (r.other == j)
        if np.any(mine):
            out[j] = seen[mine].mean(axis=0)
        elif np.any(ranged):
            point = _multilaterate(pos[r.pose[ranged]], r.ranges[ranged])
            out[j] = pos[r.pose[ranged]].mean(axis=0) if point is None else point
        elif np.any(lp.landmark == j):
            out[j] = lp.values[np.argmax(lp.landmark == j)]
    return out
