"""Simulated experiments as library functions; the CLI and the benchmarks only call and print them.

``room_experiment`` is Problem 1 end to end: a room, a random array and loudspeakers, simulated
echo ranges with noise and wrong picks, the reconstruction, and its errors against the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import Room
from .room_reconstruction import RoomReconstruction, reconstruct_room
from .simulation import add_outliers, add_range_noise, echo_ranges, random_points_in_room

__all__ = ["RoomExperiment", "demo_rooms", "room_experiment", "wall_errors"]


@dataclass(frozen=True)
class RoomExperiment:
    """A simulated Problem 1 instance and its reconstruction.

    Attributes:
        room: the true room.
        mics: (M, d) true (and known) microphone positions.
        sources: (J, d) true loudspeaker positions.
        ranges: J noisy range matrices (M, 1+K) given to the solver.
        outliers: J boolean matrices (M, 1+K), True where a wrong pick was injected.
        result: the reconstruction.
        offset_errors: (K,) distance from each true wall centroid to the estimated plane, metres.
        normal_errors_deg: (K,) angle between estimated and true normals, degrees.
        source_errors: (J,) loudspeaker position errors, metres.
    """

    room: Room
    mics: np.ndarray
    sources: np.ndarray
    ranges: tuple[np.ndarray, ...]
    outliers: tuple[np.ndarray, ...]
    result: RoomReconstruction
    offset_errors: np.ndarray
    normal_errors_deg: np.ndarray
    source_errors: np.ndarray


def wall_errors(
    room: Room, normals: np.ndarray, offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Offset errors (K,) in metres and normal angle errors (K,) in degrees, walls in the same order.

    The offset error of wall k is the distance from the true wall's centroid p_k (the paper's
    description of a wall by n_k and p_k) to the estimated plane, |n_k_est . p_k - o_k_est|: the
    offset where the wall is, independent of where the coordinate origin happens to be.
    """
    cos = np.clip(np.einsum("kd,kd->k", normals, room.normals), -1.0, 1.0)
    offset_err = np.abs(np.einsum("kd,kd->k", normals, room.wall_centroids) - offsets)
    return offset_err, np.degrees(np.arccos(cos))


def room_experiment(
    room: Room,
    *,
    n_mics: int = 8,
    n_sources: int = 1,
    sigma: float = 1e-3,
    outlier_fraction: float = 0.0,
    margin: float = 0.3,
    rng=None,
) -> RoomExperiment:
    """Draw microphones and loudspeakers uniformly in ``room`` (``margin`` m from the walls), simulate
    first-order echo ranges with N(0, sigma^2) noise and a fraction of wrong picks, reconstruct."""
    rng = np.random.default_rng(rng)
    mics = random_points_in_room(room, n_mics, margin=margin, rng=rng)
    sources = random_points_in_room(room, n_sources, margin=margin, rng=rng)
    ranges, outliers = [], []
    for s in sources:
        r = add_range_noise(echo_ranges(room, mics, s), sigma, rng=rng)
        r, out = add_outliers(r, outlier_fraction, rng=rng)
        ranges.append(r)
        outliers.append(out)
    result = reconstruct_room(mics, ranges, rng=rng)
    off, ang = wall_errors(room, result.wall_normals, result.wall_offsets)
    return RoomExperiment(
        room=room,
        mics=mics,
        sources=sources,
        ranges=tuple(ranges),
        outliers=tuple(outliers),
        result=result,
        offset_errors=off,
        normal_errors_deg=ang,
        source_errors=np.linalg.norm(result.sources - sources, axis=1),
    )


def demo_rooms() -> dict[str, Room]:
    """The rooms of ``rangeslam demo``: the paper's Fig. 3 shoebox and a non-box convex room."""
    # A 5.1 x 3.7 x 2.6 m shoebox with one corner cut by a slanted wall and a sloping ceiling.
    normals = np.array(
        [
            [-1, 0, 0],
            [1, 0, 0],
            [0, -1, 0],
            [0, 1, 0],
            [0, 0, -1],
            [0.0, 0.25, 1.0],
            [1.0, 1.0, 0.0],
        ]
    )
    points = np.array(
        [[0, 0, 0], [5.1, 0, 0], [0, 0, 0], [0, 3.7, 0], [0, 0, 0], [0, 0, 2.6], [4.3, 3.7, 0]]
    )
    return {
        "shoebox": Room.shoebox([5.1, 3.7, 2.6]),
        "cut corner": Room.from_planes(normals, points),
    }
