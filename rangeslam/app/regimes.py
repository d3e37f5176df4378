"""The regime map: where each range-only SLAM method wins (``rangeslam bench compare --regimes``).

A cell is one regime: the walk (the lemniscate of eq. 12, or a smooth random walk in a random
convex room), the number of steps M, +-20% step bounds or none, the range noise, the dimension,
a fraction of missing echoes and one of wrong picks. Every method runs on the same noisy ranges:

- "edm": the EDM answer of :func:`rangeslam.slam` (convex iteration, eqs. 10-11), before GTSAM;
- "edm_gtsam": :func:`rangeslam.slam`, the EDM answer refined by GTSAM with the step prior;
- "gtsam_1": GTSAM's graph (the same factors) from one random start as GTSAM's range-only
  examples make them (a random walk of the nominal steps, landmarks uniform in a box);
- "gtsam_k": GTSAM from random starts until it has used the wall time of "edm_gtsam", the lowest
  final graph cost kept (at least one start);
- "ekf", "ekf_rts": the filterpy EKF (:func:`rangeslam.baselines.ekf_slam`), filtered and
  Rauch-Tung-Striebel smoothed.

Each method is told the noise level (the graph's and the filter's weights). With wrong picks the
graph methods use a Huber kernel. Per trial: the trajectory's RMS error after the best rigid
motion with reflection, the landmarks' (each up to its mirror image through the walk's plane on
the planar lemniscate, as the paper's Fig. 5 right panel), the Cramer-Rao bound with the step
prior the graph uses, the wall time and GTSAM's iterations. Trials draw their scene from a
Generator keyed on (seed, cell, trial), so any subset of cells draws the same scenes.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from rangeslam.errors import InvalidInputError, RangeSlamError

__all__ = [
    "REGIME_METHODS",
    "REGIME_SIGMAS",
    "REGIME_STEPS",
    "RegimeCell",
    "RegimeScene",
    "draw_scene",
    "regime_cells",
    "run_regime_trial",
]

REGIME_STEPS = (4, 5, 6, 8, 10, 20)
REGIME_SIGMAS = (1e-3, 1e-2)
REGIME_METHODS = ("edm", "edm_gtsam", "gtsam_1", "gtsam_k", "ekf", "ekf_rts")
#: Trajectory RMS error under which a trial counts as a success, metres.
SUCCESS_M = 0.10
#: Walls of the random convex rooms (a loudspeaker and its first-order images: 7 landmarks in
#: 3-D, as the paper's Fig. 5; 6 in 2-D).
ROOM_WALLS = {2: 5, 3: 6}
#: GTSAM random starts at most for "gtsam_k" (its time budget is that of "edm_gtsam").
MAX_RANDOM_STARTS = 200
#: Steps of the EKF's delayed-initialisation window (as ``bench compare``).
EKF_WINDOW = 5
WALKS = ("lemniscate", "random")


@dataclass(frozen=True)
class RegimeCell:
    """One regime. ``walk``: "lemniscate" (eq. 12, planar, 3-D only) or "random" (a smooth
    random walk of 0.3 m steps in a random convex room); ``m`` steps; ``bounds``: +-20% step
    bounds (centred on the true steps) or none; ``sigma``: range noise, metres; ``dim`` 2 or 3;
    ``missing``: fraction of echoes missing; ``wrong``: fraction of wrong picks (0.2-1 m)."""

    walk: str
    m: int
    bounds: bool
    sigma: float
    dim: int = 3
    missing: float = 0.0
    wrong: float = 0.0

    def __post_init__(self) -> None:
        if self.walk not in WALKS:
            raise InvalidInputError(f"walk must be one of {WALKS}; got {self.walk!r}")
        if self.walk == "lemniscate" and self.dim != 3:
            raise InvalidInputError("the lemniscate of eq. (12) is a 3-D walk: dim must be 3")
        if self.dim not in (2, 3):
            raise InvalidInputError(f"dim must be 2 or 3; got {self.dim!r}")
        if not (isinstance(self.m, int) and self.m >= 3):
            raise InvalidInputError(f"m must be an integer >= 3; got {self.m!r}")
        if not (np.isfinite(self.sigma) and self.sigma > 0):
            raise InvalidInputError(f"sigma must be positive and finite; got {self.sigma!r}")
        for name in ("missing", "wrong"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise InvalidInputError(f"{name} must be in [0, 1); got {getattr(self, name)!r}")

    @property
    def label(self) -> str:
        """A short name of the regime, e.g. "random 3-D, M=8, bounds, 1 cm, 30% missing"."""
        parts = [
            self.walk if self.walk == "lemniscate" else f"random {self.dim}-D",
            f"M={self.m}",
            "bounds" if self.bounds else "no bounds",
            f"{self.sigma * 1000:g} mm",
        ]
        if self.missing:
            parts.append(f"{100 * self.missing:g}% missing")
        if self.wrong:
            parts.append(f"{100 * self.wrong:g}% wrong")
        return ", ".join(parts)

    def spawn_key(self, trial: int) -> tuple[int, ...]:
        """The trial's key in the run's SeedSequence: the cell's values and the trial index."""
        return (
            WALKS.index(self.walk),
            self.m,
            int(self.bounds),
            round(self.sigma * 1e9),
            self.dim,
            round(self.missing * 1000),
            round(self.wrong * 1000),
            trial,
        )


def regime_cells(
    steps: Sequence[int] = REGIME_STEPS,
    sigmas: Sequence[float] = REGIME_SIGMAS,
    *,
    variants: bool = True,
) -> list[RegimeCell]:
    """The map's cells: every walk x bounds (or none) x sigma x M, and (``variants``) at each M
    of at least 6, with bounds and the largest sigma on random walks: 2-D, 30% of the echoes
    missing, 5% wrong picks."""
    cells = [
        RegimeCell(walk, int(m), bounds, float(s))
        for walk in WALKS
        for bounds in (True, False)
        for s in sigmas
        for m in steps
    ]
    if variants:
        s = float(max(sigmas))
        for m in (int(m) for m in steps if m >= 6):
            cells += [
                RegimeCell("random", m, True, s, dim=2),
                RegimeCell("random", m, True, s, missing=0.3),
                RegimeCell("random", m, True, s, wrong=0.05),
            ]
    return cells


@dataclass(frozen=True)
class RegimeScene:
    """One drawn scene: ``trajectory`` (M, d) and ``landmarks`` (K, d) true positions, metres;
    ``ranges`` (M, K) noisy (wrong picks included), NaN where missing; ``mask`` (M, K) True where
    observed; ``step_bounds`` (lower, upper) each (M - 1,) or None; ``planar_height``: z of the
    lemniscate's plane (landmarks judged up to their mirror image through it), else None."""

    trajectory: np.ndarray
    landmarks: np.ndarray
    ranges: np.ndarray
    mask: np.ndarray
    step_bounds: tuple[np.ndarray, np.ndarray] | None
    planar_height: float | None


#: Draws of the missing echoes at most before a scene is given up as unidentifiable.
MASK_DRAWS = 1000


def echo_mask(shape: tuple[int, int], cell: RegimeCell, rng: np.random.Generator) -> np.ndarray:
    """(M, K) True where observed: the direct sound (column 0) always, each echo missing with
    probability ``cell.missing``, redrawn until every step hears d + 1 landmarks and every
    landmark is heard d + 1 times (else the problem is under-determined, and ``slam`` refuses
    it)."""
    from rangeslam.sim.scenes import random_mask

    need = cell.dim + 1
    for _ in range(MASK_DRAWS):
        mask = random_mask(shape, cell.missing, rng=rng)
        mask[:, 0] = True
        if np.all(mask.sum(axis=1) >= need) and np.all(mask.sum(axis=0) >= need):
            return mask
    raise InvalidInputError(
        f"no mask with {100 * cell.missing:g}% missing echoes leaves {shape} ranges determined"
    )


def draw_scene(cell: RegimeCell, rng: np.random.Generator) -> RegimeScene:
    """A scene of ``cell``: the walk, a loudspeaker uniform in the room and its first-order
    images, ranges with N(0, sigma^2) noise, missing echoes and wrong picks as the cell says."""
    from rangeslam.app.experiments import FIG5_ROOM_SIZE
    from rangeslam.geometry.edm import range_matrix
    from rangeslam.geometry.room import Room
    from rangeslam.sim.scenes import (
        add_outliers,
        add_range_noise,
        random_convex_room,
        random_points_in_room,
    )
    from rangeslam.sim.trajectories import lemniscate, random_walk, step_lengths

    if cell.walk == "lemniscate":
        room = Room.shoebox(FIG5_ROOM_SIZE)
        traj = lemniscate(cell.m, step=0.3, phase=rng.uniform(0, 2 * np.pi))
        height = float(traj[0, 2])
    else:
        room = random_convex_room(cell.dim, ROOM_WALLS[cell.dim], rng=rng)
        start = random_points_in_room(room, 1, margin=0.6, rng=rng)[0]
        traj = random_walk(
            cell.m, start=start, step_length=0.3, step_jitter=0.1, turn_std=0.3, room=room,
            margin=0.3, rng=rng,
        )  # fmt: skip
        height = None
    source = random_points_in_room(room, 1, margin=0.1, rng=rng)[0]
    landmarks = np.vstack([source, room.image_sources(source, 1).positions])
    ranges = add_range_noise(range_matrix(traj, landmarks), cell.sigma, rng=rng)
    mask = echo_mask(ranges.shape, cell, rng) if cell.missing else np.ones(ranges.shape, bool)
    if cell.wrong:
        ranges, _ = add_outliers(
            ranges, cell.wrong, min_error=0.2, max_error=1.0, mask=mask, rng=rng
        )
    ranges = np.where(mask, ranges, np.nan)
    steps = step_lengths(traj)
    bounds = (0.8 * steps, 1.2 * steps) if cell.bounds else None
    return RegimeScene(traj, landmarks, ranges, mask, bounds, height)


@dataclass(frozen=True)
class MethodRun:
    """One method on one scene: trajectory ``receivers`` (M, d) and ``sources`` (K, d) (NaN when
    it failed), wall ``seconds``, GTSAM ``iterations`` (summed over starts; NaN without GTSAM),
    random ``starts`` used, and ``status`` ("ok", or why it failed)."""

    receivers: np.ndarray
    sources: np.ndarray
    seconds: float
    iterations: float = float("nan")
    starts: int = 0
    status: str = "ok"


def failed_run(scene: RegimeScene, seconds: float, exc: BaseException) -> MethodRun:
    """A method that raised: NaN positions and the exception's first line as its status."""
    why = f"{type(exc).__name__}: {exc}".splitlines()[0][:200]
    return MethodRun(
        np.full_like(scene.trajectory, np.nan),
        np.full_like(scene.landmarks, np.nan),
        seconds,
        status=why,
    )


def run_slam(scene: RegimeScene, cell: RegimeCell, rng) -> tuple[MethodRun, MethodRun]:
    """ "edm" and "edm_gtsam": one :func:`rangeslam.slam` call (its time for both; the EDM
    answer's own share is not separated)."""
    from rangeslam.mdu.slam import slam

    t0 = time.perf_counter()
    try:
        result = slam(
            scene.ranges, step_bounds=scene.step_bounds, mask=scene.mask, dim=cell.dim,
            noise_std=cell.sigma, robust="huber" if cell.wrong else None, rng=rng,
        )  # fmt: skip
    except RangeSlamError as exc:  # the method's failure is its result
        lost = failed_run(scene, time.perf_counter() - t0, exc)
        return lost, lost
    seconds = time.perf_counter() - t0
    status = "ok" if result.converged else f"flagged: {result.status.name}"
    edm = MethodRun(np.asarray(result.edm_receivers), np.asarray(result.edm_sources), seconds)
    full = MethodRun(
        np.asarray(result.receivers), np.asarray(result.sources), seconds, status=status
    )
    return edm, full


def graph_from(scene: RegimeScene, cell: RegimeCell, x0: np.ndarray, s0: np.ndarray):
    """GTSAM's graph (range factors, the step prior of ``slam``, Huber with wrong picks) from
    receivers ``x0`` (M, d) and sources ``s0`` (K, d): the
    :class:`~rangeslam.solvers.gtsam_graph.GraphFit`, or None when GTSAM failed."""
    from rangeslam.errors import SolverError
    from rangeslam.solvers.gtsam_graph import refine_graph

    try:
        return refine_graph(
            x0, s0, np.nan_to_num(scene.ranges), noise_std=cell.sigma, mask=scene.mask,
            step_bounds=scene.step_bounds, robust="huber" if cell.wrong else None,
            covariances=False, max_iterations=5000,
        )  # fmt: skip
    except SolverError:
        return None


def graph_from_random_start(scene: RegimeScene, cell: RegimeCell, rng):
    """:func:`graph_from` one GTSAM-style random start."""
    from rangeslam.mdu.slam_graph import nominal_steps, random_start

    observed = scene.mask
    steps = nominal_steps(scene.step_bounds, np.nan_to_num(scene.ranges), observed)
    size = float(np.max(scene.ranges[observed]))
    x0, s0 = random_start(steps, scene.landmarks.shape[0], cell.dim, size, rng)
    return graph_from(scene, cell, x0, s0)


def oracle_error(scene: RegimeScene, cell: RegimeCell) -> float:
    """The oracle's trajectory error, metres: the graph every GTSAM method minimises, from the
    truth (0 without noise; NaN when GTSAM failed)."""
    from rangeslam.geometry.alignment import align

    if cell.sigma <= 0:
        return 0.0
    fit = graph_from(scene, cell, scene.trajectory, scene.landmarks)
    if fit is None:
        return float("nan")
    return align(fit.receivers, scene.trajectory, reflection=True).rmse


def run_random_starts(
    scene: RegimeScene, cell: RegimeCell, rng, budget: float, max_starts: int
) -> MethodRun:
    """GTSAM from random starts until ``budget`` seconds are used (at least one start, at most
    ``max_starts``); the lowest final graph cost wins."""
    t0 = time.perf_counter()
    best, iterations, starts = None, 0, 0
    while starts < max_starts and (starts == 0 or time.perf_counter() - t0 < budget):
        fit = graph_from_random_start(scene, cell, rng)
        starts += 1
        if fit is None:
            continue
        iterations += fit.iterations
        if fit.converged and (best is None or fit.error < best.error):
            best = fit
    seconds = time.perf_counter() - t0
    if best is None:
        lost = failed_run(scene, seconds, RangeSlamError("GTSAM failed from every start"))
        return MethodRun(lost.receivers, lost.sources, seconds, iterations, starts, lost.status)
    return MethodRun(best.receivers, best.sources, seconds, float(iterations), starts)


def run_ekf(scene: RegimeScene, cell: RegimeCell, rng, smooth: bool) -> MethodRun:
    """The filterpy EKF (RTS-smoothed when ``smooth``), its first steps (at most 5) its
    delayed-initialisation window."""
    from rangeslam.baselines.ekf_slam import ekf_slam

    t0 = time.perf_counter()
    try:
        out = ekf_slam(
            np.nan_to_num(scene.ranges), step_bounds=scene.step_bounds, mask=scene.mask,
            dim=cell.dim, noise_std=cell.sigma, smooth=smooth,
            init_steps=min(EKF_WINDOW, cell.m), rng=rng,
        )  # fmt: skip
    except RangeSlamError as exc:
        return failed_run(scene, time.perf_counter() - t0, exc)
    status = "ok" if out.converged else f"flagged: {out.status.name}"
    seconds = time.perf_counter() - t0
    return MethodRun(np.asarray(out.receivers), np.asarray(out.sources), seconds, status=status)


def landmark_error(alignment, sources: np.ndarray, scene: RegimeScene) -> float:
    """RMS landmark error, metres, after the trajectory's ``alignment``; on the planar
    lemniscate each landmark up to its mirror image through the walk's plane."""
    from rangeslam.evaluation.metrics import planar_source_error

    if scene.planar_height is not None:
        return planar_source_error(alignment, sources, scene.landmarks, scene.planar_height)
    diff = alignment.apply(sources) - scene.landmarks
    return float(np.sqrt(np.mean(np.sum(diff**2, axis=1))))


def scene_bound(scene: RegimeScene, cell: RegimeCell) -> float:
    """The receiver-gauge Cramer-Rao bound of the trajectory's RMS error, metres, from the
    observed ranges and the step prior the graph uses (inf: not identifiable)."""
    from rangeslam.errors import DegenerateGeometryError
    from rangeslam.verdict.crlb import mdu_crlb

    priors = {}
    if scene.step_bounds is not None:
        priors = dict(step_bounds=scene.step_bounds, step_prior="uniform", step_sigma=cell.sigma)
    try:
        return mdu_crlb(
            scene.trajectory, scene.landmarks, cell.sigma, mask=scene.mask, **priors
        ).receiver_rmse
    except DegenerateGeometryError:
        return float("inf")


def method_row(name: str, run: MethodRun, scene: RegimeScene) -> dict:
    """The row values of one method: error, landmark error, success, time, iterations."""
    from rangeslam.geometry.alignment import align

    if not np.all(np.isfinite(run.receivers)):
        error = landmarks = float("nan")
    else:
        a = align(run.receivers, scene.trajectory, reflection=True)
        error, landmarks = a.rmse, landmark_error(a, run.sources, scene)
    return {
        f"{name}_error_m": error,
        f"{name}_landmark_error_m": landmarks,
        f"{name}_success": bool(np.isfinite(error) and error < SUCCESS_M),
        f"{name}_seconds": run.seconds,
        f"{name}_iterations": run.iterations,
        f"{name}_starts": run.starts,
        f"{name}_status": run.status,
    }


def run_regime_trial(
    cell: RegimeCell, trial: int, seed: int, *, max_starts: int = MAX_RANDOM_STARTS
) -> dict:
    """Every method on one scene of ``cell``: a row (the cell's values, the bound, each
    method's figures; :func:`method_row`). The scene and every method's randomness come from
    the Generator keyed on (``seed``, the cell, ``trial``)."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=cell.spawn_key(trial)))
    scene = draw_scene(cell, rng)
    row = {"regime": cell.label, **asdict(cell), "trial": trial, "seed": seed, "status": "ok"}
    row["crlb_m"] = scene_bound(scene, cell)
    row["oracle_error_m"] = oracle_error(scene, cell)
    edm, full = run_slam(scene, cell, rng)
    runs = {
        "edm": edm,
        "edm_gtsam": full,
        "gtsam_1": run_random_starts(scene, cell, rng, 0.0, 1),
        "gtsam_k": run_random_starts(scene, cell, rng, full.seconds, max_starts),
        "ekf": run_ekf(scene, cell, rng, smooth=False),
        "ekf_rts": run_ekf(scene, cell, rng, smooth=True),
    }
    for name, run in runs.items():
        row.update(method_row(name, run, scene))
    return row
