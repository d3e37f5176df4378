"""The regime map of zero-knowledge calibration (Problem 2): ``calibrate`` against its peers.

A cell: the scene (the paper's Fig. 3 setting: 6 microphones in a 1 m cube at the centre of a
shoebox and a loudspeaker with its 5 first-order images nearest them; or 12 microphones and 12
sources uniform in a random convex room), the range noise, and a fraction of wrong picks. Methods
on the same ranges:

- "calibrate": :func:`rangeslam.calibrate` (convex iteration, eqs. 8-10, then least squares);
- "trace_min": the EDM completion by trace minimisation alone (one SDP, Z = I), embedded;
- "ls_1": least squares on the ranges (GTSAM's range factors) from one random start, points
  uniform in a box of the largest range;
- "ls_k": the same from random starts until it has used the wall time of "calibrate", the
  lowest final cost kept.

Every method is told the noise level; with wrong picks the least-squares methods use a Huber
kernel and ``calibrate`` its own robust path. Per trial: the receivers' RMS error after the best
rigid motion with reflection, the receiver-gauge Cramer-Rao bound, wall time.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from rangeslam.app.regimes import MethodRun
from rangeslam.errors import InvalidInputError, RangeSlamError

__all__ = [
    "CALIBRATION_METHODS",
    "CalibrationCell",
    "calibration_cells",
    "calibration_scene",
    "run_calibration_trial",
]

CALIBRATION_METHODS = ("calibrate", "trace_min", "ls_1", "ls_k")
SCENES = ("fig3", "12x12")
#: Receiver RMS error under which a calibration counts as a success, metres.
CALIBRATION_SUCCESS_M = 0.05


@dataclass(frozen=True)
class CalibrationCell:
    """One calibration regime: ``scene`` "fig3" or "12x12", range noise ``sigma`` (metres),
    fraction ``wrong`` of wrong picks (0.2-1 m)."""

    scene: str
    sigma: float
    wrong: float = 0.0

    def __post_init__(self) -> None:
        if self.scene not in SCENES:
            raise InvalidInputError(f"scene must be one of {SCENES}; got {self.scene!r}")
        if not (np.isfinite(self.sigma) and self.sigma > 0):
            raise InvalidInputError(f"sigma must be positive and finite; got {self.sigma!r}")
        if not 0.0 <= self.wrong < 1.0:
            raise InvalidInputError(f"wrong must be in [0, 1); got {self.wrong!r}")

    @property
    def label(self) -> str:
        """E.g. "12x12, 10 mm, 5% wrong"."""
        text = f"{self.scene}, {self.sigma * 1000:g} mm"
        return text + (f", {100 * self.wrong:g}% wrong" if self.wrong else "")

    def spawn_key(self, trial: int) -> tuple[int, ...]:
        """The trial's key in the run's SeedSequence."""
        return (
            7,
            SCENES.index(self.scene),
            round(self.sigma * 1e9),
            round(1000 * self.wrong),
            trial,
        )


def calibration_cells(sigmas=(1e-3, 1e-2)) -> list[CalibrationCell]:
    """Both scenes at each sigma, and at the largest sigma with 5% wrong picks."""
    cells = [CalibrationCell(scene, float(s)) for scene in SCENES for s in sigmas]
    return cells + [CalibrationCell(scene, float(max(sigmas)), 0.05) for scene in SCENES]


def calibration_scene(cell: CalibrationCell, rng: np.random.Generator):
    """(receivers (M, 3), sources (K, 3), noisy ranges (M, K)) of one trial of ``cell``."""
    from rangeslam.app.experiments import fig3_scene
    from rangeslam.geometry.edm import range_matrix
    from rangeslam.sim.scenes import (
        add_outliers,
        add_range_noise,
        random_convex_room,
        random_points_in_room,
    )

    if cell.scene == "fig3":
        scene = fig3_scene(rng)
        receivers, sources = scene.mics, scene.sources
    else:
        room = random_convex_room(3, 6, rng=rng)
        receivers = random_points_in_room(room, 12, margin=0.2, rng=rng)
        sources = random_points_in_room(room, 12, margin=0.2, rng=rng)
    ranges = add_range_noise(range_matrix(receivers, sources), cell.sigma, rng=rng)
    if cell.wrong:
        ranges, _ = add_outliers(ranges, cell.wrong, min_error=0.2, max_error=1.0, rng=rng)
    return receivers, sources, ranges


def run_calibrate(ranges: np.ndarray, cell: CalibrationCell, rng) -> MethodRun:
    """:func:`rangeslam.calibrate` with the noise level told."""
    from rangeslam.mdu.calibration import calibrate

    t0 = time.perf_counter()
    try:
        out = calibrate(ranges, noise_std=cell.sigma, rng=rng)
    except RangeSlamError as exc:
        return lost_run(ranges, time.perf_counter() - t0, exc)
    status = "ok" if out.converged else f"flagged: {out.status.name}"
    seconds = time.perf_counter() - t0
    return MethodRun(np.asarray(out.receivers), np.asarray(out.sources), seconds, status=status)


def lost_run(ranges: np.ndarray, seconds: float, exc: BaseException) -> MethodRun:
    """A method that raised: NaN points, the exception's first line as its status."""
    m, k = ranges.shape
    why = f"{type(exc).__name__}: {exc}".splitlines()[0][:200]
    return MethodRun(np.full((m, 3), np.nan), np.full((k, 3), np.nan), seconds, status=why)


def run_trace_min(ranges: np.ndarray) -> MethodRun:
    """The EDM completion by trace minimisation alone (one SDP), embedded in 3-D."""
    from rangeslam.mdu.core import mdu_edm, mdu_mask
    from rangeslam.solvers.sdp import complete_edm

    m = ranges.shape[0]
    t0 = time.perf_counter()
    try:
        scale = float(np.median(ranges))
        w = mdu_mask(np.ones(ranges.shape, dtype=bool))
        out = complete_edm(mdu_edm(ranges / scale), w, 3, method="trace_min")
    except RangeSlamError as exc:
        return lost_run(ranges, time.perf_counter() - t0, exc)
    points = scale * np.asarray(out.points)
    return MethodRun(points[:m], points[m:], time.perf_counter() - t0)


def least_squares_starts(
    ranges: np.ndarray, cell: CalibrationCell, rng, budget: float, max_starts: int
) -> MethodRun:
    """Least squares (GTSAM's range factors, Huber with wrong picks) from random starts, points
    uniform in a box of the largest range, until ``budget`` seconds are used (at least one start,
    at most ``max_starts``); the lowest final cost wins."""
    from rangeslam.errors import SolverError
    from rangeslam.solvers.gtsam_graph import refine_graph

    m, k = ranges.shape
    size = float(np.max(ranges))
    t0 = time.perf_counter()
    best, iterations, starts = None, 0, 0
    while starts < max_starts and (starts == 0 or time.perf_counter() - t0 < budget):
        starts += 1
        x0, s0 = rng.uniform(-size, size, (m, 3)), rng.uniform(-size, size, (k, 3))
        try:
            fit = refine_graph(
                x0, s0, ranges, noise_std=cell.sigma, robust="huber" if cell.wrong else None,
                covariances=False, max_iterations=5000,
            )  # fmt: skip
        except SolverError:
            continue
        iterations += fit.iterations
        if fit.converged and (best is None or fit.error < best.error):
            best = fit
    seconds = time.perf_counter() - t0
    if best is None:
        lost = lost_run(ranges, seconds, RangeSlamError("least squares failed from every start"))
        return MethodRun(lost.receivers, lost.sources, seconds, iterations, starts, lost.status)
    return MethodRun(best.receivers, best.sources, seconds, float(iterations), starts)


def calibration_oracle_error(receivers, sources, ranges, cell: CalibrationCell) -> float:
    """The oracle's receiver error, metres: least squares on the ``ranges`` (M, K) (Huber at its
    95%-efficiency scale with wrong picks) from the true ``receivers`` (M, d) and
    ``sources`` (K, d); 0 without noise."""
    from rangeslam._robust import ROBUST_KERNEL_CONSTANTS
    from rangeslam.geometry.alignment import align
    from rangeslam.solvers.least_squares import refine_unfolding

    if cell.sigma <= 0:
        return 0.0
    mask = np.isfinite(ranges)
    scale = ROBUST_KERNEL_CONSTANTS["huber"] * cell.sigma
    loss = {"loss": "huber", "loss_scale": scale} if cell.wrong else {}
    fit = refine_unfolding(receivers, sources, np.nan_to_num(ranges), mask, **loss)
    return align(fit.receivers, receivers, reflection=True).rmse


def run_calibration_trial(
    cell: CalibrationCell, trial: int, seed: int, *, max_starts: int = 200
) -> dict:
    """Every calibration method on one scene of ``cell``: a row with the cell's values, the
    bound (``crlb_m``) and per method its receiver error, success, time, iterations, starts and
    status."""
    from rangeslam.app.experiments import receiver_crlb
    from rangeslam.geometry.alignment import align

    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=cell.spawn_key(trial)))
    receivers, sources, ranges = calibration_scene(cell, rng)
    row = {"regime": cell.label, **asdict(cell), "trial": trial, "seed": seed, "status": "ok"}
    row["crlb_m"] = receiver_crlb(receivers, sources, cell.sigma)
    row["oracle_error_m"] = calibration_oracle_error(receivers, sources, ranges, cell)
    full = run_calibrate(ranges, cell, rng)
    runs = {
        "calibrate": full,
        "trace_min": run_trace_min(ranges),
        "ls_1": least_squares_starts(ranges, cell, rng, 0.0, 1),
        "ls_k": least_squares_starts(ranges, cell, rng, full.seconds, max_starts),
    }
    for name, run in runs.items():
        ok = np.all(np.isfinite(run.receivers))
        error = align(run.receivers, receivers, reflection=True).rmse if ok else float("nan")
        row.update(
            {
                f"{name}_error_m": error,
                f"{name}_success": bool(np.isfinite(error) and error < CALIBRATION_SUCCESS_M),
                f"{name}_seconds": run.seconds,
                f"{name}_iterations": run.iterations,
                f"{name}_starts": run.starts,
                f"{name}_status": run.status,
            }
        )
    return row
