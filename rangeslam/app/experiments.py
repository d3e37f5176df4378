"""Simulated experiments as library functions; the CLI and the benchmarks only call and print them.

``room_experiment`` is Problem 1 end to end: a room, a random array and loudspeakers, simulated
echo ranges with noise and wrong picks, the reconstruction, and its errors against the truth.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from rangeslam._validation import as_rng, check_int
from rangeslam.errors import DegenerateGeometryError, InvalidInputError, SolverError
from rangeslam.evaluation.metrics import (
    mean_nees,
    planar_source_error,
    trajectory_nees,
    wall_errors,
)
from rangeslam.geometry.alignment import align
from rangeslam.geometry.edm import range_matrix
from rangeslam.geometry.room import Room
from rangeslam.localization.room_reconstruction import RoomReconstruction, reconstruct_room
from rangeslam.mdu.calibration import Calibration, calibrate
from rangeslam.sim.scenes import add_outliers, add_range_noise, echo_ranges, random_points_in_room
from rangeslam.solvers.least_squares import refine_unfolding
from rangeslam.status import HasStatus, Status
from rangeslam.verdict.crlb import mdu_crlb

__all__ = [
    "CalibrationExperiment",
    "CalibrationScene",
    "RoomExperiment",
    "SlamExperiment",
    "calibration_experiment",
    "demo_rooms",
    "fig3_scene",
    "fig5_scene",
    "mean_nees",
    "receiver_crlb",
    "room_experiment",
    "slam_experiment",
    "wall_errors",
]

#: The shoebox of the paper's Fig. 3, metres.
FIG3_ROOM_SIZE = (5.1, 3.7, 2.6)


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
    rng = as_rng(rng)
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


@dataclass(frozen=True)
class CalibrationScene:
    """A zero-knowledge calibration instance (Fig. 3): microphones and the sources they hear.

    Attributes:
        room: the shoebox.
        mics: (M, 3) microphone positions, metres.
        loudspeaker: (3,) the real source.
        sources: (K, 3) the loudspeaker and its K - 1 image sources nearest the array's centroid.
        ranges: (M, K) noise-free ranges, metres.
    """

    room: Room
    mics: np.ndarray
    loudspeaker: np.ndarray
    sources: np.ndarray
    ranges: np.ndarray


def fig3_scene(
    rng: np.random.Generator,
    *,
    n_mics: int = 6,
    n_images: int = 5,
    cube: float = 1.0,
    room_size: tuple[float, float, float] = FIG3_ROOM_SIZE,
) -> CalibrationScene:
    """The Fig. 3 setup: ``n_mics`` microphones uniform in a ``cube``-metre cube at the centre of
    the shoebox, a loudspeaker uniform in the room, and its ``n_images`` first-order image sources
    nearest the array (higher orders are left out: in a shoebox, second-order images coincide in
    pairs, which would repeat a source)."""
    room = Room.shoebox(room_size)
    centre = np.asarray(room_size) / 2
    mics = centre + rng.uniform(-cube / 2, cube / 2, size=(n_mics, 3))
    loudspeaker = random_points_in_room(room, 1, rng=rng)[0]
    candidates = room.image_sources(loudspeaker, 1).positions
    dist = np.linalg.norm(candidates - mics.mean(axis=0), axis=1)
    sources = np.vstack([loudspeaker, candidates[np.argsort(dist)[:n_images]]])
    return CalibrationScene(room, mics, loudspeaker, sources, range_matrix(mics, sources))


@dataclass(frozen=True)
class CalibrationExperiment:
    """One simulated calibration and its errors against the truth.

    Attributes:
        scene: the true configuration.
        ranges: (M, K) noisy ranges given to the solver.
        sigma: range noise standard deviation, metres.
        result: what :func:`calibrate` returned.
        mic_error: RMS microphone error after the best rigid motion (with reflection), metres.
        mic_crlb: the receiver-gauge CRLB of that RMS error, metres (NaN at sigma = 0, inf when
            the configuration is flexible to first order).
        oracle_error: the oracle's microphone error, metres: :func:`calibrate`'s own cost (least
            squares on the ranges) minimised from the truth; what the search should reach.
        oracle_rms: the oracle's Monte-Carlo RMS error over fresh noise draws on the same scene,
            metres (NaN when none were asked for, 0 without noise).
    """

    scene: CalibrationScene
    ranges: np.ndarray
    sigma: float
    result: Calibration
    mic_error: float
    mic_crlb: float
    oracle_error: float
    oracle_rms: float


def _calibration_oracle(scene: CalibrationScene, ranges: np.ndarray) -> float:
    """RMS microphone error (metres) of least squares on ``ranges`` (M, K) from the truth."""
    oracle = refine_unfolding(scene.mics, scene.sources, ranges, np.ones(ranges.shape, bool))
    return align(oracle.receivers, scene.mics, reflection=True).rmse


def calibration_experiment(
    sigma: float, rng: np.random.Generator, *, oracle_draws: int = 0, **calibrate_options
) -> CalibrationExperiment:
    """A Fig. 3 scene, ranges with N(0, sigma^2) noise, :func:`calibrate`, and the error vs CRLB.

    ``calibrate_options`` go to :func:`calibrate` (noise_std defaults to sigma, rng to ``rng``).
    ``oracle_draws`` fresh noise draws on the same scene give the oracle's Monte-Carlo RMS error
    (``oracle_rms``), the figure its bound is checked against.
    """
    draws = check_int(oracle_draws, "oracle_draws", 0, 10_000)
    scene = fig3_scene(rng)
    ranges = add_range_noise(scene.ranges, sigma, rng=rng) if sigma > 0 else scene.ranges
    calibrate_options.setdefault("noise_std", sigma)
    calibrate_options.setdefault("rng", rng)
    result = calibrate(ranges, **calibrate_options)
    error = align(result.receivers, scene.mics, reflection=True).rmse
    bound = receiver_crlb(scene.mics, scene.sources, sigma)
    oracle_error = _calibration_oracle(scene, ranges) if sigma > 0 else 0.0
    mc = [_calibration_oracle(scene, add_range_noise(scene.ranges, sigma, rng=rng))
          for _ in range(draws if sigma > 0 else 0)]  # fmt: skip
    oracle_rms = float(np.sqrt(np.mean(np.square(mc)))) if mc else float("nan")
    if sigma <= 0 and draws:
        oracle_rms = 0.0
    return CalibrationExperiment(
        scene, ranges, sigma, result, error, bound, oracle_error, oracle_rms
    )


def receiver_crlb(receivers: np.ndarray, sources: np.ndarray, sigma: float, **priors) -> float:
    """Receiver-gauge CRLB of the RMS receiver error, metres, from the ranges and the ``priors``
    of :func:`rangeslam.evaluation.mdu_crlb` (step_bounds, step_prior, odometry_sigma): NaN at
    sigma = 0, inf when the configuration is flexible to first order (not identifiable)."""
    if sigma <= 0:
        return float("nan")
    try:
        return mdu_crlb(receivers, sources, sigma, **priors).receiver_rmse
    except DegenerateGeometryError:
        return float("inf")


#: The room of the paper's Fig. 5, metres.
FIG5_ROOM_SIZE = (5.0, 4.0, 2.6)


@dataclass(frozen=True)
class SlamExperiment(HasStatus):
    """One simulated Fig. 5 run: errors of the EDM answer, EDM + GTSAM, and GTSAM alone.

    Attributes:
        trajectory: (M, 3) true positions; landmarks: (7, 3) loudspeaker and first-order images.
        ranges: (M, 7) noisy ranges; sigma: their noise, metres; bounds: whether step bounds
            were given; step_bounds: (lower, upper), each (M - 1,), or None.
        result: what :func:`rangeslam.mdu.slam` returned.
        baseline_receivers / baseline_sources: GTSAM from a GTSAM-style start (no EDM).
        edm_error, error, baseline_error: trajectory RMS error after rigid alignment (with
            reflection), metres.
        source_error: landmark RMS error of EDM + GTSAM after the trajectory's alignment, each
            landmark taken up to its mirror image in the trajectory's plane (eq. 12 is planar).
        oracle_error, oracle_source_error: the same errors of the oracle: the GTSAM graph
            :func:`rangeslam.mdu.slam` ends with (range factors, step priors, kernel, noise)
            minimised from the truth (0 at sigma = 0, where the truth is its minimum).
        oracle_rms: the oracle's Monte-Carlo RMS trajectory error over fresh noise (and bound
            placement) draws on the same walk, metres (NaN when none were asked for).
        crlb: receiver-gauge CRLB of the trajectory error with the information the method
            uses: the ranges and, with step bounds, the step prior ``slam`` reads them as
            (:func:`rangeslam.evaluation.mdu_crlb`); inf when not identifiable, NaN at sigma = 0.
        crlb_ranges: the same from the ranges alone (equal to ``crlb`` without bounds).
        nees: normalised estimation error squared of the whole trajectory against
            ``result.trajectory_cov`` (NaN without it); nees_dof: its degrees of freedom
            (M d - 6), the mean NEES of a consistent estimator.
        status: ``result.status`` (``converged`` is derived from it).
        seconds: wall time of the :func:`rangeslam.mdu.slam` call (the whole pipeline).
    """

    trajectory: np.ndarray
    landmarks: np.ndarray
    ranges: np.ndarray
    sigma: float
    bounds: bool
    step_bounds: tuple[np.ndarray, np.ndarray] | None
    result: object
    baseline_receivers: np.ndarray
    baseline_sources: np.ndarray
    edm_error: float
    error: float
    baseline_error: float
    source_error: float
    oracle_error: float
    oracle_source_error: float
    oracle_rms: float
    crlb: float
    crlb_ranges: float
    nees: float
    nees_dof: int
    status: Status
    seconds: float


def gtsam_style_start(
    ranges: np.ndarray, step_bounds, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """The start GTSAM's range-only examples use when nothing better is known: a random walk of
    the nominal steps (the bounds' midpoints, else what the ranges imply) and landmarks uniform in
    a box of the largest range; the same draw as :func:`rangeslam.mdu.slam`'s extra starts."""
    from rangeslam.mdu.slam_graph import nominal_steps, random_start

    observed = np.isfinite(ranges)
    bounds = None if step_bounds is None else tuple(np.asarray(b) for b in step_bounds)
    steps = nominal_steps(bounds, ranges, observed)
    return random_start(steps, ranges.shape[1], 3, float(np.max(ranges[observed])), rng)


def _gtsam_alone(start_x, start_s, ranges, sigma, step_bounds, step_prior):
    """GTSAM's graph alone from the given start: (receivers, sources), the start when it fails."""
    from rangeslam.solvers.gtsam_graph import refine_graph

    try:
        base = refine_graph(
            start_x,
            start_s,
            ranges,
            noise_std=max(sigma, 1e-4),
            step_bounds=step_bounds,
            step_prior=step_prior,
            covariances=False,
            max_iterations=5000,
        )
    except SolverError:  # a diverged baseline counts as its failure, not as an error of the run
        return start_x, start_s
    return base.receivers, base.sources


def place_step_bounds(
    steps: np.ndarray, placement: str, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) step bounds, each (M - 1,), metres, of width 40% of the true ``steps``
    (M - 1,): "centred" on them (the paper's +-20%) or "random" (each true step uniform inside
    its bounds: the model the "uniform" step prior assumes)."""
    if placement == "centred":
        lower = 0.8 * steps
    elif placement == "random":
        lower = steps * (1 - 0.4 * rng.uniform(size=len(steps)))
    else:
        raise InvalidInputError(
            f"bounds_placement must be 'centred' or 'random'; got {placement!r}"
        )
    return lower, lower + 0.4 * steps


def _slam_oracle(
    traj, landmarks, ranges, sigma: float, step_bounds, slam_options: dict
) -> tuple[float, float]:
    """(trajectory, landmark) RMS errors (metres) of :func:`rangeslam.mdu.slam`'s final graph
    minimised from the truth ``traj`` (M, 3), ``landmarks`` (K, 3), with the noise it was told
    (else the true ``sigma``); (0, 0) without noise, where the truth is the minimum."""
    from rangeslam.solvers.gtsam_graph import refine_graph

    if sigma <= 0:
        return 0.0, 0.0
    fit = refine_graph(
        traj,
        landmarks,
        ranges,
        noise_std=slam_options.get("noise_std") or sigma,
        step_bounds=step_bounds,
        step_sigma=slam_options.get("step_sigma"),
        step_prior=slam_options.get("step_prior", "uniform"),
        robust=slam_options.get("robust"),
        covariances=False,
        max_iterations=5000,
    )
    a = align(fit.receivers, traj, reflection=True)
    return a.rmse, planar_source_error(a, fit.sources, landmarks, float(traj[0, 2]))


def _slam_bounds(traj, landmarks, sigma, step_bounds, slam_options) -> tuple[float, float]:
    """Receiver-gauge CRLBs (metres) of the trajectory: with the step prior :func:`slam` reads
    the bounds as (floored at its noise), and from the ranges alone."""
    ranges_only = receiver_crlb(traj, landmarks, sigma)
    if step_bounds is None:
        return ranges_only, ranges_only
    floor = slam_options.get("step_sigma") or slam_options.get("noise_std") or sigma
    step_prior = slam_options.get("step_prior", "uniform")
    bound = receiver_crlb(
        traj, landmarks, sigma, step_bounds=step_bounds, step_prior=step_prior, step_sigma=floor
    )
    return bound, ranges_only


def _slam_oracle_rms(traj, landmarks, sigma, placement, slam_options, draws: int, rng) -> float:
    """The oracle's Monte-Carlo RMS trajectory error (metres) on this walk: ``draws`` fresh range
    noise (and, with ``placement``, step-bound placement) draws, each minimised from the truth;
    NaN when ``draws`` is 0, 0 without noise."""
    from rangeslam.sim.trajectories import step_lengths

    if draws == 0:
        return float("nan")
    if sigma <= 0:
        return 0.0
    steps, errors = step_lengths(traj), []
    for _ in range(draws):
        ranges = add_range_noise(range_matrix(traj, landmarks), sigma, rng=rng)
        bounds = None if placement is None else place_step_bounds(steps, placement, rng)
        errors.append(_slam_oracle(traj, landmarks, ranges, sigma, bounds, slam_options)[0])
    return float(np.sqrt(np.mean(np.square(errors))))


def fig5_scene(m: int, sigma: float, rng: np.random.Generator):
    """(trajectory (M, 3), landmarks (7, 3), ranges (M, 7) with N(0, sigma^2) noise): the
    lemniscate of eq. (12) from a random phase, a loudspeaker uniform in the Fig. 5 room and its
    6 first-order images, metres."""
    from rangeslam.sim.trajectories import lemniscate

    room = Room.shoebox(FIG5_ROOM_SIZE)
    traj = lemniscate(m, step=0.3, phase=rng.uniform(0, 2 * np.pi))
    source = random_points_in_room(room, 1, rng=rng)[0]
    landmarks = np.vstack([source, room.image_sources(source, 1).positions])
    ranges = range_matrix(traj, landmarks)
    if sigma > 0:
        ranges = add_range_noise(ranges, sigma, rng=rng)
    return traj, landmarks, ranges


def slam_experiment(
    m: int,
    sigma: float,
    bounds: bool,
    rng: np.random.Generator,
    *,
    bounds_placement: str = "random",
    baseline: bool = True,
    oracle_draws: int = 0,
    **slam_options,
) -> SlamExperiment:
    """Fig. 5: the lemniscate of eq. (12) from a random phase, M steps of t_n = 0.3 n, a
    loudspeaker uniform in the 5 x 4 x 2.6 m room and its 6 first-order images; ranges with
    N(0, sigma^2) noise; step bounds of width 40% of the true step, or none.

    ``bounds_placement``: "centred" (the paper's +-20% of the true step) or "random" (the true
    step uniform inside bounds of the same width: the model the "uniform" step prior assumes, so
    the one in which its covariances can be judged, and a check that nothing relies on the truth
    sitting in the middle; the default). ``baseline=False`` skips GTSAM alone (its fields are
    then NaN). ``oracle_draws`` fresh noise draws on the same walk give the oracle's Monte-Carlo
    RMS error (``oracle_rms``), the figure its bound is checked against."""
    from rangeslam.mdu.slam import slam
    from rangeslam.sim.trajectories import step_lengths

    if bounds_placement not in ("centred", "random"):
        raise InvalidInputError(
            f"bounds_placement must be 'centred' or 'random'; got {bounds_placement!r}"
        )
    draws = check_int(oracle_draws, "oracle_draws", 0, 10_000)
    traj, landmarks, ranges = fig5_scene(m, sigma, rng)
    step_prior = slam_options.get("step_prior", "uniform")
    steps = step_lengths(traj)
    step_bounds = place_step_bounds(steps, bounds_placement, rng) if bounds else None
    slam_options.setdefault("noise_std", sigma)
    t0 = time.perf_counter()
    result = slam(ranges, step_bounds=step_bounds, rng=rng, **slam_options)
    seconds = time.perf_counter() - t0
    a = align(result.receivers, traj, reflection=True)
    start_x, start_s = gtsam_style_start(ranges, step_bounds, rng)
    if not baseline:
        base_x, base_s = np.full_like(traj, np.nan), np.full_like(landmarks, np.nan)
    else:
        base_x, base_s = _gtsam_alone(start_x, start_s, ranges, sigma, step_bounds, step_prior)
    bound, ranges_only = _slam_bounds(traj, landmarks, sigma, step_bounds, slam_options)
    nees, dof = trajectory_nees(a, result.trajectory_cov, traj, result.trajectory_dof)
    oracle = _slam_oracle(traj, landmarks, ranges, sigma, step_bounds, slam_options)
    placement = bounds_placement if bounds else None
    oracle_rms = _slam_oracle_rms(
        traj,
        landmarks,
        sigma,
        placement,
        slam_options,
        draws,
        rng,
    )
    return SlamExperiment(
        trajectory=traj,
        landmarks=landmarks,
        ranges=ranges,
        sigma=sigma,
        bounds=bounds,
        step_bounds=step_bounds,
        result=result,
        baseline_receivers=base_x,
        baseline_sources=base_s,
        edm_error=align(result.edm_receivers, traj, reflection=True).rmse,
        error=a.rmse,
        baseline_error=align(base_x, traj, reflection=True).rmse if baseline else float("nan"),
        source_error=planar_source_error(a, result.sources, landmarks, float(traj[0, 2])),
        oracle_error=oracle[0],
        oracle_source_error=oracle[1],
        oracle_rms=oracle_rms,
        crlb=bound,
        crlb_ranges=ranges_only,
        nees=nees,
        nees_dof=dof,
        status=Status(result.status),
        seconds=seconds,
    )
