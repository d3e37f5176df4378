"""End to end from room impulse responses: load RIRs, then a room map or a trajectory from them.

Two things can be known besides the RIRs, and they decide what is estimated:

- the microphone positions (a fixed array, one RIR per microphone, one loudspeaker): the room,
  by :func:`rangeslam.acoustics.labelling.room_from_rirs` (detect the echoes, label them with image
  sources by geometric consensus, Problem 1 of the paper for the walls);
- bounds on the steps of one microphone moving through the room (one RIR per step): the
  trajectory and the landmarks (the loudspeaker and its image sources), by
  :func:`rangeslam.acoustics.walk.walk_from_rirs` (detect, track the echoes from step to step,
  range-only SLAM of section 4 with the eq. (11) step bounds).

:func:`load_rirs` (:mod:`rangeslam.datasets.rir_files`, re-exported here) reads an ``.npz`` or
WAV files; :func:`run_rirs` runs either pipeline and returns a :class:`RunResult`;
:func:`evaluate_run` compares it with ground truth when there is some
(:mod:`rangeslam.evaluation.metrics`). The ``rangeslam run`` command is these three calls plus
output.

Bad input is refused before anything is estimated (:class:`~rangeslam.errors.InvalidInputError`, or
:class:`~rangeslam.errors.DataFormatError` naming the file): RIRs of different lengths or sampling
rates (never padded, cropped or resampled: sample 0 must be the emission in every RIR), NaN or
infinite samples, a missing sampling rate, arrays of the wrong shape. A silent RIR (every sample 0)
is not an error: it gives a :class:`SilentRirWarning` and its row is masked (no range from it). A
clipped one (3 or more consecutive samples at its largest magnitude, the detector's test) gives a
:class:`~rangeslam.acoustics.echoes.ClippedRirWarning` and is masked too, unless
``clipped="use"`` (see :func:`run_rirs`). Too few echoes for the geometry is a result whose
``status`` says why (``converged`` False) with the reason in ``message``.

In array mode the direct paths are checked against the microphones first
(:mod:`rangeslam.acoustics.input_sanity`, ``check_input``): a delay common to every RIR (sample 0
is not the emission; pyroomacoustics' RIRs as it writes them), a sampling rate that is not the
RIRs' and microphones not in metres are named, with what to do, in ``message`` and ``status``
(and ``input_checks``), whatever the pipeline made of the RIRs; nothing is changed in them.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import (
    as_dim,
    as_flag,
    as_float_array,
    as_points,
    as_rng,
    as_scalar,
    frozen,
    shape_str,
)
from rangeslam.acoustics.echoes import SPEED_OF_SOUND
from rangeslam.acoustics.input_sanity import (
    InputCheck,
    RirScreen,
    check_screens,
    screen_rirs,
    with_input_checks,
)
from rangeslam.acoustics.rir_notes import rir_notes
from rangeslam.acoustics.unknown_emission import (
    NOT_FINITE,
    check_unknown_emission,
    loudspeakers_unknown_emission,
    rirs_unknown_emission,
)
from rangeslam.datasets.rir_files import (
    LoadedRirs,
    SilentRirWarning,
    check_fs,
    first_bad,
    load_rirs,
)
from rangeslam.errors import InvalidInputError
from rangeslam.evaluation.metrics import SHOEBOX_WALLS, shoebox_wall_errors, trajectory_rmse
from rangeslam.logsteps import logged_step
from rangeslam.solvers.step_bounds import StepBounds
from rangeslam.status import HasStatus, Status

log = logging.getLogger(__name__)

__all__ = [
    "MEASURED_RIR_OPTIONS",
    "SHOEBOX_WALLS",
    "LoadedRirs",
    "RunErrors",
    "RunResult",
    "SilentRirWarning",
    "evaluate_run",
    "load_rirs",
    "run_loudspeakers",
    "run_rirs",
    "shoebox_wall_errors",
]

#: Options of :func:`run_rirs` (array mode) for measured RIRs, tuned on the dEchorate RIRs
#: (48 kHz, a 5.7 x 6.0 x 2.4 m room; tests/test_run.py and tests/test_echo_labelling.py).
#: A measured loudspeaker and microphone make every arrival a long ringing pulse, each of whose
#: lobes the detector would take for an echo, so the RIRs are matched-filtered with the strongest
#: direct sound (10 samples at 48 kHz before its peak to 40 after). Echoes are looked for in the
#: first 30 ms (10 m of path: first-order echoes of a room up to about 5 m across), above 3 noise
#: standard deviations; the direct path is the first peak of at least half the largest. The
#: labelling tolerance is 4 cm (measured echoes are timed to 1-2 cm, and the calibrated geometry is
#: a few centimetres off) and labels the walls it finds rather than asking for six.
MEASURED_RIR_OPTIONS: dict[str, Any] = {
    "direct_template": (10 / 48000, 40 / 48000),
    "detect_options": {"max_time": 0.03, "noise_factor": 3.0, "direct_fraction": 0.5},
    "label_options": {"tolerance": 0.04, "n_images": None},
}

_ARRAY_OPTIONS = ("direct_template", "label_options", "reconstruct_options")
_WALK_OPTIONS = ("keyframes", "track_options", "slam_options")


# ---- running ------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RunResult(HasStatus):
    """Result of :func:`run_rirs`. M RIRs; d = 3 for an array, 2 or 3 for a walk.

    Attributes:
        mode: "array" (known microphones: the room) or "walk" (step bounds: the trajectory).
        result: the pipeline's own result:
            :class:`~rangeslam.acoustics.labelling.RoomFromRirs` (array) or
            ``rangeslam.acoustics.walk.WalkFromRirs`` (walk), with the detections and everything
            in between.
        status: :attr:`~rangeslam.status.Status.CONVERGED` when the pipeline converged (array:
            labelling and reconstruction converged and the walls bound a room; walk: tracking and
            SLAM converged) and gave a finite answer; else the pipeline's own status, or
            ``SOLVER_FAILED`` for an answer that is not finite. ``converged`` is derived from it.
        message: what happened, including the RIRs that were silent or clipped.
        fs: Hz. c: m/s.
        mics: (M, 3) the microphone positions given (array mode).
        source: (3,) the loudspeaker (array mode; None when it was not found).
        image_sources: (K, 3) first-order image sources (array mode), one per wall.
        wall_normals: (K, 3) outward unit normals (array mode). wall_offsets: (K,) metres: wall k
            is {x : wall_normals[k] . x = wall_offsets[k]}.
        wall_support: (K,) microphones whose echo of wall k was labelled (array mode).
        trajectory: (M, d) the microphone at each step (walk mode; SLAM's frame, which is
            arbitrary up to a rigid motion and a reflection).
        landmarks: (K, d) the loudspeaker and image sources heard along the walk, same frame.
        keyframes: (M,) the RIR of each row of ``trajectory`` (walk mode).
        silent: (M,) True for RIRs whose every sample is 0 (masked).
        clipped: (M,) True for clipped RIRs (3 or more consecutive samples at the largest
            magnitude), masked unless ``clipped="use"``.
        masked: (M,) True for the RIRs left out (silent, or clipped and masked): the pipeline saw
            zeros there and took no range from them.
        no_echoes: (M,) True for RIRs in which the detector found nothing (masked ones included).
        sources: (J, 3) every loudspeaker (:func:`run_loudspeakers`; ``source`` is row 0; NaN
            rows, and ``source`` None, for a loudspeaker not located with an echo), or None.
        c_std: m/s, the standard deviation of ``c`` when it was estimated (``estimate_c``), else
            None.
        emission_offsets: (J,) seconds from sample 0 to each loudspeaker's emission, estimated
            (``unknown_emission``; NaN where not found), else None. emission_offset_stds: (J,)
            their standard deviations, seconds (NaN where not estimated), or None.
        input_checks: (J,) what each loudspeaker's direct paths say of the input
            (:class:`~rangeslam.acoustics.input_sanity.InputCheck`: a delay before the emission,
            a wrong ``fs``, microphones not in metres); the first that found something sets
            ``status`` and leads ``message``. None in walk mode or with ``check_input=False``.
    """

    mode: str
    result: Any
    status: Status
    message: str
    fs: float
    c: float
    mics: np.ndarray | None
    source: np.ndarray | None
    image_sources: np.ndarray | None
    wall_normals: np.ndarray | None
    wall_offsets: np.ndarray | None
    wall_support: np.ndarray | None
    trajectory: np.ndarray | None
    landmarks: np.ndarray | None
    keyframes: np.ndarray | None
    silent: np.ndarray
    clipped: np.ndarray
    masked: np.ndarray
    no_echoes: np.ndarray
    sources: np.ndarray | None = None
    c_std: float | None = None
    emission_offsets: np.ndarray | None = None
    emission_offset_stds: np.ndarray | None = None
    input_checks: tuple[InputCheck, ...] | None = None

    @property
    def n_rirs(self) -> int:
        """M."""
        return len(self.silent)

    @property
    def detections(self) -> tuple:
        """The M :class:`~rangeslam.acoustics.echoes.EchoDetection` of the RIRs."""
        return tuple(self.result.detections)


def _as_rirs(rirs: ArrayLike | Sequence[ArrayLike]) -> np.ndarray:
    """(M, L) finite float64 from an array or a list of M equally long 1-D RIRs."""
    if not isinstance(rirs, np.ndarray) and isinstance(rirs, Sequence):
        rows = [as_float_array(r, f"rirs[{m}]") for m, r in enumerate(rirs)]
        for m, r in enumerate(rows):
            if r.ndim != 1:
                raise InvalidInputError(
                    f"rirs[{m}] must be one RIR, shape (L,); got {shape_str(r.shape)}"
                )
            if len(r) != len(rows[0]):
                raise InvalidInputError(
                    f"rirs must all have the same length (nothing is padded or cropped); rirs[{m}] "
                    f"has {len(r)} samples, rirs[0] has {len(rows[0])}"
                )
        x = np.array(rows, dtype=float).reshape(len(rows), -1)
    else:
        x = as_float_array(rirs, "rirs")
    if x.ndim != 2 or x.shape[0] < 1 or x.shape[1] < 3:
        raise InvalidInputError(
            f"rirs must have shape (M, L), one RIR of at least 3 samples per row; "
            f"got {shape_str(x.shape)}"
        )
    bad = first_bad(x)
    if bad is not None:
        raise InvalidInputError(f"rirs must be finite; rirs[{bad[0]}] sample {bad[1]} is {x[bad]}")
    return x


def _check_bounds(step_bounds: Any, m: int, what: str = "RIRs") -> StepBounds:
    """Finite bounds, 0 <= lower <= upper, on the M - 1 steps of M ``what`` (RIRs, keyframes),
    as the :class:`StepBounds` that walk_from_rirs, slam and refine_graph take unchanged."""
    if m < 2:
        raise InvalidInputError(f"a walk needs at least 2 {what} (steps); got {m}")
    try:
        b = np.array([np.asarray(v, dtype=float) for v in step_bounds], dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(
            f"step_bounds must be (lower, upper), each ({m - 1},) for {m} {what}; got "
            f"{step_bounds!r:.80}"
        ) from exc
    if b.shape != (2, m - 1):
        raise InvalidInputError(
            f"step_bounds must be (lower, upper), each (M - 1,) = ({m - 1},) for {m} {what}; got "
            f"shape {shape_str(b.shape)}"
        )
    bad = first_bad(b)
    if bad is not None:
        raise InvalidInputError(f"step_bounds must be finite; entry {bad} is {b[bad]}")
    if np.any(b[0] < 0) or np.any(b[0] > b[1]):
        i = int(np.argmax((b[0] < 0) | (b[0] > b[1])))
        raise InvalidInputError(
            f"step_bounds must have 0 <= lower <= upper; step {i} has [{b[0, i]:g}, {b[1, i]:g}]"
        )
    return StepBounds(lower=b[0], upper=b[1])


def run_rirs(
    rirs: ArrayLike | Sequence[ArrayLike],
    fs: float,
    *,
    mics: ArrayLike | None = None,
    step_bounds: tuple[ArrayLike, ArrayLike] | ArrayLike | None = None,
    c: float = SPEED_OF_SOUND,
    dim: int = 3,
    rng: np.random.Generator | int | None = None,
    clipped: str = "mask",
    direct_template: tuple[float, float] | None = None,
    detect_options: dict[str, Any] | None = None,
    label_options: dict[str, Any] | None = None,
    reconstruct_options: dict[str, Any] | None = None,
    keyframes: ArrayLike | None = None,
    track_options: dict[str, Any] | None = None,
    slam_options: dict[str, Any] | None = None,
    estimate_c: bool = False,
    unknown_emission: bool = False,
    check_input: bool = True,
) -> RunResult:
    """The room (known microphones) or the trajectory (step bounds) from M RIRs of one loudspeaker.

    Args:
        rirs: (M, L) RIRs, or M 1-D arrays of one length; sample n is time n / fs from the emission.
        fs: sampling rate, Hz. mics: (M, 3) microphone positions, metres: array mode,
            :func:`rangeslam.acoustics.labelling.room_from_rirs`.
        step_bounds: (lower, upper), each (M - 1,), or a (2, M - 1) array: bounds on the distance
            the microphone moves between consecutive RIRs, metres: walk mode,
            ``rangeslam.acoustics.walk.walk_from_rirs``. Exactly one of the two.
        c: speed of sound, m/s. dim: 3 for an array; 2 or 3 for a walk. rng: Generator or seed.
        clipped: what to do with a clipped RIR: "mask" (default: leave it out, as a silent one:
            a clipped direct path can move the answer by centimetres while every residual test
            still passes) or "use" (keep it; its echo times near the clipped samples are less
            accurate). Both warn (:class:`~rangeslam.acoustics.echoes.ClippedRirWarning`).
        direct_template, label_options, reconstruct_options: array mode: as
            :func:`~rangeslam.acoustics.labelling.room_from_rirs`. For measured RIRs pass
            ``**MEASURED_RIR_OPTIONS``.
        detect_options: keyword arguments of :func:`rangeslam.acoustics.echoes.detect_echoes_many` (both).
        keyframes: walk mode: (M,) the RIRs that are SLAM steps, when more RIRs were recorded
            than steps (echoes are followed from RIR to RIR); ``step_bounds`` then has M - 1
            entries. Default: every RIR is a step.
        track_options, slam_options: walk mode: as ``walk_from_rirs``.
        estimate_c: array mode: estimate the speed of sound with the loudspeaker from the direct
            paths (:func:`rangeslam.acoustics.sound_speed.estimate_sound_speed`, ``c`` the start)
            and use it; ``c_std`` reports its standard deviation. Not with ``direct_template``.
        unknown_emission: array mode: sample 0 is not the emission (``emission_offsets``).
        check_input: array mode: what the direct paths say of the input first (``input_checks``:
            a delay before the emission, a wrong ``fs``, microphones not in metres; default True).

    Returns:
        A :class:`RunResult`; not CONVERGED, with the reason in ``message``, when the input check
        found a cause, the echoes were too few for the geometry or a solver did not converge.

    Raises:
        InvalidInputError naming the argument: RIRs not (M, L), of different lengths, with NaN or
        infinite samples, or all silent or masked; a bad ``clipped``, ``fs``, ``c`` or ``dim``;
        both or neither of ``mics`` and ``step_bounds``; ``mics`` not (M, 3) or ``step_bounds``
        not M - 1 steps; options of the other mode. DegenerateGeometryError: coplanar microphones.
    """
    rng = as_rng(rng)
    x = _as_rirs(rirs)
    fs, c, dim = check_fs(fs), _check_c(c), as_dim(dim)
    options = RirRunOptions(  # in the order of its fields
        direct_template, detect_options, label_options, reconstruct_options, keyframes,
        track_options, slam_options)  # fmt: skip
    mode, pts, bounds = _check_geometry(mics, step_bounds, options, dim, len(x))
    unknown = check_unknown_emission(unknown_emission, mode, estimate_c)
    screen = screen_rirs(x, clipped)  # before any advance smooths a clipped run
    checks = _input_checks(check_input, [screen], fs, pts, c, detect_options, unknown)
    if unknown:
        res = rirs_unknown_emission(screen, fs, pts, options, c=c, rng=rng)
        return with_input_checks(res, checks)
    speed = _estimate_c(screen.rirs, fs, pts, c, options) if estimate_c else None
    c = c if speed is None else speed.c
    if mode == "array":
        answer = _run_array(screen.rirs, fs, pts, c=c, rng=rng, options=options)
    else:
        answer = _run_walk(screen.rirs, fs, bounds, c=c, dim=dim, rng=rng, options=options)
    return _verdict(mode, answer, screen, fs=fs, c=c, mics=pts, speed=speed, checks=checks)


def _check_geometry(mics: Any, step_bounds: Any, options: RirRunOptions, dim: int, m: int):
    """(mode, (M, 3) mics or None, StepBounds or None) of :func:`run_rirs`, checked."""
    mode = _check_mode(mics, step_bounds, options)
    pts = _check_mics(mics, dim, m) if mode == "array" else None
    bounds = _check_walk_bounds(step_bounds, options.keyframes, m) if mode == "walk" else None
    return mode, pts, bounds


def _input_checks(check_input, screens, fs: float, pts, c: float, detect_options, unknown: bool):
    """The direct paths' :class:`InputCheck` of each screened set (array mode; None in walk mode
    or when ``check_input`` is False), taken with ``c`` as given, before it is estimated."""
    if not as_flag(check_input, "check_input") or pts is None:
        return None
    return check_screens(
        screens, fs, pts, c=c, detect_options=detect_options, emission_known=not unknown
    )


def _estimate_c(x: np.ndarray, fs: float, pts: Any, c: float, options: RirRunOptions):
    """The speed of sound from the RIRs' direct paths (``estimate_sound_speed``, ``c`` the start;
    ``c`` itself when it cannot be estimated, the reason in the estimate's message); array mode
    without a direct template only."""
    from rangeslam.acoustics.echoes import detect_echoes_many
    from rangeslam.acoustics.sound_speed import estimate_sound_speed

    if pts is None or options.direct_template is not None:
        raise InvalidInputError(
            "estimate_c is for array mode (mics) without direct_template; got "
            + ("step_bounds" if pts is None else "a direct_template")
        )
    dets = detect_echoes_many(x, fs, **(options.detect_options or {}))
    return estimate_sound_speed(dets, pts, c0=c)


def run_loudspeakers(
    rir_sets: Sequence[ArrayLike],
    fs: float,
    *,
    mics: ArrayLike,
    c: float = SPEED_OF_SOUND,
    rng: np.random.Generator | int | None = None,
    clipped: str = "mask",
    direct_template: tuple[float, float] | None = None,
    detect_options: dict[str, Any] | None = None,
    label_options: dict[str, Any] | None = None,
    reconstruct_options: dict[str, Any] | None = None,
    estimate_c: bool = False,
    unknown_emission: bool = False,
    check_input: bool = True,
) -> RunResult:
    """The room from J loudspeakers' RIRs at the same M known microphones, walls fitted jointly
    (:func:`rangeslam.acoustics.joint_room.room_from_loudspeakers`); array mode of
    :func:`run_rirs` for several loudspeakers. The result's per-RIR flags run over the J * M RIRs,
    loudspeaker by loudspeaker; ``sources`` holds each loudspeaker, in order (NaN where not
    located; ``source`` is loudspeaker 0, None then). ``estimate_c``: c from every loudspeaker's
    direct paths (their estimates' inverse-variance mean).
    ``unknown_emission``: as :func:`run_rirs`, one delay per loudspeaker. ``direct_template``:
    as :func:`run_rirs` (each loudspeaker's own direct sound; ``MEASURED_RIR_OPTIONS`` holds it);
    not with ``estimate_c``. ``check_input``: as :func:`run_rirs`, one check per loudspeaker.

    Raises:
        InvalidInputError as :func:`run_rirs`, naming ``rir_sets[j]``; fewer than one set.
    """
    from rangeslam.acoustics.joint_room import room_from_loudspeakers

    rng = as_rng(rng)
    if isinstance(rir_sets, np.ndarray) or not isinstance(rir_sets, Sequence) or not rir_sets:
        raise InvalidInputError("rir_sets must be a non-empty list of (M, L) RIR arrays")
    sets = [_as_rirs(x) for x in rir_sets]
    fs, c = check_fs(fs), _check_c(c)
    pts = _check_mics(mics, 3, len(sets[0]))
    for j, x in enumerate(sets):
        if len(x) != len(pts):
            raise InvalidInputError(
                f"rir_sets[{j}] must hold one RIR per microphone, {len(pts)}; got {len(x)}"
            )
    if estimate_c and direct_template is not None:
        raise InvalidInputError("estimate_c is for RIRs without direct_template; got one")
    unknown = check_unknown_emission(unknown_emission, "array", estimate_c)
    screens = [screen_rirs(x, clipped) for x in sets]
    checks = _input_checks(check_input, screens, fs, pts, c, detect_options, unknown)
    if unknown:
        opts = RirRunOptions(direct_template, detect_options, label_options, reconstruct_options)
        res = loudspeakers_unknown_emission(screens, fs, pts, opts, c=c, rng=rng)
        return with_input_checks(res, checks)
    speed = _joint_c(screens, fs, pts, c, detect_options) if estimate_c else None
    c = c if speed is None else speed.c
    res = room_from_loudspeakers(
        [s.rirs for s in screens],
        fs,
        pts,
        c=c,
        rng=rng,
        direct_template=direct_template,
        detect_options=detect_options,
        label_options=label_options,
        reconstruct_options=reconstruct_options,
    )
    screen = RirScreen(
        rirs=np.zeros((0, 0)),
        silent=np.concatenate([s.silent for s in screens]),
        clipped=np.concatenate([s.clipped for s in screens]),
        masked=np.concatenate([s.masked for s in screens]),
        clipped_mode=clipped,
    )
    rec = res.reconstruction
    answer = _joint_answer(res)
    out = _verdict("array", answer, screen, fs=fs, c=c, mics=pts, speed=speed, checks=checks)
    if rec is None:
        return out
    sources = np.full((len(sets), 3), np.nan)  # a loudspeaker not located: NaN
    sources[res.located] = rec.sources
    return replace(out, sources=frozen(sources))


def _joint_answer(res: Any) -> PipelineAnswer:
    """The answer of :func:`run_loudspeakers` from its ``room_from_loudspeakers`` result."""
    rec = res.reconstruction
    if rec is None:
        return PipelineAnswer(result=res, finite=False)
    finite = bool(
        np.all(np.isfinite(rec.sources))
        and np.all(np.isfinite(rec.wall_normals))
        and np.all(np.isfinite(rec.wall_offsets))
    )
    first = bool(res.located[0])  # else the reconstruction's row 0 is another loudspeaker
    return PipelineAnswer(
        result=res,
        finite=finite,
        source=frozen(np.array(rec.sources[0])) if first else None,
        image_sources=frozen(np.array(rec.image_sources[0])) if first else None,
        wall_normals=frozen(np.array(rec.wall_normals)),
        wall_offsets=frozen(np.array(rec.wall_offsets)),
        wall_support=frozen(rec.inliers[:, :, 1:].sum(axis=(0, 1)).astype(int)),
    )


def _joint_c(screens, fs: float, pts: np.ndarray, c: float, detect_options):
    """c from every loudspeaker's direct paths: the inverse-variance mean of the converged
    estimates (each ``estimate_sound_speed``), as one estimate; the first failure when none."""
    options = RirRunOptions(detect_options=detect_options)
    each = [_estimate_c(s.rirs, fs, pts, c, options) for s in screens]
    good = [e for e in each if e.converged]
    if not good:
        return each[0]
    w = np.array([1.0 / max(e.c_std, 1e-9) ** 2 for e in good])
    c_hat = float(np.sum(w * [e.c for e in good]) / w.sum())
    std = float(1.0 / np.sqrt(w.sum()))
    msg = (
        f"c = {c_hat:.3f} +- {std:.2g} m/s from the direct paths of {len(good)} of "
        f"{len(each)} loudspeakers (started at {c:g})"
    )
    return replace(good[0], c=c_hat, c_std=std, message=msg)


@dataclass(frozen=True)
class RirRunOptions:
    """The tuning of :func:`run_rirs`'s pipelines, None where not given: ``direct_template``,
    ``label_options``, ``reconstruct_options`` (array mode, as
    :func:`~rangeslam.acoustics.labelling.room_from_rirs`); ``keyframes``, ``track_options``,
    ``slam_options`` (walk mode, as ``walk_from_rirs``); ``detect_options`` (both)."""

    direct_template: tuple[float, float] | None = None
    detect_options: dict[str, Any] | None = None
    label_options: dict[str, Any] | None = None
    reconstruct_options: dict[str, Any] | None = None
    keyframes: Any = None
    track_options: dict[str, Any] | None = None
    slam_options: dict[str, Any] | None = None


def _check_c(c: object) -> float:
    """The speed of sound as a positive finite float, m/s."""
    return as_scalar(c, "c", low=0.0, low_open=True, expected="a positive speed of sound in m/s")


def _check_mode(mics: Any, step_bounds: Any, options: RirRunOptions) -> str:
    """The mode: "array" (mics given) or "walk" (step_bounds given); refuses both, neither, and
    options of the other mode."""
    if (mics is None) == (step_bounds is None):
        raise InvalidInputError(
            "give exactly one of mics (a known array: the room) and step_bounds (a moving "
            "microphone: its trajectory); got " + ("both" if mics is not None else "neither")
        )
    mode = "array" if mics is not None else "walk"
    other = _WALK_OPTIONS if mode == "array" else _ARRAY_OPTIONS
    wrong = [k for k in other if getattr(options, k) is not None]
    if wrong:
        raise InvalidInputError(
            f"{wrong[0]} applies to the other mode; with "
            + ("mics (array mode)" if mode == "array" else "step_bounds (walk mode)")
            + f" pass only {', '.join(('detect_options', *(_ARRAY_OPTIONS if mode == 'array' else _WALK_OPTIONS)))}"
        )
    return mode


def _check_mics(mics: ArrayLike, dim: int, m: int) -> np.ndarray:
    """(M, 3) microphone positions, one per RIR (array mode is 3-D)."""
    if dim != 3:
        raise InvalidInputError(f"dim must be 3 with mics (rooms are 3-D); got {dim}")
    pts = as_points(mics, "mics", dim=3)
    if len(pts) != m:
        raise InvalidInputError(
            f"mics must have one row per RIR, shape ({m}, 3); got {shape_str(pts.shape)}"
        )
    return pts


def _check_walk_bounds(step_bounds: Any, keyframes: ArrayLike | None, m: int) -> StepBounds:
    """Bounds for the K steps: every RIR, or the ``keyframes``."""
    if keyframes is None:
        return _check_bounds(step_bounds, m)
    keys = np.asarray(keyframes)
    if keys.ndim != 1 or not np.issubdtype(keys.dtype, np.integer):
        raise InvalidInputError(
            f"keyframes must be (M,) integer indices of RIRs; got {shape_str(keys.shape)} "
            f"{keys.dtype}"
        )
    return _check_bounds(step_bounds, len(keys), "keyframes")


@dataclass(frozen=True, eq=False)
class PipelineAnswer:
    """What either pipeline found, in :class:`RunResult`'s fields (None where the mode has none);
    ``finite``: the answer is finite (the loudspeaker, walls, trajectory and landmarks)."""

    result: Any
    finite: bool
    source: np.ndarray | None = None
    image_sources: np.ndarray | None = None
    wall_normals: np.ndarray | None = None
    wall_offsets: np.ndarray | None = None
    wall_support: np.ndarray | None = None
    trajectory: np.ndarray | None = None
    landmarks: np.ndarray | None = None
    keyframes: np.ndarray | None = None


@logged_step(log, "room: detecting and labelling echoes, reconstructing the room")
def _run_array(
    x: np.ndarray, fs: float, pts: np.ndarray, *, c: float, rng, options: RirRunOptions
) -> PipelineAnswer:
    """Array mode: :func:`~rangeslam.acoustics.labelling.room_from_rirs`, and the loudspeaker,
    first-order image sources and walls it found."""
    from rangeslam.acoustics.labelling import room_from_rirs

    res = room_from_rirs(
        x,
        fs,
        pts,
        c=c,
        rng=rng,
        direct_template=options.direct_template,
        detect_options=options.detect_options,
        label_options=options.label_options,
        reconstruct_options=options.reconstruct_options,
    )
    rec, lab = res.reconstruction, res.labelling
    source = rec.sources[0] if rec is not None else lab.source
    source = frozen(np.array(source, dtype=float)) if np.all(np.isfinite(source)) else None
    if rec is None:
        return PipelineAnswer(result=res, finite=source is not None, source=source)
    normals = frozen(np.array(rec.wall_normals))
    offsets = frozen(np.array(rec.wall_offsets))
    finite = source is not None and bool(
        np.all(np.isfinite(normals)) and np.all(np.isfinite(offsets))
    )
    return PipelineAnswer(
        result=res,
        finite=finite,
        source=source,
        image_sources=frozen(np.array(rec.image_sources[0])),
        wall_normals=normals,
        wall_offsets=offsets,
        wall_support=frozen(np.array(lab.support[1:], dtype=int)),
    )


def _run_walk(
    x: np.ndarray, fs: float, bounds: StepBounds, *, c: float, dim: int, rng, options: RirRunOptions
) -> PipelineAnswer:
    """Walk mode: ``rangeslam.acoustics.walk.walk_from_rirs`` with the eq. (11) step
    bounds, and the trajectory and landmarks of its SLAM."""
    try:
        from rangeslam.acoustics.walk import walk_from_rirs
    except ImportError as exc:  # the walk pipeline ships with rangeslam.acoustics.walk
        raise ImportError(
            "walk mode (step_bounds) needs rangeslam.acoustics.walk.walk_from_rirs, which this "
            f"installation lacks ({exc})"
        ) from exc

    extra = {} if options.keyframes is None else {"keyframes": options.keyframes}
    res = walk_from_rirs(
        x,
        fs,
        step_bounds=bounds,
        c=c,
        dim=dim,
        rng=rng,
        detect_options=options.detect_options,
        track_options=options.track_options,
        slam_options=options.slam_options,
        **extra,
    )
    keys = getattr(res, "keyframes", None)
    keys = frozen(np.arange(len(x)) if keys is None else np.array(keys, dtype=int))
    s = res.slam
    if s is None:
        return PipelineAnswer(result=res, finite=False, keyframes=keys)
    trajectory = frozen(np.array(s.receivers, dtype=float))
    landmarks = frozen(np.array(s.sources, dtype=float))
    return PipelineAnswer(
        result=res,
        finite=bool(np.all(np.isfinite(trajectory)) and np.all(np.isfinite(landmarks))),
        trajectory=trajectory,
        landmarks=landmarks,
        keyframes=keys,
    )


def _pipeline_status(res: Any) -> Status:
    """The status of a pipeline's result (its own ``status``; for a result that only says
    ``converged``, CONVERGED or SOLVER_FAILED)."""
    status = getattr(res, "status", None)
    if status is not None:
        return Status(status)
    return Status.CONVERGED if res.converged else Status.SOLVER_FAILED


def _verdict(
    mode: str,
    answer: PipelineAnswer,
    screen: RirScreen,
    *,
    fs: float,
    c: float,
    mics: Any,
    speed: Any = None,
    checks: tuple[InputCheck, ...] | None = None,
) -> RunResult:
    """The :class:`RunResult`: the pipeline's status (SOLVER_FAILED for an answer that is not
    finite), and a message naming the RIRs left out or without echoes (and the estimate of c,
    ``speed``, when there was one), then the input ``checks`` (:func:`with_input_checks`)."""
    res = answer.result
    no_echoes = np.array([not d.found for d in res.detections], dtype=bool)
    status = _pipeline_status(res)
    notes = []
    if status is Status.CONVERGED and not answer.finite:
        status = Status.SOLVER_FAILED
        notes.append(NOT_FINITE)
    notes += rir_notes(screen.silent, screen.clipped, screen.masked, no_echoes, screen.clipped_mode)
    head = [] if speed is None else [speed.message]
    out = RunResult(
        mode=mode,
        result=res,
        status=status,
        message="; ".join([*head, res.message, *notes]),
        fs=fs,
        c=c,
        mics=None if mics is None else frozen(mics),
        source=answer.source,
        image_sources=answer.image_sources,
        wall_normals=answer.wall_normals,
        wall_offsets=answer.wall_offsets,
        wall_support=answer.wall_support,
        trajectory=answer.trajectory,
        landmarks=answer.landmarks,
        keyframes=answer.keyframes,
        silent=frozen(screen.silent),
        clipped=frozen(screen.clipped),
        masked=frozen(screen.masked),
        no_echoes=frozen(no_echoes),
        c_std=speed.c_std if speed is not None and speed.converged else None,
    )
    return with_input_checks(out, checks)


# ---- evaluation against ground truth ------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RunErrors:
    """Errors of a :class:`RunResult` against ground truth (None where there was none to compare).

    Attributes:
        source_error: metres, estimated to true loudspeaker (array mode).
        wall_errors: (6,) metres per shoebox wall, :func:`shoebox_wall_errors` (array mode).
        trajectory_rmse: metres, RMS error of the trajectory after the best rigid motion with
            reflection (walk mode: SLAM's frame is arbitrary).
    """

    source_error: float | None = None
    wall_errors: np.ndarray | None = None
    trajectory_rmse: float | None = None


def evaluate_run(
    run: RunResult,
    *,
    source: ArrayLike | None = None,
    room_size: ArrayLike | None = None,
    trajectory: ArrayLike | None = None,
) -> RunErrors:
    """Compare ``run`` with what is known of the truth: the loudspeaker (3,), the shoebox size (3,)
    (walls at 0 and L, 0 and W, 0 and H), the trajectory (M, d) at the keyframes or at every RIR.
    Missing estimates give inf."""
    src_err = walls = traj = None
    if source is not None and run.mode == "array":
        s = as_float_array(source, "source").reshape(-1)
        src_err = math.inf if run.source is None else float(np.linalg.norm(run.source - s))
    if room_size is not None and run.mode == "array":
        if run.wall_normals is None or len(run.wall_normals) == 0:
            walls = np.full(6, np.inf)
        else:
            walls = shoebox_wall_errors(run.wall_normals, run.wall_offsets, room_size)
    if trajectory is not None and run.mode == "walk":
        if run.trajectory is None or not np.all(np.isfinite(run.trajectory)):
            traj = math.inf
        else:
            truth = as_points(trajectory, "trajectory")
            if len(truth) == run.n_rirs and run.keyframes is not None:
                truth = truth[run.keyframes]  # the truth at every RIR: keep the steps'
            if truth.shape != run.trajectory.shape:
                raise InvalidInputError(
                    f"trajectory must have shape {shape_str(run.trajectory.shape)}; got "
                    f"{shape_str(truth.shape)}"
                )
            traj = trajectory_rmse(run.trajectory, truth)
    return RunErrors(
        source_error=src_err,
        wall_errors=None if walls is None else frozen(walls),
        trajectory_rmse=traj,
    )
