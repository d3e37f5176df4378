"""Yardsticks: Cramer-Rao bounds of the estimators' problems, and errors against ground truth."""

from __future__ import annotations

from rangeslam.evaluation.metrics import (
    ATTAINED_RTOL,
    SHOEBOX_WALLS,
    ApeStatistics,
    BoundComparison,
    PositionErrors,
    ape,
    ape_statistics,
    mean_nees,
    planar_source_error,
    rms_against_bound,
    shoebox_wall_errors,
    trajectory_nees,
    trajectory_rmse,
    wall_errors,
)
from rangeslam.verdict.crlb import MDUBound, mdu_crlb, multilateration_crlb, wall_crlb

__all__ = [
    "ATTAINED_RTOL",
    "SHOEBOX_WALLS",
    "ApeStatistics",
    "BoundComparison",
    "MDUBound",
    "PositionErrors",
    "ape",
    "ape_statistics",
    "mdu_crlb",
    "mean_nees",
    "multilateration_crlb",
    "planar_source_error",
    "rms_against_bound",
    "shoebox_wall_errors",
    "trajectory_nees",
    "trajectory_rmse",
    "wall_crlb",
    "wall_errors",
]
