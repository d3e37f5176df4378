"""A moving microphone's trajectory and landmarks from its RIRs: tracks -> EDM start -> GTSAM.

:func:`walk_from_rirs` chains echo detection (:func:`rangeslam.acoustics.echoes.detect_echoes_many`),
echo tracking (:func:`rangeslam.acoustics.tracking.track_echoes`), the EDM start with step bounds
(:func:`rangeslam.mdu.slam.slam`, eq. 11) and GTSAM refinement
(:func:`rangeslam.solvers.gtsam_graph.refine_graph`), linking the tracks of one fixed point into
one landmark by the EDM rank test with the trajectory known.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from rangeslam._robust import mad_sigma
from rangeslam._validation import (
    as_dim,
    as_rng,
    as_scalar,
    as_speed,
    check_options_for,
    frozen,
)
from rangeslam.acoustics.echoes import (
    SPEED_OF_SOUND,
    EchoDetection,
    detect_echoes,
    detect_echoes_many,
)
from rangeslam.acoustics.tracking import EchoTracks, track_echoes
from rangeslam.errors import InvalidInputError, SolverError
from rangeslam.logsteps import logged_step
from rangeslam.mdu.core import (
    canonical_frame,
    residual_status,
    rotated_covariances,
    step_prior_rows,
    unfolding_check,
)
from rangeslam.mdu.slam import SlamResult, slam
from rangeslam.solvers.gtsam_graph import refine_graph
from rangeslam.solvers.step_bounds import StepBounds
from rangeslam.status import HasStatus, Status
from rangeslam.verdict.thresholds import EXACT_RTOL

__all__ = ["WalkFromRirs", "walk_from_rirs"]

# ---- the walk: tracks -> SLAM ------------------------------------------------------------------

# Rounds of "drop the entries beyond the gate, refine again" on the start set and on the answer.
_PRUNE_ROUNDS = 3
# Gate on range residuals, in robust standard deviations, and its floor in samples (c / fs): an
# entry further than this from its landmark's fit is taken for a wrong or merged echo.
_GATE_K = 4.0
_GATE_FLOOR = 0.1

log = logging.getLogger(__name__)
#: detect_echoes_many and track_echoes with their times logged (``rangeslam -v``).
_detect_logged = logged_step(log, "walk: detecting echoes in every RIR")(detect_echoes_many)
_track_logged = logged_step(log, "walk: tracking echoes from RIR to RIR")(track_echoes)
# More than this share of the steps on a bound: the bounds decide the answer, not converged (a
# 10-step walk given bounds 1.3x too long was 17 cm off with a 2 mm residual; helper review).
_MAX_PINNED = 0.5
# Kernel of the last GTSAM run, from the gated Huber answer: Tukey's, which gives no weight to the
# few ranges biased by millimetres (merged arrivals) that Huber's still follows (Fig. 5 walks 9 and
# 10 of benchmarks/bench_walk_rirs.py: 3.41 and 3.20 mm with Huber, 2.30 and 1.20 mm with Tukey;
# Tukey in the gating rounds too made walk 10 worse, 5.1 mm).
_FINAL_KERNEL = "tukey"
#: Iteration limit of the last GTSAM fit. With the robust kernel and the step priors' dead zones
#: LM creeps: on 1 of 10 simulated Fig. 5 walks (`rangeslam simulate walk --seed 5`) it ran out of
#: GTSAM's 500 at a 0.6 mm answer and the walk was called not converged; 3000 ended it there in
#: the same 20 s run.
_FINAL_MAX_ITERATIONS = 3000


@dataclass(frozen=True, eq=False)  # arrays: compared by identity
class WalkFromRirs(HasStatus):
    """Result of :func:`walk_from_rirs`. F frames (RIRs), M steps (keyframes), K landmarks.

    Attributes:
        detections: the F echo detections.
        tracks: the :class:`EchoTracks` over the F frames (fragments of echo curves).
        keyframes: (M,) the frame of each SLAM step.
        ranges: (M, K) ranges to the landmarks (column 0: the loudspeaker, by the direct path),
            metres; NaN where ``mask`` is False.
        mask: (M, K) True where used (entries the fit rejected are False).
        columns: K tuples, the columns of ``tracks`` joined into each landmark.
        start_columns: the columns of ``tracks`` the EDM start was solved on.
        slam: the answer as a :class:`~rangeslam.mdu.slam.SlamResult` (``receivers`` (M, d) the
            trajectory, ``sources`` (K, d) the landmarks, covariances), or None when there is none.
        gate: the residual gate used to reject entries, metres.
        status: :attr:`~rangeslam.status.Status.CONVERGED` when a trajectory was found and
            passed the residual test; NOT_IDENTIFIABLE (too few echoes tracked or landmarks
            kept, or the steps sit on their bounds), SOLVER_FAILED (the EDM start or GTSAM
            failed), INCONSISTENT (the residual test failed). ``converged`` is derived from it.
        message: what happened.
    """

    detections: tuple[EchoDetection, ...]
    tracks: EchoTracks
    keyframes: np.ndarray
    ranges: np.ndarray | None
    mask: np.ndarray | None
    columns: tuple[tuple[int, ...], ...]
    start_columns: tuple[int, ...]
    slam: SlamResult | None
    gate: float
    status: Status
    message: str

    @property
    def trajectory(self) -> np.ndarray | None:
        """(M, d) the positions of the steps, or None."""
        return None if self.slam is None else self.slam.receivers

    @property
    def landmarks(self) -> np.ndarray | None:
        """(K, d) the loudspeaker (row 0) and the image sources, or None."""
        return None if self.slam is None else self.slam.sources


def _keyframes(keyframes, n_frames: int) -> np.ndarray:
    if keyframes is None:
        return np.arange(n_frames)
    k = np.asarray(keyframes)
    if k.ndim != 1 or k.size < 3 or not np.issubdtype(k.dtype, np.integer):
        raise InvalidInputError(
            f"keyframes must be at least 3 frame indices (integers); got {keyframes!r}"
        )
    if k[0] < 0 or k[-1] >= n_frames or np.any(np.diff(k) <= 0):
        raise InvalidInputError(
            f"keyframes must increase strictly within [0, {n_frames}) (one RIR per frame); "
            f"got {k.tolist()}"
        )
    return k.astype(int)


def _frame_steps(upper: np.ndarray, keyframes: np.ndarray, n_frames: int) -> np.ndarray:
    """(F - 1,) the largest move between consecutive frames: twice a step's upper bound shared
    among the frames recorded during it (frames before the first step or after the last take
    the nearest step's)."""
    per = np.maximum(2.0 * upper / np.diff(keyframes), 1e-6)  # a step bounded by 0: standing
    step_of = np.clip(
        np.searchsorted(keyframes, np.arange(n_frames - 1), side="right") - 1, 0, len(per) - 1
    )
    return per[step_of]


def _subspace(trajectory: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal basis (M, p) of the vectors rho^2 - |r|^2 a fixed point p can give along the
    trajectory r (centred): rho^2 - |r|^2 = -2 r.p + |p|^2 is affine in r, so the vector lies in
    the span of [r, 1] (p = d + 1, or 3 for a planar walk in 3-D): the EDM rank test with the
    trajectory known. Also returns (M,) |r|^2."""
    r = trajectory - trajectory.mean(axis=0)
    a = np.column_stack([-2.0 * r, np.ones(len(r))])
    u, sv, _ = np.linalg.svd(a, full_matrices=False)
    return u[:, sv > 1e-6 * sv[0]], np.sum(r**2, axis=1)


def _predict(basis: np.ndarray, ref: np.ndarray, r: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(M,) the ranges of the point whose rho^2 - ``ref`` fits the observed ``r`` best in the
    basis (:func:`_subspace`)."""
    coef, *_ = np.linalg.lstsq(basis[ok], r[ok] ** 2 - ref[ok], rcond=None)
    return np.sqrt(np.maximum(ref + basis @ coef, 0.0))


def _link(ranges, mask, columns, basis, ref, gate, min_hits):
    """Join track columns into landmarks: longest first, a column joins the first landmark whose
    ranges it agrees with where both are observed and whose fit (``_predict``) keeps every range
    within ``gate``; otherwise it starts a landmark if it fits one point itself. Returns
    [(columns, ranges (M,), observed (M,))] with at least ``min_hits`` observed each."""
    p = basis.shape[1]
    groups: list[tuple[list[int], np.ndarray, np.ndarray]] = []
    for c in sorted(columns, key=lambda c: -int(mask[:, c].sum())):
        ok_c = mask[:, c]
        if ok_c.sum() <= p:  # p hits fit any point: no test
            continue
        for cols, r, ok in groups:
            both = ok & ok_c
            if np.any(np.abs(r[both] - ranges[both, c]) > gate):
                continue
            r2 = np.where(ok_c, ranges[:, c], r)
            ok2 = ok | ok_c
            if np.max(np.abs(_predict(basis, ref, r2, ok2) - r2)[ok2]) <= gate:
                cols.append(c)
                r[:] = r2
                ok[:] = ok2
                break
        else:
            r = np.where(ok_c, ranges[:, c], np.nan)
            if np.max(np.abs(_predict(basis, ref, r, ok_c) - r)[ok_c]) <= gate:
                groups.append(([c], r, ok_c.copy()))
    return [(tuple(cols), r, ok) for cols, r, ok in groups if ok.sum() >= min_hits]


def _locate(trajectory: np.ndarray, r: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """The point at ranges ``r`` (observed where ``ok``) from the trajectory: least squares from
    starts on both sides of the trajectory's best-fit plane (a planar walk hears a point and its
    mirror image alike; either will do)."""
    centre = trajectory.mean(axis=0)
    _, _, vt = np.linalg.svd(trajectory - centre)
    normal = vt[-1]
    spread = float(np.nanmax(r[ok]))
    best = None
    for sign in (1.0, -1.0):
        x0 = centre + sign * 0.5 * spread * normal
        fit = least_squares(
            lambda x: np.linalg.norm(trajectory[ok] - x, axis=1) - r[ok], x0, method="lm"
        )
        if best is None or fit.cost < best.cost:
            best = fit
    return best.x


def _steps_on_bounds(traj: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> int:
    """Steps of ``traj`` within 2 % of the bounds' width of either bound (bounds of zero width
    not counted)."""
    steps = np.linalg.norm(np.diff(traj, axis=0), axis=1)
    width = upper - lower
    near = (steps <= lower + 0.02 * width) | (steps >= upper - 0.02 * width)
    return int(np.sum(near & (width > 0)))


def _gated_refine(traj, pts, r, mask, bounds, sigma, gate_floor):
    """GTSAM (Huber) on the ranges, then rounds of masking the entries beyond the gate
    (``_GATE_K`` robust sigmas, at least ``gate_floor``) and refining again. Returns
    (fit, mask, gate, sigma)."""
    mask = mask.copy()
    r = np.nan_to_num(r)

    gate = gate_floor
    fit = None
    for _ in range(_PRUNE_ROUNDS):
        fit = refine_graph(
            traj,
            pts,
            r,
            noise_std=sigma,
            mask=mask,
            step_bounds=bounds,
            robust="huber",
            covariances=False,
        )
        traj, pts = fit.receivers, fit.sources
        res = np.abs(np.nan_to_num(fit.residuals))
        sigma = max(mad_sigma(np.where(mask, res, np.nan)), 0.25 * gate_floor / _GATE_K)
        gate = max(_GATE_K * sigma, gate_floor)
        drop = mask & (res > gate)
        if not drop.any():
            break
        mask &= ~drop
    return fit, mask, gate, sigma


def walk_from_rirs(
    rirs: ArrayLike,
    fs: float,
    *,
    step_bounds: tuple[ArrayLike, ArrayLike],
    keyframes: ArrayLike | None = None,
    c: float = SPEED_OF_SOUND,
    dim: int = 3,
    n_start: int = 8,
    min_hits: int | None = None,
    isolation: float = 3.0,
    rng: np.random.Generator | int | None = None,
    detect_options: dict[str, Any] | None = None,
    track_options: dict[str, Any] | None = None,
    slam_options: dict[str, Any] | None = None,
) -> WalkFromRirs:
    """Trajectory and landmarks of a moving microphone from its RIRs and bounds on its steps.

    1. :func:`rangeslam.acoustics.echoes.detect_echoes_many` on every RIR (frame).
    2. :func:`track_echoes` over all frames, with the largest move between frames twice a
       step's upper bound shared among the frames recorded during it.
    3. At the M keyframes (the SLAM steps), the ``n_start`` tracks with the most hits (at least
       ``min_hits``; more where a step would hear fewer than d + 1 of them) and the direct path: :func:`rangeslam.mdu.slam` (EDM completion with the step
       bounds of eq. 11, then GTSAM, Huber kernel), each track a landmark of its own.
    4. Entries beyond a gate (4 robust sigmas of the range residuals, at least 0.1 sample) are
       masked and GTSAM run again (at most 3 rounds).
    5. Linking: a fixed point's squared ranges minus the loudspeaker's are affine in the
       position, so they lie in a (d + 1)-dimensional space known from the trajectory (the EDM
       rank test); tracks whose ranges fit one point within the gate are one landmark.
    6. GTSAM on all landmarks (each started by least squares from the trajectory), gated as in 4;
       landmarks left with d or fewer ranges dropped; a last run with Tukey's kernel.

    Args:
        rirs: (F, L) RIRs, t = 0 at the emission, one per frame. fs: Hz.
        step_bounds: (lower, upper), each (M - 1,): bounds on the steps between keyframes [m].
        keyframes: (M,) increasing frame indices of the SLAM steps (default: every frame). Record
            more RIRs than steps where steps are long: echoes are followed frame to frame.
        c: speed of sound, m/s. dim: 2 or 3.
        n_start: tracks the EDM start is solved on (besides the direct path).
        min_hits: fewest keyframes a landmark is heard at (default max(dim + 3, M // 3), at most M).
        isolation: samples; an arrival nearer than this to another in its RIR is left out (two
            arrivals that close bias each other's times). 0 keeps them all.
        rng: random generator (or seed) for the SDP's restarts.
        detect_options, track_options, slam_options: keyword arguments of
            :func:`rangeslam.acoustics.echoes.detect_echoes_many`, :func:`track_echoes` and
            :func:`rangeslam.mdu.slam` (e.g. ``noise_std``).

    Returns:
        A :class:`WalkFromRirs`; ``converged`` False, with the reason, when too few echoes were
        tracked, the SDP failed, or the answer failed its residual test.
    """
    rng = as_rng(rng)
    c, dim, isolation, dopts, topts, sopts = _check_walk_args(
        c, dim, isolation, detect_options, track_options, slam_options
    )
    dets = tuple(_detect_logged(rirs, fs, **dopts))
    prob = _parse_walk(dets, step_bounds, keyframes, dim, n_start, min_hits, isolation)
    topts.setdefault("c", c)
    max_step = topts.pop("max_step", _frame_steps(prob.bounds.upper, prob.keys, len(dets)))
    tracks = _track_logged(dets, max_step, **topts)
    prob = replace(prob, gate_floor=_GATE_FLOOR * (c / dets[0].fs))
    key = tracks.rows(prob.keys)
    mask = _isolated(prob, key)
    chosen = _choose_start(prob, key, mask)
    out = _WalkOut(prob, tracks, tuple(chosen.start_cols), dets)
    sopts = {"robust": "huber", **sopts}
    first = _first_fit(prob, key.ranges, mask, chosen, sopts, rng)
    if isinstance(first, _Failure):
        return out.result(first.status, first.message)
    start, fit0, gate = first
    land = _landmarks(prob, key.ranges, mask, chosen.candidates, fit0, gate)
    if isinstance(land, _Failure):
        return out.result(land.status, land.message)
    final = _final_fit(prob, fit0.receivers, land, start.residual_rms)
    if isinstance(final, _Failure):
        return out.result(final.status, final.message)
    return _walk_verdict(prob, out, key, start, land, final, sopts.get("noise_std"))


# ---- the steps of walk_from_rirs ---------------------------------------------------------------


@dataclass(frozen=True)
class _WalkProblem:
    """The checked inputs of :func:`walk_from_rirs`: M keyframes of F frames."""

    keys: np.ndarray  # (M,) frame of each SLAM step
    bounds: StepBounds  # (M - 1,) bounds on the steps between keyframes (eq. 11), metres
    dim: int
    n_start: int
    min_hits: int
    isolation: float  # samples
    frame_times: tuple[np.ndarray, ...]  # F: each frame's arrival times in samples
    gate_floor: float  # metres: _GATE_FLOOR samples

    @property
    def m(self) -> int:
        """M, the number of SLAM steps."""
        return len(self.keys)


@dataclass(frozen=True)
class _Failure:
    """A run that stopped early: its status and why."""

    status: Status
    message: str


@dataclass(frozen=True)
class _StartChoice:
    """Step 3: the tracks heard often enough, those the EDM start is solved on, and hits (K,)."""

    candidates: list[int]
    start_cols: list[int]
    hits: np.ndarray


@dataclass(frozen=True)
class _Landmarks:
    """Step 5: the linked landmarks (column 0 the loudspeaker): ranges and mask (M, L), starting
    points (L, 3 or d) and the track columns of each."""

    ranges: np.ndarray
    mask: np.ndarray
    points: np.ndarray
    columns: list[tuple[int, ...]]


@dataclass(frozen=True)
class _FinalFit:
    """Step 6: the last GTSAM run, on the landmarks kept, with its gate."""

    fit: Any
    ranges: np.ndarray
    mask: np.ndarray
    columns: list[tuple[int, ...]]
    gate: float
    n_linked: int  # entries linked before the gate


@dataclass(frozen=True)
class _WalkOut:
    """What every :class:`WalkFromRirs` of one run shares."""

    prob: _WalkProblem
    tracks: EchoTracks
    start_cols: tuple[int, ...]
    dets: tuple = ()

    def result(self, status, msg, ranges=None, mask=None, columns=(), answer=None, gate=None):
        """The :class:`WalkFromRirs` with these fields (``gate`` None: the gate's floor)."""
        return WalkFromRirs(
            detections=self.dets,
            tracks=self.tracks,
            keyframes=frozen(self.prob.keys),
            ranges=None if ranges is None else frozen(np.where(mask, ranges, np.nan)),
            mask=None if mask is None else frozen(mask),
            columns=tuple(columns),
            start_columns=tuple(self.start_cols),
            slam=answer,
            gate=float(self.prob.gate_floor if gate is None else gate),
            status=Status(status),
            message=msg,
        )


def _check_walk_args(c, dim, isolation, detect_options, track_options, slam_options):
    """The scalars and option dicts of :func:`walk_from_rirs`, checked before the (slow)
    detection: (c, dim, isolation, detect, track and slam options as new dicts)."""
    c = as_speed(c, "c")
    if c is None:
        raise InvalidInputError("c must be a positive speed of sound in m/s; got None")
    dim = as_dim(dim)
    isolation = as_scalar(isolation, "isolation", low=0.0, expected="a number of samples >= 0")
    dopts = check_options_for(detect_options, "detect_options", detect_echoes, passed=("rir", "fs"))
    topts = check_options_for(track_options, "track_options", track_echoes, passed=("detections",))
    sopts = check_options_for(
        slam_options, "slam_options", slam, passed=("ranges", "mask", "step_bounds", "dim", "rng")
    )
    return c, dim, isolation, dopts, topts, sopts


def _parse_walk(dets, step_bounds, keyframes, dim, n_start, min_hits, isolation):
    """Check the inputs of :func:`walk_from_rirs` once (messages name the argument)."""
    n_frames = len(dets)
    if n_frames < 3:
        raise InvalidInputError(f"rirs must hold at least 3 RIRs (frames); got {n_frames}")
    keys = _keyframes(keyframes, n_frames)
    m = len(keys)
    bounds = StepBounds.parse(step_bounds, m - 1)
    if dim not in (2, 3):
        raise InvalidInputError(f"dim must be 2 or 3; got {dim!r}")
    if not (isinstance(n_start, int | np.integer) and n_start >= dim + 1):
        raise InvalidInputError(
            f"n_start must be an integer >= dim + 1 = {dim + 1}; got {n_start!r}"
        )
    if m < dim + 2:
        raise InvalidInputError(
            f"keyframes must give at least dim + 2 = {dim + 2} steps (RIRs, when keyframes is "
            f"None); got {m}"
        )
    min_hits = min(max(dim + 3, m // 3), m) if min_hits is None else min_hits
    if not (isinstance(min_hits, int | np.integer) and dim + 2 <= min_hits <= m):
        raise InvalidInputError(
            f"min_hits must be an integer in [dim + 2, M] = [{dim + 2}, {m}]; got {min_hits!r}"
        )
    if not (isinstance(isolation, int | float | np.number) and 0 <= isolation < np.inf):
        raise InvalidInputError(f"isolation must be a number of samples >= 0; got {isolation!r}")
    return _WalkProblem(
        keys=keys,
        bounds=bounds,
        dim=dim,
        n_start=n_start,
        min_hits=min_hits,
        isolation=isolation,
        frame_times=tuple(d.times * d.fs for d in dets),
        gate_floor=math.nan,  # set once the tracks are in (c is checked by track_echoes)
    )


def _isolated(prob: _WalkProblem, key: EchoTracks) -> np.ndarray:
    """(M, K) the keyframe entries to use: arrivals nearer than ``isolation`` samples to another
    in their RIR are biased by it and left out."""
    mask = key.mask.copy()
    if prob.isolation > 0:
        for i, f in enumerate(prob.keys):
            t = prob.frame_times[f]
            if len(t) > 1:
                gap = np.abs(t[:, None] - t[None, :]) + np.diag(np.full(len(t), np.inf))
                crowded = np.flatnonzero(gap.min(axis=1) < prob.isolation)
                mask[i] &= ~np.isin(key.detection[i], crowded)
    return mask


def _choose_start(prob: _WalkProblem, key: EchoTracks, mask: np.ndarray) -> _StartChoice:
    """Step 3: the ``n_start`` tracks with the most hits (then amplitude), plus those that fill
    the steps hearing fewer than d + 1 of them."""
    hits = mask.sum(axis=0)
    candidates = [j for j in range(1, key.n_tracks) if hits[j] >= prob.min_hits]
    amp = np.where(mask, np.abs(np.nan_to_num(key.amplitudes)), 0.0).sum(axis=0) / np.maximum(
        hits, 1
    )
    ranked = sorted(candidates, key=lambda j: (-hits[j], -amp[j]))
    start_cols = ranked[: prob.n_start]
    # every step must hear dim + 1 landmarks of the start: add the tracks that fill the gaps most
    for _ in range(prob.n_start):
        short = mask[:, [0, *start_cols]].sum(axis=1) < prob.dim + 1
        rest = [j for j in ranked if j not in start_cols]
        if not short.any() or not rest:
            break
        best = max(rest, key=lambda j: int(np.sum(mask[short, j])))
        if not mask[short, best].any():
            break
        start_cols.append(best)
    return _StartChoice(candidates=candidates, start_cols=start_cols, hits=hits)


@logged_step(log, "walk: SLAM on the tracks at the steps (EDM start, then GTSAM)")
def _first_fit(prob: _WalkProblem, ranges, mask, chosen: _StartChoice, sopts, rng):
    """Steps 3-4: the EDM start on the direct path and the start tracks, then gated GTSAM.
    Returns (start, fit, gate) or a :class:`_Failure`."""
    m, dim, hits, min_hits = prob.m, prob.dim, chosen.hits, prob.min_hits
    if hits[0] < min_hits:
        return _Failure(
            Status.NOT_IDENTIFIABLE,
            f"the direct path was found clear of other arrivals at {hits[0]} of {m} steps "
            f"(< {min_hits})",
        )
    if len(chosen.start_cols) < dim + 1:
        return _Failure(
            Status.NOT_IDENTIFIABLE,
            f"{len(chosen.start_cols)} echoes were tracked over at least {min_hits} of the {m} "
            f"steps; at least {dim + 1} are needed",
        )
    cols0 = [0, *chosen.start_cols]
    try:
        start = slam(
            np.nan_to_num(ranges[:, cols0]),
            mask=mask[:, cols0],
            step_bounds=prob.bounds,
            dim=dim,
            rng=rng,
            # the full schedule: on tracked ranges of simulated RIRs (0.35 mm residuals) the cheap
            # start's lowest-cost run was a flexible one, flagged NOT_IDENTIFIABLE
            **{"edm_start": "full", **sopts},
        )
    except SolverError as exc:
        return _Failure(Status.SOLVER_FAILED, f"the EDM start failed: {exc}")
    except InvalidInputError as exc:  # e.g. the tracks leave the unfolding under-determined
        return _Failure(Status.NOT_IDENTIFIABLE, f"the EDM start refused the tracked ranges: {exc}")
    sigma0 = max(start.residual_rms, prob.gate_floor / _GATE_K)
    try:
        fit0, _, gate, _ = _gated_refine(
            start.receivers,
            start.sources,
            ranges[:, cols0],
            mask[:, cols0],
            prob.bounds,
            sigma0,
            prob.gate_floor,
        )
    except SolverError as exc:
        return _Failure(Status.SOLVER_FAILED, f"GTSAM from the EDM start failed: {exc}")
    return start, fit0, gate


@logged_step(log, "walk: landmarks from the other tracks")
def _landmarks(prob: _WalkProblem, ranges, mask, candidates, fit0, gate):
    """Step 5: link the candidate tracks into landmarks on the trajectory of ``fit0`` and start
    each by least squares. Returns :class:`_Landmarks` or a :class:`_Failure`."""
    traj = fit0.receivers
    direct = np.where(mask[:, 0], ranges[:, 0], np.nan)
    basis, ref = _subspace(traj)
    groups = _link(ranges, mask, candidates, basis, ref, gate, prob.min_hits)
    if len(groups) < prob.dim + 1:
        return _Failure(
            Status.NOT_IDENTIFIABLE,
            f"{len(groups)} landmarks were linked; at least {prob.dim + 1} are needed",
        )
    return _Landmarks(
        ranges=np.column_stack([direct] + [g[1] for g in groups]),
        mask=np.column_stack([mask[:, 0]] + [g[2] for g in groups]),
        points=np.vstack([fit0.sources[0]] + [_locate(traj, g[1], g[2]) for g in groups]),
        columns=[(0,), *[g[0] for g in groups]],
    )


@logged_step(log, "walk: final fit of trajectory and landmarks")
def _final_fit(prob: _WalkProblem, traj, land: _Landmarks, start_rms: float):
    """Step 6: gated GTSAM on all landmarks, those left with d or fewer ranges dropped, then a
    last run with ``_FINAL_KERNEL``. Returns :class:`_FinalFit` or a :class:`_Failure`."""
    dim = prob.dim
    sigma0 = max(start_rms, prob.gate_floor / _GATE_K)
    failed = _Failure(Status.SOLVER_FAILED, "")
    try:
        fit, m_all, gate, sigma = _gated_refine(
            traj, land.points, land.ranges, land.mask, prob.bounds, sigma0, prob.gate_floor
        )
    except SolverError as exc:
        return replace(failed, message=f"GTSAM on the linked landmarks failed: {exc}")
    # a landmark the gate left with d or fewer ranges is not determined: leave it out
    keep = m_all.sum(axis=0) > dim
    if not keep[0]:
        return _Failure(
            Status.NOT_IDENTIFIABLE,
            f"the direct path kept {int(m_all[:, 0].sum())} ranges through the gate of "
            f"{gate:.2g} m: the loudspeaker is not determined",
        )
    if keep.sum() < dim + 2:
        return _Failure(
            Status.NOT_IDENTIFIABLE,
            f"{int(keep.sum()) - 1} echo landmarks kept ranges through the gate",
        )
    r_all, m_all = land.ranges[:, keep], m_all[:, keep]
    try:
        fit = refine_graph(
            fit.receivers,
            fit.sources[keep],
            np.nan_to_num(r_all),
            noise_std=sigma,
            mask=m_all,
            step_bounds=prob.bounds,
            robust=_FINAL_KERNEL,
            covariances=True,
            max_iterations=_FINAL_MAX_ITERATIONS,
        )
    except SolverError as exc:
        return replace(failed, message=f"GTSAM on the linked landmarks failed: {exc}")
    cols = [c for c, k in zip(land.columns, keep, strict=True) if k]
    n_linked = int(land.mask.sum())
    return _FinalFit(fit=fit, ranges=r_all, mask=m_all, columns=cols, gate=gate, n_linked=n_linked)


@logged_step(log, "walk: verdict (identifiability, residuals)")
def _walk_verdict(prob, out: _WalkOut, key, start, land, final: _FinalFit, noise):
    """The residual test (chi-square with a known ``noise``, else relative RMS), the EDM start's
    and GTSAM's convergence, and the steps pinned on a bound; the answer in the canonical frame."""
    fit, r_all, m_all = final.fit, final.ranges, final.mask
    res = np.where(m_all, fit.residuals, np.nan)
    ssr = float(np.nansum(res**2))
    status, why = residual_status(
        ssr,
        m_all,
        prob.dim,
        noise,
        float(np.median(r_all[m_all])),
        chi_square=noise is not None,
        bounded=True,
    )
    msg = why
    if not start.converged:
        msg += f"the EDM start did not converge ({start.message}); "
        # The start only initialises the final fit: its solver running out of iterations is
        # overruled by a final fit that converged and passed the tests; a start that was not
        # identifiable or inconsistent is not.
        start_overruled = start.status is Status.SOLVER_FAILED and fit.converged
        if status is Status.CONVERGED and not start_overruled:
            status = start.status
    if not fit.converged:
        msg += f"GTSAM: {fit.message}; "
        status = Status.SOLVER_FAILED if status is Status.CONVERGED else status
    if status is Status.CONVERGED:
        check = walk_check(fit, r_all, m_all, noise, prob.bounds)
        status, msg = check.status, msg + (check.reason + "; " if check.reason else "")
    pinned = _steps_on_bounds(fit.receivers, prob.bounds.lower, prob.bounds.upper)
    if pinned > _MAX_PINNED * (prob.m - 1):
        msg += (
            f"{pinned} of the {prob.m - 1} steps sit on a step bound: the bounds, not the ranges, "
            "decide the trajectory (are they right?); "
        )
        status = Status.NOT_IDENTIFIABLE if status is Status.CONVERGED else status
    answer = _slam_answer(fit, start, res, ssr, m_all, status, msg.rstrip("; "))
    summary = (
        f"{len(final.columns) - 1} echo landmarks from "
        f"{sum(len(c) for c in final.columns[1:])} of {key.n_tracks - 1} tracks, "
        f"{int(m_all.sum())} ranges used, {final.n_linked - int(m_all.sum())} left out by the "
        f"gate of {final.gate:.2g} m"
    )
    msg = f"{summary}; {msg.rstrip('; ')}" if msg else summary
    return out.result(status, msg, r_all, m_all, final.columns, answer, final.gate)


def walk_check(fit, ranges: np.ndarray, mask: np.ndarray, noise: float | None, bounds):
    """:func:`rangeslam.mdu.core.unfolding_check` of the final fit (trajectory (M, d),
    landmarks (K, d); ``ranges`` and ``mask`` (M, K), metres) with the uniform step prior's
    information; landmarks are noted, not judged (a planar walk has their mirror images)."""
    res = fit.residuals[mask]
    n_points = sum(mask.shape)
    scale = float(np.median(ranges[mask]))
    sigma = noise or float(np.sqrt(np.mean(res**2)))
    rows = step_prior_rows(bounds, "uniform", None, fit.receivers, sigma, n_points)
    return unfolding_check(
        np.asarray(fit.receivers),
        np.asarray(fit.sources),
        np.where(mask, ranges, 0.0),
        mask,
        noise,
        EXACT_RTOL * scale,
        prior_jac=rows if sigma else None,
        what="the walk",
        judge_sources="none",
    )


def _slam_answer(fit, start, res, ssr, m_all, status: Status, message: str) -> SlamResult:
    """The :class:`~rangeslam.mdu.slam.SlamResult` of the walk, rotated to the canonical frame
    (with its covariances)."""
    rec, src, rot = canonical_frame(fit.receivers, fit.sources)
    cov_r, cov_s, cov_traj = rotated_covariances(fit, rot)
    # SlamResult reports ``converged`` (or, once converted, a ``status``)
    names = {f.name for f in fields(SlamResult)}
    verdict = {"status": status} if "status" in names else {"converged": status is Status.CONVERGED}
    return SlamResult(
        receivers=frozen(rec),
        sources=frozen(src),
        receiver_cov=frozen(cov_r),
        source_cov=frozen(cov_s),
        trajectory_cov=frozen(cov_traj),
        residuals=frozen(res),
        edm_receivers=start.edm_receivers,
        edm_sources=None,
        residual_rms=float(np.sqrt(ssr / m_all.sum())),
        message=message,
        attempts=start.attempts,
        start="edm",
        eigen_gap=start.eigen_gap,
        sdp_solves=start.sdp_solves,
        **verdict,
    )
