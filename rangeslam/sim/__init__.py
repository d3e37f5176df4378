"""Simulation: scenes with noisy ranges, trajectories (eq. 12) and room impulse responses."""

from __future__ import annotations

from rangeslam.sim.rir import room_rirs, shoebox_rirs
from rangeslam.sim.scenes import (
    add_outliers,
    add_range_noise,
    echo_ranges,
    random_convex_room,
    random_mask,
    random_points_in_room,
    range_matrix,
)
from rangeslam.sim.trajectories import lemniscate, random_walk, smooth_path, step_lengths

__all__ = [
    "add_outliers",
    "add_range_noise",
    "echo_ranges",
    "lemniscate",
    "random_convex_room",
    "random_mask",
    "random_points_in_room",
    "random_walk",
    "range_matrix",
    "room_rirs",
    "shoebox_rirs",
    "smooth_path",
    "step_lengths",
]
