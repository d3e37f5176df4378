"""Each robot's first pose from the data alone, never from the reference values.

The gauge: the file's priors when it has them (a robot with a prior on one of its poses is
placed by it: its odometry chain run back from there), else robot A's first pose at the origin.
Every other robot's first pose is an unknown rigid motion of its dead-reckoned chain (SE(2): 3
numbers, SE(3): 6), placed in turn (the robot with the most links first) from the measurements
it shares with what is placed already: ranges to placed robots' poses, ranges to landmarks the
placed robots locate (d + 1 ranges or an observation: :func:`rangeslam.rangeaided.start.
located_landmarks`), relative observations of those landmarks. The rigid motion is found by a
small search: least squares (scipy, the robust soft-L1 loss at level_sigmas() whitened units, as
the chain drifts) from a grid of headings (12 in 2-D; in 3-D 12 yaws and 12 random rotations)
times a translation that lays the linked ends' centroids on each other, offset by the median
range in each axis direction; the lowest cost is kept, the other distinct minima (outside the
kept one's confidence region, :func:`rangeslam.verdict.judge.distance_level`) are returned as
alternatives for the judge. A robot nothing links to what is placed is not placed (left at the
origin) and says so: the data do not say where it is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from rangeslam.rangeaided.poses import compose, positions, relative, transform_points
from rangeslam.rangeaided.problem import RangeAidedProblem, tangent_width
from rangeslam.rangeaided.start import (
    first_poses,
    identity_pose,
    located_landmarks,
    odometry_start,
)
from rangeslam.verdict.checks import level_sigmas
from rangeslam.verdict.judge import distance_level

__all__ = ["HEADINGS", "Links", "Placement", "anchors", "links", "place_robots", "rigid_fit"]

#: Headings of the placement search's grid in 2-D (and yaws in 3-D, with as many random
#: rotations): 30 degrees apart, so one start lies within 15 degrees of any heading.
HEADINGS = 12


@dataclass(frozen=True)
class Placement:
    """Each robot's first pose and where it came from.

    Attributes:
        first: (R, 3) or (R, 7) first poses (a robot not placed: the identity).
        placed: (R,) bool: the data (or the gauge, a prior, the user) placed the robot.
        how: (R,) in words, how each robot was placed (or why not).
        options: (R,) per robot, the other distinct minima of its search, (k, w) first poses,
            best first (empty when it was not searched).
        anchored: (R,) bool: placed by the gauge, a prior or the user (not searched).
    """

    first: np.ndarray
    placed: np.ndarray
    how: tuple[str, ...]
    options: tuple[np.ndarray, ...]
    anchored: np.ndarray

    def words(self, robots: tuple[str, ...]) -> str:
        """Each robot's placement in words, "A: ...; B: ..."."""
        return "; ".join(f"{name}: {how}" for name, how in zip(robots, self.how, strict=True))

    def unplaced_reason(self, robots: tuple[str, ...]) -> str:
        """Why some robots are not placed ('' when all are)."""
        loose = [robots[r] for r in np.flatnonzero(~self.placed)]
        if not loose:
            return ""
        return (f"robots {', '.join(loose)} share no range or landmark with the placed robots: "
                "the data do not say where they are (left at the origin)")  # fmt: skip


@dataclass(frozen=True)
class Links:
    """What ties one robot's dead-reckoned chain (its own frame) to placed things.

    Attributes:
        range_local, range_world: (n, d) the robot's ends in its frame, the other ends in the
            world [m]; ranges: (n,) [m]; range_sigma: (n,) [m].
        point_local, point_world: (m, d) landmarks the robot observes, in its frame and where
            the placed robots locate them [m]; point_sigma: (m,) [m] (RMS of the covariance).
    """

    range_local: np.ndarray
    range_world: np.ndarray
    ranges: np.ndarray
    range_sigma: np.ndarray
    point_local: np.ndarray
    point_world: np.ndarray
    point_sigma: np.ndarray

    @property
    def count(self) -> int:
        """Scalar measurements: ranges plus d per observation."""
        return len(self.ranges) + self.point_local.size


def anchors(problem: RangeAidedProblem, local: np.ndarray):
    """((R, w) first poses, (R,) anchored, how) of the gauge: a robot with a pose prior is
    placed by its first prior (its chain ``local`` (P, w), each robot from the identity, run
    back from there); without any prior in the problem, robot A at the origin."""
    n_r = len(problem.robots)
    first = np.tile(identity_pose(problem.dim), (n_r, 1))
    anchored = np.zeros(n_r, bool)
    how = ["not placed"] * n_r
    pp = problem.pose_priors
    for k in np.argsort(pp.time, kind="stable"):
        i = int(pp.pose[k])
        r = int(problem.pose_robot[i])
        if not anchored[r]:
            back = relative(local[i], identity_pose(problem.dim))
            first[r] = compose(pp.values[k : k + 1], back)[0]
            anchored[r] = True
            how[r] = f"from the file's prior on {problem.pose_names[i]}"
    if not len(pp.time) and not len(problem.landmark_priors.time):
        anchored[0] = True
        how[0] = "first pose at the origin (the gauge)"
    return first, anchored, how


def links(problem, robot: int, local, world, placed_pose, marks, located) -> Links:
    """The :class:`Links` of ``robot`` (an index): its ranges to poses ``placed_pose`` ((P,)
    bool) of ``world`` (P, w) and to landmarks ``located`` ((L,) bool) at ``marks`` (L, d), and
    its observations of those landmarks; ``local`` (P, w) the chains in their robots' frames."""
    r, s, mine = problem.ranges, problem.landmark_observations, problem.pose_robot == robot
    loc, wpos = positions(local), positions(world)
    other_pose = np.where(r.to_landmark, 0, r.other)
    other_ok = np.where(r.to_landmark, located[np.where(r.to_landmark, r.other, 0)],
                        placed_pose[other_pose] & ~mine[other_pose])  # fmt: skip
    forward = mine[r.pose] & other_ok
    backward = ~r.to_landmark & mine[other_pose] & placed_pose[r.pose] & ~mine[r.pose]
    far_end = np.where(r.to_landmark[:, None], marks[np.where(r.to_landmark, r.other, 0)],
                       wpos[other_pose])  # fmt: skip
    use = forward | backward
    here = np.where(forward[:, None], loc[r.pose], loc[other_pose])[use]
    there = np.where(forward[:, None], far_end, wpos[r.pose])[use]
    seen = mine[s.pose] & located[s.landmark]
    d = problem.dim
    pts = (
        transform_points(local[s.pose[seen]], s.values[seen]) if np.any(seen) else np.zeros((0, d))
    )
    sig = np.sqrt(np.trace(s.covariance[seen], axis1=1, axis2=2) / d)
    return Links(here, there, r.ranges[use], np.sqrt(r.variance[use]), pts,
                 marks[s.landmark[seen]], sig)  # fmt: skip


def _rigid(params: np.ndarray, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """(d, d) rotation and (d,) translation of search parameters (2-D: x, y, theta; 3-D:
    translation, rotation vector)."""
    if dim == 2:
        c, s = np.cos(params[2]), np.sin(params[2])
        return np.array([[c, -s], [s, c]]), params[:2]
    return Rotation.from_rotvec(params[3:]).as_matrix(), params[:3]


def _first_pose(params: np.ndarray, dim: int) -> np.ndarray:
    """The first pose row of search parameters."""
    if dim == 2:
        return np.array([params[0], params[1], np.arctan2(np.sin(params[2]), np.cos(params[2]))])
    q = Rotation.from_rotvec(params[3:]).as_quat()  # scalar last, as the rows
    return np.r_[params[:3], q * np.sign(q[3] if q[3] != 0 else 1.0)]


def _residuals(params: np.ndarray, link: Links, dim: int) -> np.ndarray:
    rot, t = _rigid(params, dim)
    ends = link.range_local @ rot.T + t
    res_r = (np.linalg.norm(ends - link.range_world, axis=1) - link.ranges) / link.range_sigma
    res_p = ((link.point_local @ rot.T + t) - link.point_world) / link.point_sigma[:, None]
    return np.concatenate([res_r, res_p.ravel()])


def _grid(link: Links, dim: int, rng) -> list[np.ndarray]:
    """Starts of the search: headings times centroid-matching translations (module docstring)."""
    local = np.vstack([link.range_local, link.point_local])
    world = np.vstack([link.range_world, link.point_world])
    yaws = 2 * np.pi * np.arange(HEADINGS) / HEADINGS
    if dim == 2:
        rotations = [np.array([0.0, 0.0, a]) for a in yaws]
    else:
        rotations = [np.array([0.0, 0.0, a]) for a in yaws]
        rotations += list(Rotation.random(HEADINGS, random_state=rng).as_rotvec())
    reach = float(np.median(link.ranges)) if len(link.ranges) else 0.0
    offsets = [np.zeros(dim)] + [reach * e for e in np.vstack([np.eye(dim), -np.eye(dim)])]
    starts = []
    for rv in rotations:
        params = np.r_[np.zeros(dim), rv] if dim == 3 else np.r_[0.0, 0.0, rv[2]]
        rot, _ = _rigid(params, dim)
        centre = world.mean(axis=0) - rot @ local.mean(axis=0)
        for off in offsets:
            params[:dim] = centre + off
            starts.append(params.copy())
    return starts


def rigid_fit(link: Links, dim: int, starts: list[np.ndarray]) -> list[tuple[float, np.ndarray]]:
    """(cost, first pose) of the distinct minima the least squares reach from ``starts``, lowest
    first: a minimum is another when it lies outside each kept one's confidence region (its
    parameter step in the kept one's Gauss-Newton information beyond distance_level(k))."""
    found = []
    for x0 in starts:
        fit = least_squares(_residuals, x0, args=(link, dim), loss="soft_l1",
                            f_scale=level_sigmas(), method="trf")  # fmt: skip
        found.append((float(fit.cost), fit.x, fit.jac))
    found.sort(key=lambda f: f[0])
    level = distance_level(tangent_width(dim))
    kept: list[tuple[float, np.ndarray, np.ndarray]] = []
    for cost, x, jac in found:
        if all(_far(x, y, info, dim) > level for _, y, info in kept):
            kept.append((cost, x, jac.T @ jac))
    return [(cost, _first_pose(x, dim)) for cost, x, _ in kept]


def _far(x: np.ndarray, y: np.ndarray, info: np.ndarray, dim: int) -> float:
    """Squared step from ``y`` to ``x`` (search parameters) in ``info``, the angle wrapped."""
    step = x - y
    if dim == 2:
        step[2] = np.arctan2(np.sin(step[2]), np.cos(step[2]))
    else:
        rel = Rotation.from_rotvec(y[3:]).inv() * Rotation.from_rotvec(x[3:])
        step[3:] = rel.as_rotvec()
    return float(step @ info @ step)


def place_robots(problem: RangeAidedProblem, *, first=None, rng=None, random_start=False):
    """The :class:`Placement` of every robot (module docstring); the reference is not read.

    Args:
        problem: the range-aided SLAM problem.
        first: (R, 3) or (R, 7) first poses the user knows (given data): taken as they are,
            nothing searched.
        rng: numpy Generator of the 3-D grid's random rotations and of random starts (default
            seeded 0).
        random_start: one start per robot, a uniform heading (3-D: rotation) and a translation
            uniform within the median range of the centroid-matching one, instead of the grid
            (the judge's random starts).
    """
    n_r = len(problem.robots)
    if first is not None:
        arr = first_poses(problem, first)
        return Placement(arr, np.ones(n_r, bool), ("given",) * n_r,
                         tuple(np.zeros((0, arr.shape[1])) for _ in range(n_r)),
                         np.ones(n_r, bool))  # fmt: skip
    rng = np.random.default_rng(0) if rng is None else rng
    local, _ = odometry_start(problem, np.tile(identity_pose(problem.dim), (n_r, 1)))
    first, anchored, how = anchors(problem, local)
    placed = anchored.copy()
    options = [np.zeros((0, first.shape[1])) for _ in range(n_r)]
    while not np.all(placed):
        world, _ = odometry_start(problem, first)
        on = placed[problem.pose_robot]
        marks, located = located_landmarks(problem, world, on)
        cand = {r: links(problem, r, local, world, on, marks, located)
                for r in np.flatnonzero(~placed)}  # fmt: skip
        robot = max(cand, key=lambda r: cand[r].count)
        link = cand[robot]
        if link.count == 0:
            break
        starts = _random_starts(link, problem.dim, rng) if random_start else _grid(
            link, problem.dim, rng)  # fmt: skip
        minima = rigid_fit(link, problem.dim, starts)
        first[robot], placed[robot] = minima[0][1], True
        options[robot] = np.array([m[1] for m in minima[1:]]).reshape(-1, first.shape[1])
        how[robot] = (f"placed from {len(link.ranges)} ranges and {len(link.point_local)} "
                      f"landmark observations ({len(minima)} distinct minima of "
                      f"{len(starts)} starts)")  # fmt: skip
    return Placement(first, placed, tuple(how), tuple(options), anchored)


def _random_starts(link: Links, dim: int, rng) -> list[np.ndarray]:
    """One random start of the search (:func:`place_robots`' ``random_start``)."""
    local = np.vstack([link.range_local, link.point_local])
    world = np.vstack([link.range_world, link.point_world])
    rv = Rotation.random(random_state=rng).as_rotvec() if dim == 3 else None
    params = np.r_[np.zeros(dim), rv] if dim == 3 else np.r_[0.0, 0.0, rng.uniform(-np.pi, np.pi)]
    rot, _ = _rigid(params, dim)
    reach = float(np.median(link.ranges)) if len(link.ranges) else 1.0
    params[:dim] = world.mean(axis=0) - rot @ local.mean(axis=0) + rng.uniform(-reach, reach, dim)
    return [params]
