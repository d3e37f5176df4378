"""Cases for the verdict benchmark: does "converged" mean right?

Each :class:`VerdictCase` is one call of an estimator on data drawn at random from an ``rng``,
with the truth it was built from. The TRUTH, never the estimator, decides what is right:

- *identifiable*: the Cramer-Rao bound at the truth, for the data actually usable (clean ranges
  only, injected wrong picks masked out; with the priors the estimator uses), is finite and its
  RMS is at most :data:`rangeslam.verdict.PRECISION_FRACTION` of the scene size (the median true
  range), and the construction has no ambiguity (a point heard by exactly d partners, all points
  in one plane at dim=3, a linear array, 3-D data fitted in dim=2; for a located point, a mirror
  image through the anchors' plane that fits the noise-free ranges within chi-square(1, 0.999)
  noise variances);
- *right*: identifiable and the estimate's error (RMS over the points the bound is about, after
  the same alignment) at most :data:`BOUND_FACTOR` times that RMS bound plus :data:`EXACT_SLACK`
  of the scene size. Real data use stated tolerances instead (see the ``real_*`` builders).
- *the call contradicted*: the ``noise_std`` passed is a third of the noise drawn ("noise_std
  /3"), so the residuals contradict the model the caller declared, and INCONSISTENT is what
  the chi-square test is asked to say. A right estimate flagged INCONSISTENT there is
  "flagged-inconsistent-call", counted apart from the false alarms (the strict count adds
  them to the false alarms; the benchmark prints both).

:func:`classify` turns a case and what the estimator returned (a result or a package error) into
one of :data:`OUTCOMES`. ``flagged`` means a status other than CONVERGED, or a package error.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from rangeslam._validation import as_rng
from rangeslam.errors import DegenerateGeometryError, InvalidInputError, RangeSlamError
from rangeslam.geometry.alignment import align
from rangeslam.geometry.edm import range_matrix
from rangeslam.geometry.rigid_motion import receiver_gauge_projection, rigid_motion_basis
from rangeslam.geometry.room import Room
from rangeslam.sim.scenes import add_outliers, echo_ranges, random_points_in_room
from rangeslam.verdict import PRECISION_FRACTION, mirror_gap, reflected
from rangeslam.verdict.crlb import mdu_crlb, multilateration_crlb, wall_crlb
from rangeslam.verdict.judge import cost_level

__all__ = [
    "BOUND_FACTOR",
    "EXACT_SLACK",
    "OUTCOMES",
    "REGIMES",
    "CaseOutcome",
    "VerdictCase",
    "classify",
    "draw_cases",
    "make_case",
    "mirror_room_gap",
    "real_cases",
    "run_case",
]

#: Right = error at most this multiple of the RMS Cramer-Rao bound at the truth ...
BOUND_FACTOR = 3.0
#: ... plus this fraction of the scene size (exact data: the bound is 0).
EXACT_SLACK = 1e-6
#: The classes, in table order.
OUTCOMES = (
    "converged-right",
    "converged-wrong",
    "flagged-right",
    "flagged-wrong",
    "flagged-inconsistent-call",
)

_ROOM_SIZE = (5.1, 3.7, 2.6)  # the Fig. 3 shoebox, metres
_FIG5_ROOM = (5.0, 4.0, 2.6)  # the Fig. 5 shoebox, metres


@dataclass(frozen=True)
class VerdictCase:
    """One estimator call and its truth.

    Attributes:
        estimator: name of the public function called ("multilaterate", "calibrate", ...).
        regime: the kind of data (e.g. "robust 20% wrong").
        run: no-argument callable that calls the estimator and returns its result.
        judge: callable(result) -> (error in metres, within tolerance): the error of the estimate
            against the truth (RMS over the points the bound is about, after alignment) and
            whether it is within BOUND_FACTOR x bound (+ EXACT_SLACK x scale) or, for real data,
            the stated tolerances.
        bound: RMS Cramer-Rao bound at the truth, metres (inf when the information is singular;
            nan for real data and for constructions the bound cannot describe).
        scale: scene size, the median true range, metres.
        identifiable: the truth's verdict (see the module docstring).
        reason: why the truth is not identifiable ("" when it is).
        seed: the integer the case's data were drawn from (``make_case(estimator, regime, seed)``
            draws them again), or None for real data.
        noise_std_too_small: the ``noise_std`` passed is below the noise drawn (a third of it),
            so a right estimate flagged INCONSISTENT is a right flag (module docstring); set by
            :func:`make_case` from the regime.
    """

    estimator: str
    regime: str
    run: Callable[[], Any]
    judge: Callable[[Any], tuple[float, bool]]
    bound: float
    scale: float
    identifiable: bool
    reason: str = ""
    seed: int | None = None
    noise_std_too_small: bool = False


@dataclass(frozen=True)
class CaseOutcome:
    """What one case gave: status name (or the error's class), message, error (metres), the RMS
    bound (metres), the classification (one of OUTCOMES, or "foreign-exception" for an exception
    that is not the package's), and the seconds the estimator took."""

    case: VerdictCase
    status: str
    message: str
    error: float
    bound: float
    classification: str
    seconds: float


def classify(case: VerdictCase, result: Any) -> str:
    """One of :data:`OUTCOMES` for what ``case``'s estimator returned: a result with a ``status``
    / ``converged``, or a raised package error (:class:`RangeSlamError`, which counts as flagged;
    right then means the truth says the data were identifiable, i.e. the refusal was a false
    alarm). Raises InvalidInputError for anything else."""
    if isinstance(result, RangeSlamError):
        return "flagged-wrong" if case.identifiable else "flagged-right"
    if isinstance(result, BaseException) or not hasattr(result, "converged"):
        raise InvalidInputError(
            "result must be an estimator's result (with .converged) or a package error; "
            f"got {type(result).__name__}"
        )
    right = case.identifiable and _judged(case, result)[1]
    if result.converged:
        return "converged-right" if right else "converged-wrong"
    status = getattr(result.status, "name", str(result.status))
    if right and case.noise_std_too_small and status == "INCONSISTENT":
        return "flagged-inconsistent-call"
    return "flagged-wrong" if right else "flagged-right"


def _judged(case: VerdictCase, result: Any) -> tuple[float, bool]:
    """case.judge(result), with an estimate that cannot be compared (wrong shape, NaN) as
    (nan, False)."""
    try:
        error, ok = case.judge(result)
    except (ValueError, RangeSlamError, np.linalg.LinAlgError):
        return float("nan"), False
    return float(error), bool(ok) and bool(np.isfinite(error))


def run_case(case: VerdictCase) -> CaseOutcome:
    """Run ``case.run()`` timed; a package error counts as flagged, a foreign exception is
    recorded as "foreign-exception" (a defect to report, never hidden)."""
    t0 = time.perf_counter()
    try:
        result = case.run()
    except RangeSlamError as exc:
        dt = time.perf_counter() - t0
        return CaseOutcome(
            case, type(exc).__name__, str(exc), float("nan"), case.bound, classify(case, exc), dt
        )
    except Exception as exc:
        dt = time.perf_counter() - t0
        msg = f"{type(exc).__name__}: {exc}"
        return CaseOutcome(case, "foreign", msg, float("nan"), case.bound, "foreign-exception", dt)
    dt = time.perf_counter() - t0
    error, _ = _judged(case, result)
    status = getattr(result.status, "name", str(result.status))
    return CaseOutcome(case, status, result.message, error, case.bound, classify(case, result), dt)


# --- the truth ---------------------------------------------------------------------------------


def _within(error: float, bound: float, scale: float) -> tuple[float, bool]:
    """(error, error <= BOUND_FACTOR bound + EXACT_SLACK scale)."""
    return error, bool(error <= BOUND_FACTOR * bound + EXACT_SLACK * scale)


def _identifiable(bound: float, scale: float, reason: str) -> tuple[bool, str]:
    """The truth's verdict from the RMS bound and a construction's ambiguity (``reason``)."""
    if reason:
        return False, reason
    if not np.isfinite(bound):
        return False, "Fisher information singular at the truth"
    if bound > PRECISION_FRACTION * scale:
        return False, f"RMS bound {bound:.3g} m > {PRECISION_FRACTION} x scene {scale:.3g} m"
    return True, ""


def _receiver_error(result: Any, truth: np.ndarray) -> float:
    """RMS receiver error after the best rigid motion with reflection, metres."""
    est = np.asarray(result.receivers, dtype=float)
    if est.shape != truth.shape or not np.all(np.isfinite(est)):
        return float("nan")
    return float(align(est, truth, reflection=True).rmse)


def _mdu_bound(receivers, sources, sigma, mask, **priors) -> float:
    """Receiver-gauge RMS bound of :func:`mdu_crlb` (inf when singular), metres."""
    try:
        return mdu_crlb(receivers, sources, sigma, mask=mask, **priors).receiver_rmse
    except DegenerateGeometryError:
        return float("inf")


def _noise_option(mode: str, sigma: float, rng: np.random.Generator) -> float | None:
    """The ``noise_std`` passed: the truth ("given"), None ("not given"), 3x ("x3") or a third
    ("/3")."""
    return {"given": sigma, "not given": None, "x3": 3 * sigma, "/3": sigma / 3}[mode]


# --- multilaterate -----------------------------------------------------------------------------


def _anchors(rng: np.random.Generator, n: int, layout: str) -> np.ndarray:
    """(n, 3) anchors in a 4 x 4 x 3 m box: "random", or "slab" (a horizontal slab of random
    half-thickness 1e-4..1e-2 m at z = 1.5)."""
    a = rng.uniform([0, 0, 0], [4, 4, 3], size=(n, 3))
    if layout == "slab":
        half = 10 ** rng.uniform(-4, -2)
        a[:, 2] = 1.5 + rng.uniform(-half, half, n)
    return a


def multilaterate_case(regime: str, rng: np.random.Generator, seed: int | None = None):
    """A :func:`rangeslam.multilaterate` case; regimes in ``REGIMES["multilaterate"]``."""
    from rangeslam.localization.multilateration import multilaterate

    spec = _MULTI[regime]
    sigma = spec.get("sigma") or float(rng.choice([1e-3, 1e-2]))
    a = _anchors(rng, spec.get("n", int(rng.integers(6, 11))), spec.get("layout", "random"))
    x = rng.uniform([0.5, 0.5, 0.3], [3.5, 3.5, 2.7])
    if spec.get("layout") == "slab":
        x[2] = 1.5 + float(rng.choice([-1, 1])) * rng.uniform(0.3, 1.2)
    true_r = np.linalg.norm(a - x, axis=1)
    r = true_r + sigma * rng.standard_normal(len(a))
    clean = np.ones(len(a), dtype=bool)
    if spec.get("wrong"):
        r, wrong = add_outliers(r, spec["wrong"], min_error=0.2, max_error=1.0, rng=rng)
        clean = ~wrong
    scale = float(np.median(true_r))
    try:
        bound = float(np.sqrt(np.trace(multilateration_crlb(a, x, sigma, mask=clean))))
    except DegenerateGeometryError:
        bound = float("inf")
    reason = "heard by exactly d anchors" if clean.sum() <= 3 else ""
    if not reason and mirror_gap(x, a[clean], true_r[clean]) < cost_level() * sigma**2:
        reason = "mirror image through the anchors' plane fits within the noise"
    ok, why = _identifiable(bound, scale, reason)
    run = partial(
        multilaterate,
        a,
        r,
        robust=bool(spec.get("wrong")),
        noise_std=_noise_option(spec.get("noise", "given"), sigma, rng),
        rng=rng,
    )

    def judge(result):
        return _within(float(np.linalg.norm(np.asarray(result.position) - x)), bound, scale)

    return VerdictCase("multilaterate", regime, run, judge, bound, scale, ok, why, seed)


_MULTI: dict[str, dict] = {
    "random 1 mm": {"sigma": 1e-3},
    "random 1 cm": {"sigma": 1e-2},
    "noise_std not given": {"noise": "not given"},
    "noise_std x3": {"noise": "x3"},
    "noise_std /3": {"noise": "/3"},
    "nearly coplanar": {"layout": "slab", "sigma": 1e-3},
    "d+1 anchors": {"n": 4},
    "d anchors": {"n": 3},
    "robust 10% wrong": {"n": 20, "wrong": 0.1},
    "robust 20% wrong": {"n": 20, "wrong": 0.2},
    "robust 30% wrong": {"n": 20, "wrong": 0.3},
    "robust 40% wrong": {"n": 20, "wrong": 0.4},
}


# --- calibrate ---------------------------------------------------------------------------------


def _fig3(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The Fig. 3 scene with 8 microphones and 7 sources (a loudspeaker and 6 images)."""
    from rangeslam.app.experiments import fig3_scene

    scene = fig3_scene(rng, n_mics=8, n_images=6)
    return np.array(scene.mics), np.array(scene.sources)


def _calibration_geometry(layout: str, rng: np.random.Generator):
    """(mics (8, 3), sources (7, 3), construction's ambiguity or "")."""
    mics, sources = _fig3(rng)
    if layout == "linear":
        direction = rng.standard_normal(3)
        direction /= np.linalg.norm(direction)
        mics = mics.mean(axis=0) + np.outer(rng.uniform(-0.5, 0.5, len(mics)), direction)
        return mics, sources, "linear array: rotations about its line are free"
    if layout == "planar":
        mics[:, 2] = sources[:, 2] = 1.3
        return mics, sources, "every point in one plane at dim=3: mirror images fit"
    return mics, sources, ""


def calibrate_case(regime: str, rng: np.random.Generator, seed: int | None = None):
    """A :func:`rangeslam.calibrate` case (8 microphones x 7 sources of the Fig. 3 scene, defaults
    apart from ``noise_std`` and ``dim``); regimes in ``REGIMES["calibrate"]``."""
    from rangeslam.mdu.calibration import calibrate

    spec = _CALIB[regime]
    sigma = spec.get("sigma") or float(rng.choice([1e-3, 1e-2]))
    mics, sources, reason = _calibration_geometry(spec.get("layout", "fig3"), rng)
    true_r = range_matrix(mics, sources)
    r = true_r + sigma * rng.standard_normal(true_r.shape)
    mask = np.ones(r.shape, dtype=bool)
    if spec.get("heard_by_3"):
        mask[0] = False
        mask[0, rng.choice(r.shape[1], 3, replace=False)] = True
        reason = "receiver 0 heard by exactly 3 sources: its mirror image fits"
    clean = mask.copy()
    if spec.get("wrong"):
        r, wrong = add_outliers(r, spec["wrong"], min_error=0.2, max_error=1.0, rng=rng)
        clean &= ~wrong
    dim = spec.get("dim", 3)
    if dim == 2:
        reason = "3-D data fitted with dim=2"
    scale = float(np.median(true_r))
    bound = _mdu_bound(mics, sources, sigma, clean)
    ok, why = _identifiable(bound, scale, reason)
    run = partial(
        calibrate,
        r,
        dim=dim,
        mask=None if mask.all() else mask,
        noise_std=_noise_option(spec.get("noise", "given"), sigma, rng),
        rng=rng,
    )
    judge = _receiver_judge(mics, bound, scale)
    return VerdictCase("calibrate", regime, run, judge, bound, scale, ok, why, seed)


def _receiver_judge(truth: np.ndarray, bound: float, scale: float):
    """judge(result): the RMS receiver error after alignment with reflection, within the bound."""

    def judge(result):
        return _within(_receiver_error(result, truth), bound, scale)

    return judge


_CALIB: dict[str, dict] = {
    "clean 1 mm": {"sigma": 1e-3},
    "clean 1 cm": {"sigma": 1e-2},
    "noise_std not given": {"noise": "not given"},
    "10% wrong, defaults": {"wrong": 0.1, "noise": "not given"},
    "20% wrong, defaults": {"wrong": 0.2, "noise": "not given"},
    "linear array": {"layout": "linear", "sigma": 1e-3},
    "planar at dim=3": {"layout": "planar", "sigma": 1e-3},
    "receiver heard by 3": {"heard_by_3": True, "sigma": 1e-3},
    "3-D data at dim=2": {"dim": 2, "sigma": 1e-3},
}


# --- slam --------------------------------------------------------------------------------------


def _trajectory(kind: str, m: int, room: Room, rng: np.random.Generator) -> np.ndarray:
    """(m, 3) receivers: the Fig. 5 lemniscate from a random phase (steps of about 30 cm), or a
    correlated 3-D random walk of 30 cm steps inside ``room``."""
    from rangeslam.sim.trajectories import lemniscate, random_walk

    if kind == "lemniscate":
        return lemniscate(m, step=0.3, phase=rng.uniform(0, 2 * np.pi))
    start = random_points_in_room(room, 1, margin=1.0, rng=rng)[0]
    return random_walk(
        m, start=start, step_length=0.3, turn_std=0.6, room=room, margin=0.4, rng=rng
    )


def slam_case(regime: str, rng: np.random.Generator, seed: int | None = None):
    """A :func:`rangeslam.slam` case: the Fig. 5 room, a loudspeaker uniform in it and its 6
    first-order images as landmarks; regimes in ``REGIMES["slam"]``. Step bounds are +-20% of the
    true steps; the bound includes them as the estimator's "uniform" prior."""
    from rangeslam.mdu.slam import slam

    spec = _SLAM[regime]
    sigma = spec.get("sigma") or float(rng.choice([1e-3, 1e-2]))
    room = Room.shoebox(_FIG5_ROOM)
    traj = _trajectory(spec.get("walk", "lemniscate"), spec["m"], room, rng)
    source = random_points_in_room(room, 1, rng=rng)[0]
    landmarks = np.vstack([source, room.image_sources(source, 1).positions])
    true_r = range_matrix(traj, landmarks)
    r = true_r + sigma * rng.standard_normal(true_r.shape)
    steps = np.linalg.norm(np.diff(traj, axis=0), axis=1)
    bounds = (0.8 * steps, 1.2 * steps) if spec.get("bounds") else None
    noise_std = _noise_option(spec.get("noise", "given"), sigma, rng)
    priors = {} if bounds is None else {"step_bounds": bounds, "step_sigma": noise_std or sigma}
    bound = _mdu_bound(traj, landmarks, sigma, None, **priors)
    dim = spec.get("dim", 3)
    scale = float(np.median(true_r))
    ok, why = _identifiable(bound, scale, "3-D data fitted with dim=2" if dim == 2 else "")
    run = partial(slam, r, step_bounds=bounds, dim=dim, noise_std=noise_std, rng=rng)
    judge = _receiver_judge(traj, bound, scale)
    return VerdictCase("slam", regime, run, judge, bound, scale, ok, why, seed)


_SLAM: dict[str, dict] = {
    "M=4, no bounds": {"m": 4},
    "M=6, bounds": {"m": 6, "bounds": True},
    "M=8, bounds": {"m": 8, "bounds": True},
    "M=10, bounds": {"m": 10, "bounds": True},
    "M=6, no bounds": {"m": 6},
    "M=8, no bounds": {"m": 8},
    "M=10, no bounds": {"m": 10},
    "M=8 bounds, noise_std not given": {"m": 8, "bounds": True, "noise": "not given"},
    "M=8 bounds, noise_std x3": {"m": 8, "bounds": True, "noise": "x3"},
    "M=8 bounds, noise_std /3": {"m": 8, "bounds": True, "noise": "/3"},
    "random walk M=10": {"m": 10, "walk": "random"},
    "random walk M=10, dim=2": {"m": 10, "walk": "random", "dim": 2},
}


# --- reconstruct_room --------------------------------------------------------------------------


def _room_scene(spec: dict, rng: np.random.Generator):
    """(room, mics (M, 3), sources (J, 3)): a shoebox with random size, microphones uniform in it
    (or on a table: z = 0.9 m with a spread of 1 mm) and ``spec["j"]`` loudspeakers."""
    room = Room.shoebox(np.asarray(_ROOM_SIZE) * rng.uniform(0.8, 1.2, 3))
    mics = random_points_in_room(room, spec.get("n", 8), margin=0.3, rng=rng)
    if spec.get("table"):
        mics[:, 2] = 0.9 + rng.uniform(-5e-4, 5e-4, len(mics))
    sources = random_points_in_room(room, spec.get("j", 1), margin=0.3, rng=rng)
    return room, mics, sources


def mirror_room_gap(room: Room, mics: np.ndarray, sources: np.ndarray) -> float:
    """Sum of squared differences (m^2) between the noise-free ranges of the microphones (M, d)
    to the loudspeakers (J, d) and their first-order images, and to those points reflected
    through the microphones' best-fit plane: the mirrored room (reflection is an isometry, so it
    is a room) without refitting, an upper bound on how much worse it fits. Microphones on a
    table hear both rooms alike."""
    points = np.vstack([np.vstack([s, room.image_sources(s).positions]) for s in sources])
    mirrored = reflected(points, mics)
    return float(np.sum((range_matrix(mics, mirrored) - range_matrix(mics, points)) ** 2))


def _wall_bound(room, mics, sources, sigma, clean) -> tuple[float, float]:
    """RMS over the walls of the offset bound (at the centroids, metres) and of the normal
    angle bound (radians); inf when the information is singular."""
    try:
        off, ang = wall_crlb(
            mics, sources, room.normals, room.offsets, sigma, points=room.wall_centroids,
            mask=clean,
        )  # fmt: skip
    except DegenerateGeometryError:
        return float("inf"), float("inf")
    return float(np.sqrt(np.mean(off**2))), float(np.sqrt(np.mean(ang**2)))


def room_case(regime: str, rng: np.random.Generator, seed: int | None = None):
    """A :func:`rangeslam.reconstruct_room` case (defaults: robust); regimes in
    ``REGIMES["reconstruct_room"]``. Error: RMS over the walls of the offset at the true wall's
    centroid; right also needs the RMS normal angle within BOUND_FACTOR x its bound."""
    from rangeslam.localization.room_reconstruction import reconstruct_room

    spec = _ROOM[regime]
    sigma = spec.get("sigma", 1e-3)
    room, mics, sources = _room_scene(spec, rng)
    true_r = [echo_ranges(room, mics, s) for s in sources]
    ranges, clean = [], []
    for t in true_r:
        noisy = t + sigma * rng.standard_normal(t.shape)
        wrong = np.zeros(t.shape, dtype=bool)
        if spec.get("wrong"):
            noisy, wrong = add_outliers(noisy, spec["wrong"], min_error=0.2, max_error=1.0, rng=rng)
        ranges.append(noisy)
        clean.append(~wrong)
    scale = float(np.median(np.concatenate([t.ravel() for t in true_r])))
    bound, angle_bound = _wall_bound(room, mics, sources, sigma, np.stack(clean))
    reason = ""
    if mirror_room_gap(room, mics, sources) <= cost_level() * sigma**2:
        reason = "the room's mirror image through the microphones' plane fits within the noise"
    ok, why = _identifiable(bound, scale, reason)
    run = partial(reconstruct_room, mics, ranges, rng=rng)

    def judge(result):
        normals, offsets = np.asarray(result.wall_normals), np.asarray(result.wall_offsets)
        err = np.abs(np.einsum("kd,kd->k", normals, room.wall_centroids) - offsets)
        cos = np.clip(np.einsum("kd,kd->k", normals, room.normals), -1.0, 1.0)
        rms, rms_angle = np.sqrt(np.mean(err**2)), np.sqrt(np.mean(np.arccos(cos) ** 2))
        error, within = _within(float(rms), bound, scale)
        return error, within and rms_angle <= BOUND_FACTOR * angle_bound + EXACT_SLACK

    return VerdictCase("reconstruct_room", regime, run, judge, bound, scale, ok, why, seed)


_ROOM: dict[str, dict] = {
    "shoebox 1 mm": {},
    "shoebox 1 cm": {"sigma": 1e-2},
    "two loudspeakers": {"j": 2},
    "mics on a table": {"table": True},
    "10% wrong": {"n": 12, "wrong": 0.1},
    "20% wrong": {"n": 12, "wrong": 0.2},
    "30% wrong": {"n": 12, "wrong": 0.3},
    "40% wrong": {"n": 12, "wrong": 0.4},
}


# --- calibrate_unknown_emission ----------------------------------------------------------------


def emission_bound(mics, sources, groups, sigma: float, mask=None) -> float:
    """Receiver-gauge RMS Cramer-Rao bound (metres) of microphones (M, 3), sources (K, 3) and one
    unknown range offset per group (``groups`` (K,) integers 0..G-1) located from ranges
    r_mk = ||x_m - s_k|| + b_{groups[k]} + N(0, sigma^2) observed where ``mask`` (M, K); inf when
    the information is singular beyond the rigid motions."""
    x, s = np.asarray(mics, float), np.asarray(sources, float)
    m, k, d = len(x), len(s), x.shape[1]
    g = np.asarray(groups)
    obs = np.ones((m, k), dtype=bool) if mask is None else np.asarray(mask, bool)
    i, j = np.nonzero(obs)
    u = (x[i] - s[j]) / np.linalg.norm(x[i] - s[j], axis=1)[:, None]
    n_g = int(g.max()) + 1
    jac = np.zeros((len(i), (m + k) * d + n_g))
    for c in range(d):
        jac[np.arange(len(i)), i * d + c] = u[:, c]
        jac[np.arange(len(i)), (m + j) * d + c] = -u[:, c]
    jac[np.arange(len(i)), (m + k) * d + g[j]] = 1.0
    basis = np.vstack([rigid_motion_basis(np.vstack([x, s])), np.zeros((n_g, d * (d + 1) // 2))])
    q = np.linalg.svd(basis, full_matrices=True)[0][:, basis.shape[1] :]
    _, sv, vt = np.linalg.svd(jac @ q, full_matrices=False)
    if sv.size < q.shape[1] or sv[-1] <= max(jac.shape) * np.finfo(float).eps * sv[0]:
        return float("inf")
    half = q @ (vt.T / sv) * sigma
    cov = (half @ half.T)[: (m + k) * d, : (m + k) * d]
    proj = receiver_gauge_projection(x, s)
    cov = proj @ cov @ proj.T
    return float(np.sqrt(np.trace(cov[: m * d, : m * d]) / m))


def emission_case(regime: str, rng: np.random.Generator, seed: int | None = None):
    """A :func:`rangeslam.calibrate_unknown_emission` case: 8 microphones in a shoebox, one
    loudspeaker and its 6 first-order images (one event, offset uniform in [-1, 1] m); regimes
    in ``REGIMES["calibrate_unknown_emission"]``."""
    from rangeslam.mdu.emission import calibrate_unknown_emission

    spec = _EMISSION[regime]
    sigma = spec.get("sigma") or float(rng.choice([1e-3, 1e-2]))
    room = Room.shoebox(np.asarray(_ROOM_SIZE) * rng.uniform(0.8, 1.2, 3))
    mics = random_points_in_room(room, 8, margin=0.3, rng=rng)
    s = random_points_in_room(room, 1, margin=0.3, rng=rng)[0]
    sources = np.vstack([s, room.image_sources(s, order=1).positions])
    groups = np.zeros(len(sources), dtype=int)
    true_r = range_matrix(mics, sources)
    r = true_r + rng.uniform(-1, 1) + sigma * rng.standard_normal(true_r.shape)
    scale = float(np.median(true_r))
    bound = emission_bound(mics, sources, groups, sigma)
    ok, why = _identifiable(bound, scale, "")
    noise_std = _noise_option(spec.get("noise", "given"), sigma, rng)
    run = partial(calibrate_unknown_emission, r, groups, dim=3, noise_std=noise_std, rng=rng)
    judge = _receiver_judge(mics, bound, scale)
    return VerdictCase(
        "calibrate_unknown_emission", regime, run, judge, bound, scale, ok, why, seed
    )


_EMISSION: dict[str, dict] = {
    "1 mm": {"sigma": 1e-3},
    "1 cm": {"sigma": 1e-2},
    "noise_std not given": {"noise": "not given"},
}


# --- the catalogue -----------------------------------------------------------------------------

_BUILDERS: dict[str, tuple[Callable, dict]] = {
    "multilaterate": (multilaterate_case, _MULTI),
    "calibrate": (calibrate_case, _CALIB),
    "slam": (slam_case, _SLAM),
    "reconstruct_room": (room_case, _ROOM),
    "calibrate_unknown_emission": (emission_case, _EMISSION),
}

#: The simulated regimes of each estimator (names as in the benchmark's table).
REGIMES: dict[str, tuple[str, ...]] = {name: tuple(t) for name, (_, t) in _BUILDERS.items()}


def make_case(estimator: str, regime: str, seed: int) -> VerdictCase:
    """The simulated case ``estimator`` x ``regime`` drawn from ``np.random.default_rng(seed)``
    (the estimator's own randomness comes from the same generator): the reproduction recipe of
    any benchmark row."""
    if estimator not in REGIMES or regime not in REGIMES[estimator]:
        raise InvalidInputError(
            f"estimator and regime must be one of REGIMES; got {estimator!r}, {regime!r}"
        )
    builder, specs = _BUILDERS[estimator]
    case = builder(regime, np.random.default_rng(seed), seed)
    return replace(case, noise_std_too_small=specs[regime].get("noise") == "/3")


def draw_cases(
    n: int,
    rng: np.random.Generator | int | None = None,
    *,
    estimators: Sequence[str] | None = None,
    weights: dict[str, float] | None = None,
) -> list[VerdictCase]:
    """``n`` simulated cases spread over the regimes of ``estimators`` (default: all), each
    estimator's share proportional to ``weights`` (default 1) and its regimes taken in turn;
    every case's data drawn from a fresh integer seed taken from ``rng`` (recorded in the case)."""
    rng = as_rng(rng)
    names = list(REGIMES) if estimators is None else list(estimators)
    unknown = [e for e in names if e not in REGIMES]
    if unknown or not names:
        raise InvalidInputError(f"estimators must be among {sorted(REGIMES)}; got {names}")
    w = np.array([(weights or {}).get(e, 1.0) for e in names], dtype=float)
    if not (isinstance(n, int | np.integer) and n >= 0) or np.any(w < 0) or w.sum() <= 0:
        raise InvalidInputError(f"need an integer n >= 0 and weights >= 0; got {n!r}, {weights!r}")
    counts = np.floor(n * w / w.sum()).astype(int)
    counts[np.argsort(-w)[: n - counts.sum()]] += 1
    plan = [
        (e, REGIMES[e][i % len(REGIMES[e])])
        for e, c in zip(names, counts, strict=True)
        for i in range(c)
    ]
    return [make_case(e, r, int(rng.integers(2**31))) for e, r in plan]


# --- real data ---------------------------------------------------------------------------------


def _dechorate_cases(data_dir: Path) -> list[VerdictCase]:
    """dEchorate: ``calibrate`` with defaults on both loudspeakers (right: median microphone error
    <= 3 cm and none above 10 cm, after alignment with reflection) and ``reconstruct_room`` per
    loudspeaker (right: every wall offset at its centroid within 10 cm)."""
    from rangeslam.datasets import load_dechorate
    from rangeslam.localization.room_reconstruction import reconstruct_room
    from rangeslam.mdu.calibration import calibrate

    data = load_dechorate(data_dir)
    ranges = np.hstack([data.ranges(0), data.ranges(1)])
    scale = float(np.nanmedian(ranges))

    def judge_cal(result):
        err = align(np.asarray(result.receivers), data.mics, reflection=True).errors
        return float(np.median(err)), bool(np.median(err) <= 0.03 and err.max() <= 0.10)

    def judge_room(result):
        normals, offsets = np.asarray(result.wall_normals), np.asarray(result.wall_offsets)
        err = np.abs(np.einsum("kd,kd->k", normals, data.room.wall_centroids) - offsets)
        return float(err.max()), bool(err.max() <= 0.10)

    cases = [
        VerdictCase(
            "calibrate", "dEchorate, defaults", partial(calibrate, ranges, rng=0), judge_cal,
            float("nan"), scale, True,
        )
    ]  # fmt: skip
    for j in (0, 1):
        run = partial(reconstruct_room, data.mics, [data.ranges(j)], rng=j)
        cases.append(
            VerdictCase(
                "reconstruct_room", "dEchorate, one loudspeaker", run, judge_room,
                float("nan"), scale, True,
            )
        )  # fmt: skip
    return cases


def _plaza_head(data, n_steps: int):
    """The first ``n_steps`` odometry steps of a Plaza data set and the ranges up to then."""
    keep = data.range_time <= data.odometry_time[n_steps - 1]
    fields = ("range_time", "range_sender", "range_beacon", "ranges", "range_row")
    return replace(
        data,
        odometry_time=data.odometry_time[:n_steps],
        odometry=data.odometry[:n_steps],
        truth_time=data.truth_time[: n_steps + 1],
        truth=data.truth[: n_steps + 1],
        **{f: getattr(data, f)[keep] for f in fields},
    )


def _plaza_cases(steps: Sequence[int]) -> list[VerdictCase]:
    """Plaza1 (never Plaza2, the unseen set): ``beacon_slam`` with defaults on the first
    ``steps`` odometry steps. Right: mean APE <= 0.5 m and the fitted range model scale r + bias
    within 0.5 m of the full run's over the measured ranges."""
    from rangeslam.beacons import RangeOdometry, beacon_slam
    from rangeslam.datasets import plaza
    from rangeslam.evaluation.metrics import ape

    full = plaza("Plaza1")
    ref = beacon_slam(RangeOdometry.from_plaza(full), start_pose=full.truth[0])
    r_lo, r_hi = float(np.min(full.ranges)), float(np.max(full.ranges))

    def judge(sub, result):
        truth = sub.truth_at(sub.pose_time)
        mean_ape = float(
            np.nanmean(ape(result.poses[:, :2], truth, result.beacons, sub.beacons).errors)
        )
        ds = np.asarray(result.range_scale) - np.asarray(ref.range_scale)
        db = np.asarray(result.range_bias) - np.asarray(ref.range_bias)
        model = max(np.max(np.abs(ds * r + db)) for r in (r_lo, r_hi))
        return mean_ape, bool(mean_ape <= 0.5 and model <= 0.5)

    cases = []
    for n in steps:
        sub = _plaza_head(full, n)
        run = partial(beacon_slam, RangeOdometry.from_plaza(sub), start_pose=sub.truth[0])
        cases.append(
            VerdictCase(
                "beacon_slam", f"Plaza1 first {n} steps", run, partial(judge, sub),
                float("nan"), float(np.median(sub.ranges)), True,
            )
        )  # fmt: skip
    return cases


def real_cases(
    data_dir: str | Path | None, *, plaza_steps: Sequence[int] = (500, 2000, 5000)
) -> tuple[list[VerdictCase], list[str]]:
    """The real-data cases that can be built here and a note for each set that cannot (absent
    data, no gtsam): dEchorate from ``data_dir`` (the folder holding ``dechorate/``) and Plaza1
    subsets (:func:`rangeslam.datasets.plaza`; the full run is made once as the reference)."""
    cases, skipped = [], []
    folder = None if data_dir is None else Path(data_dir) / "dechorate"
    if folder is not None and (folder / "echo_toa.csv").is_file():
        cases += _dechorate_cases(folder)
    else:
        skipped.append(f"dEchorate skipped: no echo_toa.csv under {folder}")
    try:
        cases += _plaza_cases(plaza_steps)
    except (ImportError, RangeSlamError, FileNotFoundError) as exc:
        skipped.append(f"Plaza1 skipped: {exc}")
    return cases, skipped
