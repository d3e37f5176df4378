"""Receiver trajectories for simulation: the paper's lemniscate (eq. 12), smooth paths, random walks.

Every function returns positions as rows, shape (M, d), in metres. Random ones take ``rng``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline

from rangeslam._validation import as_dim, as_float_array, as_points, as_rng, as_scalar
from rangeslam.errors import InvalidInputError
from rangeslam.geometry.room import Room

__all__ = ["lemniscate", "random_walk", "smooth_path", "step_lengths"]


# The longest simulated trajectory (an (n, 3) float64 array of 10^7 rows is 240 MB).
MAX_STEPS = 10_000_000


def _check_count(n: int, name: str, minimum: int = 1) -> int:
    return as_scalar(
        n, name, low=minimum, high=MAX_STEPS, integer=True,
        expected=f"an integer >= {minimum} (at most {MAX_STEPS})",
    )  # fmt: skip


def _check_positive(x: float, name: str) -> float:
    return as_scalar(x, name, low=0.0, low_open=True, expected="a positive finite number")


def lemniscate(
    n_steps: int,
    *,
    step: float = 0.3,
    phase: float = 0.0,
    centre: ArrayLike = (2.0, 2.0),
    half_width: float = 1.5,
    height: float = 0.9,
    dim: int = 3,
) -> np.ndarray:
    """Positions on the lemniscate of eq. (12) at parameters t_n = phase + step * n, n = 0..n_steps-1.

    x = cx + a cos t / (1 + sin^2 t), y = cy + sin t cos t / (1 + sin^2 t), z = height, with the
    paper's values cx = cy = 2 m, a = 1.5 m, z = 0.9 m as defaults (the y amplitude is 1 m in
    eq. 12 and stays so). With step 0.3 the steps are about 30 cm long. Shape (n_steps, dim).
    """
    n_steps = _check_count(n_steps, "n_steps")
    step = _check_positive(step, "step")
    half_width = _check_positive(half_width, "half_width")
    dim = as_dim(dim)
    c = as_float_array(centre, "centre")
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise InvalidInputError(f"centre must be 2 finite numbers, shape (2,); got {c!r:.80}")
    phase = as_scalar(phase, "phase")
    height = as_scalar(height, "height")
    t = phase + step * np.arange(n_steps)
    den = 1.0 + np.sin(t) ** 2
    x = c[0] + half_width * np.cos(t) / den
    y = c[1] + np.sin(t) * np.cos(t) / den
    if dim == 2:
        return np.column_stack([x, y])
    return np.column_stack([x, y, np.full(n_steps, float(height))])


def step_lengths(trajectory: ArrayLike) -> np.ndarray:
    """(M-1,) distances between consecutive positions of a trajectory (M, d)."""
    traj = as_points(trajectory, "trajectory", min_points=2)
    return np.linalg.norm(np.diff(traj, axis=0), axis=1)


def smooth_path(
    waypoints: ArrayLike,
    n_steps: int,
    *,
    step_length: float | None = None,
) -> np.ndarray:
    """Points along a cubic spline through ``waypoints`` (W, d), equally spaced in arc length.

    With ``step_length`` the points are that far apart along the curve from the first waypoint
    (raises if the curve is too short); otherwise the ``n_steps`` points span the whole curve.
    """
    wp = as_points(waypoints, "waypoints", min_points=2)
    n_steps = _check_count(n_steps, "n_steps", 2)
    chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(wp, axis=0), axis=1))])
    if np.any(np.diff(chord) <= 0):
        raise InvalidInputError("waypoints must not repeat consecutively")
    spline = CubicSpline(chord, wp, bc_type="natural")
    fine = np.linspace(0.0, chord[-1], 200 * len(wp) + 20 * n_steps)
    pts = spline(fine)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    if step_length is None:
        targets = np.linspace(0.0, arc[-1], n_steps)
    else:
        step_length = _check_positive(step_length, "step_length")
        targets = step_length * np.arange(n_steps)
        if targets[-1] > arc[-1]:
            raise InvalidInputError(
                f"the path through the waypoints is {arc[-1]:.3f} m long, too short for "
                f"{n_steps} steps of {step_length} m"
            )
    params = np.interp(targets, arc, fine)
    return spline(params)


def random_walk(
    n_steps: int,
    *,
    start: ArrayLike,
    step_length: float = 0.3,
    step_jitter: float = 0.0,
    turn_std: float = 0.3,
    room: Room | None = None,
    margin: float = 0.3,
    rng: np.random.Generator | int | None = None,
) -> np.ndarray:
    """A correlated random walk (M, d) from ``start`` with smoothly changing heading.

    Each step has length ``step_length * (1 + step_jitter * N(0, 1))`` (kept positive) and turns the
    heading by a normal angle of std ``turn_std`` rad (in 3-D a random small rotation of the
    direction). With a ``room`` the walk stays ``margin`` metres inside it: a step that would leave is
    re-drawn with a new random heading (up to 1000 times, then an error).
    """
    rng = as_rng(rng)
    n_steps = _check_count(n_steps, "n_steps")
    step_length = _check_positive(step_length, "step_length")
    start_pt = as_points(np.atleast_2d(as_float_array(start, "start")), "start", min_points=1)[0]
    step_jitter = as_scalar(step_jitter, "step_jitter", low=0.0)
    turn_std = as_scalar(turn_std, "turn_std", low=0.0)
    margin = as_scalar(margin, "margin")
    if room is not None and not isinstance(room, Room):
        raise InvalidInputError(f"room must be a Room or None; got {type(room).__name__}")
    d = start_pt.shape[0]
    if room is not None:
        if room.dim != d:
            raise InvalidInputError(f"start has dimension {d} but room has dimension {room.dim}")
        if not room.contains(start_pt[None, :], margin=margin)[0]:
            raise InvalidInputError(
                f"start {start_pt.tolist()} must be at least {margin} m inside the room"
            )
    heading = rng.normal(size=d)
    heading /= np.linalg.norm(heading)
    out = np.empty((n_steps, d))
    out[0] = start_pt
    for i in range(1, n_steps):
        for _attempt in range(1000):
            new_heading = heading + turn_std * rng.normal(size=d)
            new_heading /= np.linalg.norm(new_heading)
            length = step_length * max(0.05, 1.0 + step_jitter * rng.normal())
            candidate = out[i - 1] + length * new_heading
            if room is None or room.contains(candidate[None, :], margin=margin)[0]:
                break
            heading = rng.normal(size=d)
            heading /= np.linalg.norm(heading)
        else:
            raise InvalidInputError(
                "random_walk could not stay inside the room; reduce step_length or margin"
            )
        heading = new_heading
        out[i] = candidate
    return out
