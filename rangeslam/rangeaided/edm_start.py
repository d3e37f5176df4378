"""The EDM-windows start of a range-aided SLAM problem that is a beacon log (one robot in 2-D,
unicycle odometry, ranges to landmarks): the windowed EDM completion and stitching of
:func:`rangeslam.beacons.beacon_slam` (steps 2-3, :func:`rangeslam.beacons.windows.
edm_initialisation`) placed on the problem's own poses and landmarks, for GTSAM on the
problem's graph (:func:`rangeslam.rangeaided.gtsam_solve.solve_gtsam`). The reference values
are not read; the windows' noise settings are derived from the data, as beacon_slam's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rangeslam.errors import InvalidInputError
from rangeslam.rangeaided.problem import RangeAidedProblem
from rangeslam.rangeaided.start import landmark_start

__all__ = ["EdmStart", "edm_start", "edm_start_refusal"]


@dataclass(frozen=True)
class EdmStart:
    """``poses`` (P, 3) from ``first`` (3,) [m, rad], ``marks`` (L, 2) [m] (landmarks no window
    placed: from the start's poses by their ranges, as the odometry start does), ``notes`` of
    the windows in words."""

    poses: np.ndarray
    marks: np.ndarray
    notes: tuple[str, ...]


def _beacon_log(problem: RangeAidedProblem):
    """The problem as a :class:`rangeslam.beacons.RangeOdometry` when it has an EDM-windows
    start; InvalidInputError naming why not: it holds priors (the start fixes pose 0 in its own
    frame, the priors another) or it is not a beacon log."""
    from rangeslam.beacons import RangeOdometry

    if len(problem.pose_priors.time) or len(problem.landmark_priors.time):
        raise InvalidInputError("the problem holds priors (the EDM start's frame is pose 0's)")
    return RangeOdometry.from_problem(problem)


def edm_start_refusal(problem: RangeAidedProblem) -> str:
    """Why ``problem`` has no EDM-windows start, in words ("" when it has one)."""
    try:
        _beacon_log(problem)
    except InvalidInputError as exc:
        return str(exc)
    return ""


def edm_start(problem: RangeAidedProblem, first: np.ndarray | None = None) -> EdmStart:
    """The EDM-windows start of ``problem`` from the first pose ``first`` (3,) (default: the
    origin facing +x, the gauge).

    Raises:
        InvalidInputError: the problem has no such start (:func:`edm_start_refusal`).
        SolverError: no window places any landmark (beacon_slam's own failure).
    """
    from rangeslam.beacons.data import dead_reckoning
    from rangeslam.beacons.defaults import resolve_options
    from rangeslam.beacons.options import BeaconSlamOptions
    from rangeslam.beacons.windows import edm_initialisation

    try:
        data = _beacon_log(problem)
    except InvalidInputError as exc:
        raise InvalidInputError(f"problem has no EDM-windows start: {exc}") from exc
    start = np.zeros(3) if first is None else np.asarray(first, dtype=float)
    options = resolve_options(BeaconSlamOptions.from_settings({}), data)
    init = edm_initialisation(data, dead_reckoning(data.odometry, start), options)
    marks = landmark_start(problem, init.poses)
    marks[init.placed] = init.beacons[init.placed]
    return EdmStart(init.poses, marks, tuple(init.notes))
