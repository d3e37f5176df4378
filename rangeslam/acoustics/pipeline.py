"""End to end from room impulse responses: load RIRs, then a room map or a trajectory from them.

Two things can be known besides the RIRs, and they decide what is estimated:

- the microphone positions (a fixed array, one RIR per microphone, one loudspeaker): the room,
  by :func:`rangeslam.acoustics.labelling.room_from_rirs` (detect the echoes, label them with image
  sources by geometric consensus, Problem 1 of the paper for the walls);
- bounds on the steps of one microphone moving through the room (one RIR per step): the
  trajectory and the landmarks (the loudspeaker and its image sources), by
  :func:`rangeslam.acoustics.tracking.walk_from_rirs` (detect, track the echoes from step to step,
  range-only SLAM of section 4 with the eq. (11) step bounds).

:func:`load_rirs` reads an ``.npz`` or WAV files; :func:`run_rirs` runs either pipeline and returns
a :class:`RunResult`; :func:`evaluate_run` compares it with ground truth when there is some. The
``rangeslam run`` command is these three calls plus output.

Bad input is refused before anything is estimated (:class:`~rangeslam.errors.InvalidInputError`, or
:class:`~rangeslam.errors.DataFormatError` naming the file): RIRs of different lengths or sampling
rates (never padded, cropped or resampled: sample 0 must be the emission in every RIR), NaN or
infinite samples, a missing sampling rate, arrays of the wrong shape. A silent RIR (every sample 0)
is not an error: it gives a :class:`SilentRirWarning` and its row is masked (no range from it). A
clipped one (3 or more consecutive samples at its largest magnitude, the detector's test) gives a
:class:`~rangeslam.acoustics.echoes.ClippedRirWarning` and is masked too, unless ``clipped="use"``: a flat
top of 4 samples on the direct path of one RIR of ten moved its range by 1 cm and the loudspeaker
by 4 cm (from 0.01 mm), with the labelling and the reconstruction still converged (their residual
tests do not see an error that size from a compact array); so it is left out rather than passed
on as a converged answer. Too few echoes for the geometry is a result with ``converged`` False and
the reason in ``message``.
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_float_array, as_points, frozen, shape_str
from rangeslam.acoustics.echoes import CLIP_RUN, SPEED_OF_SOUND, ClippedRirWarning, clip_run
from rangeslam.errors import DataFormatError, InvalidInputError

__all__ = [
    "MEASURED_RIR_OPTIONS",
    "SHOEBOX_WALLS",
    "LoadedRirs",
    "RunErrors",
    "RunResult",
    "SilentRirWarning",
    "evaluate_run",
    "load_rirs",
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

#: Names of the walls of ``Room.shoebox(size)`` (its order), as :func:`shoebox_wall_errors` uses.
SHOEBOX_WALLS = ("west x0", "east xL", "south y0", "north yW", "floor z0", "ceiling zH")

_ARRAY_OPTIONS = ("direct_template", "label_options", "reconstruct_options")
_WALK_OPTIONS = ("keyframes", "track_options", "slam_options")


class SilentRirWarning(UserWarning):
    """A RIR has every sample 0: no range can come from it, its row is masked."""


# ---- loading ------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class LoadedRirs:
    """RIRs read by :func:`load_rirs`, with whatever else the file said. M RIRs of L samples.

    Attributes:
        rirs: (M, L) float64, sample n at time n / fs from the emission; int PCM scaled to [-1, 1).
        fs: sampling rate, Hz.
        names: (M,) where each row came from: ``"file.npz:rirs[m]"``, ``"mic03.wav"``,
            ``"array.wav:channel 2"``.
        mics: (M, d) microphone positions, metres, when an npz held them (``mics``, or dEchorate's
            ``mics_v3``); else None.
        step_bounds: (2, M - 1) lower and upper bounds on each step, metres (npz ``step_bounds``);
            else None.
        c: speed of sound, m/s (npz ``c``); else None.
        source: (d,) true loudspeaker position (npz ``source`` or ``src_v3``), for evaluation only.
        room_size: (3,) true shoebox size (npz ``room_size``), for evaluation only.
        trajectory: true microphone positions of a walk, (M, d) at every RIR or at the keyframes
            (npz ``trajectory``), for evaluation.
        keyframes: (M,) the RIRs that are SLAM steps (npz ``keyframes``), when there are more
            RIRs than steps; else None.
    """

    rirs: np.ndarray
    fs: float
    names: tuple[str, ...]
    mics: np.ndarray | None = None
    step_bounds: np.ndarray | None = None
    c: float | None = None
    source: np.ndarray | None = None
    room_size: np.ndarray | None = None
    trajectory: np.ndarray | None = None
    keyframes: np.ndarray | None = None

    @property
    def n_rirs(self) -> int:
        """M."""
        return int(self.rirs.shape[0])


def _natural_key(path: Path) -> list:
    """Sort key of a file name with its numbers compared as numbers (mic2 before mic10)."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def _check_fs(fs: object, name: str = "fs") -> float:
    if isinstance(fs, bool) or not isinstance(fs, int | float | np.integer | np.floating):
        raise InvalidInputError(f"{name} must be a positive number of Hz; got {fs!r}")
    if not (math.isfinite(fs) and fs > 0):
        raise InvalidInputError(f"{name} must be a positive number of Hz; got {fs!r}")
    return float(fs)


def _first_bad(x: np.ndarray) -> tuple[int, ...] | None:
    bad = np.argwhere(~np.isfinite(x))
    return None if len(bad) == 0 else tuple(int(i) for i in bad[0])


def load_rirs(
    path_or_paths: str | Path | Sequence[str | Path], *, fs: float | None = None
) -> LoadedRirs:
    """Read M RIRs from one ``.npz``, one multichannel WAV, or several mono WAVs.

    Args:
        path_or_paths: one of
            - an ``.npz`` with ``rirs`` (M, L) and ``fs`` (scalar, Hz), and optionally ``mics``
              (M, 3) (or dEchorate's ``mics_v3``), ``step_bounds`` (2, M - 1), ``keyframes``
              (the RIRs that are steps, when not all are), ``c`` (m/s), and
              ground truth for evaluation: ``source`` (or ``src_v3``), ``room_size``,
              ``trajectory`` (M, 3); other arrays are ignored;
            - a WAV file: each channel is one RIR;
            - a directory: its WAV files, one mono RIR each, in natural order of their names
              (``mic2.wav`` before ``mic10.wav``);
            - a list of WAV files, one mono RIR each, in the order given.
        fs: sampling rate, Hz, for an npz without ``fs``. When the files state one, ``fs`` must
            agree with it (it is a check, never a resampling).

    Integer PCM is scaled to [-1, 1) (divided by 2^(bits - 1); 8-bit is unsigned, centred first);
    float WAVs are read as they are.

    Raises:
        DataFormatError naming the file: unreadable, wrong shapes, NaN or infinite samples, files
        of different lengths or sampling rates (nothing is padded, cropped or resampled), a
        multichannel file among several, ``fs`` missing or contradicting the file.
        InvalidInputError: no such file, a directory without WAV files, a bad ``fs``.
    """
    if fs is not None:
        fs = _check_fs(fs)
    if isinstance(path_or_paths, str | Path):
        p = Path(path_or_paths)
        if p.is_dir():
            paths = sorted(
                (q for q in p.iterdir() if q.suffix.lower() == ".wav" and q.is_file()),
                key=_natural_key,
            )
            if not paths:
                npz = sorted(q.name for q in p.glob("*.npz"))
                hint = f"; it holds {', '.join(npz[:3])}: pass that file" if npz else ""
                raise InvalidInputError(f"path_or_paths: no .wav files in the directory {p}{hint}")
        else:
            paths = [p]
    elif isinstance(path_or_paths, Sequence):
        paths = [Path(q) for q in path_or_paths]
        if not paths:
            raise InvalidInputError("path_or_paths must name at least one file; got none")
    else:
        raise InvalidInputError(
            f"path_or_paths must be a path or a list of paths; got {type(path_or_paths).__name__}"
        )
    for q in paths:
        if not q.is_file():
            raise InvalidInputError(f"path_or_paths: {q} is not a file")
    suffixes = {q.suffix.lower() for q in paths}
    if ".npz" in suffixes:
        if len(paths) != 1:
            raise InvalidInputError(
                "path_or_paths: give one .npz, or WAV files; got "
                + ", ".join(str(q) for q in paths[:4])
            )
        return _load_npz(paths[0], fs)
    for q in paths:
        if q.suffix.lower() != ".wav":
            raise DataFormatError(f"{q}: not a .wav or .npz file")
    return _load_wavs(paths, fs)


def _npz_array(raw: dict, keys: tuple[str, ...], p: Path, shape: tuple[int | None, ...]):
    """The first of ``keys`` in ``raw`` as finite float64 of ``shape`` (None: any size), or None."""
    for key in keys:
        if key in raw:
            try:
                arr = np.asarray(raw[key], dtype=float)
            except (TypeError, ValueError) as exc:
                raise DataFormatError(f"{p}: {key} is not numeric ({exc})") from exc
            if arr.ndim != len(shape) or any(
                s is not None and a != s for a, s in zip(arr.shape, shape, strict=True)
            ):
                want = shape_str(tuple("*" if s is None else s for s in shape))  # type: ignore[misc]
                raise DataFormatError(
                    f"{p}: {key} must have shape {want}; got {shape_str(arr.shape)}"
                )
            bad = _first_bad(arr)
            if bad is not None:
                raise DataFormatError(f"{p}: {key}{list(bad)} is {arr[bad]}, not a finite number")
            return arr
    return None


def _load_npz(p: Path, fs: float | None) -> LoadedRirs:
    try:
        with np.load(p, allow_pickle=False) as data:
            raw = {k: data[k] for k in data.files}
    except (OSError, ValueError) as exc:
        raise DataFormatError(f"{p}: not a readable npz file ({exc})") from exc
    if "rirs" not in raw:
        raise DataFormatError(f"{p}: no 'rirs' array (M, L); it holds {sorted(raw)}")
    try:
        rirs = np.array(raw["rirs"], dtype=float)
    except (TypeError, ValueError) as exc:
        raise DataFormatError(f"{p}: rirs is not numeric ({exc})") from exc
    if rirs.ndim != 2 or rirs.shape[1] < 3 or rirs.shape[0] < 1:
        raise DataFormatError(
            f"{p}: rirs must have shape (M, L), one RIR per row; got {shape_str(rirs.shape)}"
        )
    bad = _first_bad(rirs)
    if bad is not None:
        raise DataFormatError(f"{p}: rirs[{bad[0]}] sample {bad[1]} is {rirs[bad]}")
    m = rirs.shape[0]
    file_fs = _npz_array(raw, ("fs",), p, ())
    if file_fs is None and fs is None:
        raise DataFormatError(f"{p}: no 'fs' array; give the sampling rate (fs=, --fs)")
    if file_fs is not None:
        file_fs = float(file_fs)
        if not file_fs > 0:
            raise DataFormatError(f"{p}: fs must be a positive number of Hz; got {file_fs:g}")
        if fs is not None and fs != file_fs:
            raise DataFormatError(f"{p}: fs is {file_fs:g} Hz, but fs={fs:g} was given")
    mics = _npz_array(raw, ("mics", "mics_v3"), p, (m, None))
    if mics is not None and mics.shape[1] not in (2, 3):
        raise DataFormatError(f"{p}: mics must have shape ({m}, 3); got {shape_str(mics.shape)}")
    bounds = _npz_array(raw, ("step_bounds",), p, (2, None))
    c = _npz_array(raw, ("c",), p, ())
    if c is not None and not c > 0:
        raise DataFormatError(f"{p}: c must be a positive speed of sound in m/s; got {c}")
    source = _npz_array(raw, ("source", "src_v3"), p, (None,))
    size = _npz_array(raw, ("room_size",), p, (3,))
    trajectory = _npz_array(raw, ("trajectory",), p, (None, None))
    keys = None
    if "keyframes" in raw:
        keys = np.asarray(raw["keyframes"])
        if keys.ndim != 1 or not np.issubdtype(keys.dtype, np.integer):
            raise DataFormatError(f"{p}: keyframes must be (M,) integers; got {keys.dtype}")
    n_steps = m if keys is None else len(keys)
    if bounds is not None and bounds.shape != (2, n_steps - 1):
        raise DataFormatError(
            f"{p}: step_bounds must have shape (2, {n_steps - 1}) for {n_steps} steps; got "
            f"{shape_str(bounds.shape)}"
        )
    return LoadedRirs(
        rirs=frozen(rirs),
        fs=float(file_fs if file_fs is not None else fs),
        names=tuple(f"{p.name}:rirs[{i}]" for i in range(m)),
        mics=None if mics is None else frozen(mics),
        step_bounds=None if bounds is None else frozen(bounds),
        c=None if c is None else float(c),
        source=None if source is None else frozen(source),
        room_size=None if size is None else frozen(size),
        trajectory=None if trajectory is None else frozen(trajectory),
        keyframes=None if keys is None else frozen(keys.astype(int)),
    )


def _read_wav(q: Path) -> tuple[float, np.ndarray]:
    """(fs, (C, N) float64) of one WAV file, int PCM scaled to [-1, 1)."""
    from scipy.io import wavfile

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", wavfile.WavFileWarning)  # unknown chunks (cue, list)
            rate, data = wavfile.read(q)
    except (OSError, ValueError) as exc:
        raise DataFormatError(f"{q}: not a readable WAV file ({exc})") from exc
    if data.dtype == np.uint8:
        x = (data.astype(float) - 128.0) / 128.0
    elif np.issubdtype(data.dtype, np.integer):
        x = data.astype(float) / float(2 ** (8 * data.dtype.itemsize - 1))
    else:
        x = data.astype(float)
    x = x.reshape(len(x), -1).T
    if x.shape[1] < 3:
        raise DataFormatError(f"{q}: holds {x.shape[1]} samples; a RIR needs at least 3")
    bad = _first_bad(x)
    if bad is not None:
        where = f"channel {bad[0]} " if x.shape[0] > 1 else ""
        raise DataFormatError(f"{q}: {where}sample {bad[1]} is {x[bad]}, not a finite number")
    return float(rate), x


def _load_wavs(paths: list[Path], fs: float | None) -> LoadedRirs:
    read = []
    for q in paths:
        rate, x = _read_wav(q)
        if rate <= 0:
            raise DataFormatError(f"{q}: sampling rate {rate:g} Hz in the header")
        if fs is not None and rate != fs:
            raise DataFormatError(f"{q}: sampled at {rate:g} Hz, but fs={fs:g} was given")
        if len(paths) > 1 and x.shape[0] > 1:
            raise DataFormatError(
                f"{q}: has {x.shape[0]} channels; with several files each must be mono (one RIR "
                "per file), or give one multichannel file"
            )
        q0, rate0, x0 = read[0] if read else (q, rate, x)
        if rate != rate0:
            raise DataFormatError(
                f"{q}: sampled at {rate:g} Hz, but {q0} at {rate0:g} Hz; RIRs must share one "
                "sampling rate (resample them first)"
            )
        if x.shape[1] != x0.shape[1]:
            raise DataFormatError(
                f"{q}: has {x.shape[1]} samples, but {q0} has {x0.shape[1]}; RIRs must all have "
                "the same length, sample 0 at the emission (nothing is padded or cropped)"
            )
        read.append((q, rate, x))
    names = [
        name
        for q, _, x in read
        for name in ([q.name] if len(x) == 1 else [f"{q.name}:channel {c}" for c in range(len(x))])
    ]
    return LoadedRirs(
        rirs=frozen(np.vstack([x for _, _, x in read])), fs=read[0][1], names=tuple(names)
    )


# ---- running ------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RunResult:
    """Result of :func:`run_rirs`. M RIRs; d = 3 for an array, 2 or 3 for a walk.

    Attributes:
        mode: "array" (known microphones: the room) or "walk" (step bounds: the trajectory).
        result: the pipeline's own result:
            :class:`~rangeslam.acoustics.labelling.RoomFromRirs` (array) or
            ``rangeslam.acoustics.tracking.WalkFromRirs`` (walk), with the detections and everything
            in between.
        converged: the pipeline converged (array: labelling and reconstruction converged and the
            walls bound a room; walk: tracking and SLAM converged) and gave a finite answer.
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
    """

    mode: str
    result: Any
    converged: bool
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
    bad = _first_bad(x)
    if bad is not None:
        raise InvalidInputError(f"rirs must be finite; rirs[{bad[0]}] sample {bad[1]} is {x[bad]}")
    return x


def _check_bounds(step_bounds: Any, m: int, what: str = "RIRs") -> np.ndarray:
    """(2, M - 1) finite bounds, 0 <= lower <= upper, for M steps (``what``: RIRs, keyframes)."""
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
    bad = _first_bad(b)
    if bad is not None:
        raise InvalidInputError(f"step_bounds must be finite; entry {bad} is {b[bad]}")
    if np.any(b[0] < 0) or np.any(b[0] > b[1]):
        i = int(np.argmax((b[0] < 0) | (b[0] > b[1])))
        raise InvalidInputError(
            f"step_bounds must have 0 <= lower <= upper; step {i} has [{b[0, i]:g}, {b[1, i]:g}]"
        )
    return b


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
) -> RunResult:
    """The room (known microphones) or the trajectory (step bounds) from M RIRs of one loudspeaker.

    Args:
        rirs: (M, L) RIRs, or M 1-D arrays of one length; sample n is time n / fs from the emission.
        fs: sampling rate, Hz.
        mics: (M, 3) microphone positions, metres: array mode,
            :func:`rangeslam.acoustics.labelling.room_from_rirs`.
        step_bounds: (lower, upper), each (M - 1,), or a (2, M - 1) array: bounds on the distance
            the microphone moves between consecutive RIRs, metres: walk mode,
            ``rangeslam.acoustics.tracking.walk_from_rirs``. Exactly one of ``mics`` and
            ``step_bounds``.
        c: speed of sound, m/s.
        dim: 3 for an array; 2 or 3 for a walk.
        rng: Generator or seed, passed down.
        clipped: what to do with a clipped RIR: "mask" (default: leave it out, as a silent one;
            module docstring) or "use" (keep it; its echo times near the clipped samples are less
            accurate). Both warn (:class:`~rangeslam.acoustics.echoes.ClippedRirWarning`).
        direct_template, label_options, reconstruct_options: array mode: as
            :func:`~rangeslam.acoustics.labelling.room_from_rirs`. For measured RIRs pass
            ``**MEASURED_RIR_OPTIONS``.
        detect_options: keyword arguments of :func:`rangeslam.acoustics.echoes.detect_echoes_many` (both).
        keyframes: walk mode: (M,) the RIRs that are SLAM steps, when more RIRs were recorded
            than steps (echoes are followed from RIR to RIR); ``step_bounds`` then has M - 1
            entries. Default: every RIR is a step.
        track_options, slam_options: walk mode: as ``walk_from_rirs``.

    Returns:
        A :class:`RunResult`; ``converged`` False with the reason in ``message`` when there were
        too few echoes for the geometry or a solver did not converge.

    Raises:
        InvalidInputError naming the argument: RIRs not (M, L), of different lengths, with NaN or
        infinite samples, or all silent or masked; a bad ``clipped``, ``fs``, ``c`` or ``dim``;
        both or neither of ``mics`` and ``step_bounds``; ``mics`` not (M, 3) or ``step_bounds``
        not M - 1 steps; options of the other mode. DegenerateGeometryError: coplanar microphones.
    """
    rng = np.random.default_rng(rng)
    x = _as_rirs(rirs)
    m = x.shape[0]
    fs = _check_fs(fs)
    if isinstance(c, bool) or not isinstance(c, int | float | np.integer | np.floating):
        raise InvalidInputError(f"c must be a positive speed of sound in m/s; got {c!r}")
    if not (math.isfinite(c) and c > 0):
        raise InvalidInputError(f"c must be a positive speed of sound in m/s; got {c!r}")
    c = float(c)
    if isinstance(dim, bool) or dim not in (2, 3):
        raise InvalidInputError(f"dim must be 2 or 3; got {dim!r}")
    if (mics is None) == (step_bounds is None):
        raise InvalidInputError(
            "give exactly one of mics (a known array: the room) and step_bounds (a moving "
            "microphone: its trajectory); got " + ("both" if mics is not None else "neither")
        )
    mode = "array" if mics is not None else "walk"
    given = {
        "direct_template": direct_template,
        "label_options": label_options,
        "reconstruct_options": reconstruct_options,
        "keyframes": keyframes,
        "track_options": track_options,
        "slam_options": slam_options,
    }
    other = _WALK_OPTIONS if mode == "array" else _ARRAY_OPTIONS
    wrong = [k for k in other if given[k] is not None]
    if wrong:
        raise InvalidInputError(
            f"{wrong[0]} applies to the other mode; with "
            + ("mics (array mode)" if mode == "array" else "step_bounds (walk mode)")
            + f" pass only {', '.join(('detect_options', *(_ARRAY_OPTIONS if mode == 'array' else _WALK_OPTIONS)))}"
        )

    if mode == "array":
        if dim != 3:
            raise InvalidInputError(f"dim must be 3 with mics (rooms are 3-D); got {dim}")
        pts = as_points(mics, "mics", dim=3)
        if len(pts) != m:
            raise InvalidInputError(
                f"mics must have one row per RIR, shape ({m}, 3); got {shape_str(pts.shape)}"
            )
    elif keyframes is None:
        bounds = _check_bounds(step_bounds, m)
    else:
        keys = np.asarray(keyframes)
        if keys.ndim != 1 or not np.issubdtype(keys.dtype, np.integer):
            raise InvalidInputError(
                f"keyframes must be (M,) integer indices of RIRs; got {shape_str(keys.shape)} "
                f"{keys.dtype}"
            )
        bounds = _check_bounds(step_bounds, len(keys), "keyframes")

    if clipped not in ("mask", "use"):
        raise InvalidInputError(f"clipped must be 'mask' or 'use'; got {clipped!r}")
    silent = ~np.any(x != 0, axis=1)
    if silent.all():
        raise InvalidInputError(f"rirs are all silent: every sample of the {m} RIRs is 0")
    for i in np.flatnonzero(silent):
        warnings.warn(
            f"rirs[{i}] is silent (every sample is 0): no range from it, its row is masked",
            SilentRirWarning,
            stacklevel=2,
        )
    runs = [clip_run(r) for r in x]
    is_clipped = np.array([n >= CLIP_RUN for n, _ in runs], dtype=bool)
    masked = silent | (is_clipped if clipped == "mask" else False)
    if clipped == "mask":
        for i in np.flatnonzero(is_clipped):
            n, at = runs[i]
            warnings.warn(
                f"rirs[{i}] looks clipped: {n} consecutive samples from sample {at} are at its "
                f"largest magnitude {abs(x[i, at]):.6g}; its row is masked (clipped='use' keeps "
                "it, with less accurate echo times near those samples)",
                ClippedRirWarning,
                stacklevel=2,
            )
        if masked.all():
            raise InvalidInputError(
                f"rirs: every one of the {m} RIRs is silent or clipped; pass clipped='use' to "
                "use the clipped ones"
            )
        x = np.where(masked[:, None], 0.0, x)  # a row of zeros: no detection, a masked row

    if mode == "array":
        from rangeslam.acoustics.labelling import room_from_rirs

        res = room_from_rirs(
            x,
            fs,
            pts,
            c=c,
            rng=rng,
            direct_template=direct_template,
            detect_options=detect_options,
            label_options=label_options,
            reconstruct_options=reconstruct_options,
        )
        rec, lab = res.reconstruction, res.labelling
        source = rec.sources[0] if rec is not None else lab.source
        source = frozen(np.array(source, dtype=float)) if np.all(np.isfinite(source)) else None
        if rec is not None:
            images = frozen(np.array(rec.image_sources[0]))
            normals = frozen(np.array(rec.wall_normals))
            offsets = frozen(np.array(rec.wall_offsets))
            support = frozen(np.array(lab.support[1:], dtype=int))
        else:
            images = normals = offsets = support = None
        trajectory = landmarks = keys_out = None
        finite = source is not None and (
            normals is None or bool(np.all(np.isfinite(normals)) and np.all(np.isfinite(offsets)))
        )
    else:
        try:
            from rangeslam.acoustics.tracking import walk_from_rirs
        except ImportError as exc:  # the walk pipeline ships with rangeslam.acoustics.tracking
            raise ImportError(
                "walk mode (step_bounds) needs rangeslam.acoustics.tracking.walk_from_rirs, which this "
                f"installation lacks ({exc})"
            ) from exc

        extra = {} if keyframes is None else {"keyframes": keyframes}
        res = walk_from_rirs(
            x,
            fs,
            step_bounds=(bounds[0], bounds[1]),
            c=c,
            dim=dim,
            rng=rng,
            detect_options=detect_options,
            track_options=track_options,
            slam_options=slam_options,
            **extra,
        )
        source = images = normals = offsets = support = None
        keys_out = getattr(res, "keyframes", None)
        keys_out = frozen(np.arange(m) if keys_out is None else np.array(keys_out, dtype=int))
        s = res.slam
        if s is not None:
            trajectory = frozen(np.array(s.receivers, dtype=float))
            landmarks = frozen(np.array(s.sources, dtype=float))
            finite = bool(np.all(np.isfinite(trajectory)) and np.all(np.isfinite(landmarks)))
        else:
            trajectory = landmarks = None
            finite = False

    dets = tuple(res.detections)
    no_echoes = np.array([not d.found for d in dets], dtype=bool)
    converged = bool(res.converged) and finite
    notes = []
    if res.converged and not finite:
        notes.append("the answer is not finite: not converged")
    for flags, what in (
        (silent, "silent (masked)"),
        (is_clipped, "clipped (masked)" if clipped == "mask" else "clipped (used)"),
        (no_echoes & ~masked, "without any echo detected (masked)"),
    ):
        if flags.any():
            rows = ", ".join(f"rirs[{i}]" for i in np.flatnonzero(flags))
            notes.append(f"{int(flags.sum())} of {m} RIRs {what}: {rows}")
    message = "; ".join([res.message, *notes])
    return RunResult(
        mode=mode,
        result=res,
        converged=converged,
        message=message,
        fs=fs,
        c=c,
        mics=frozen(pts) if mode == "array" else None,
        source=source,
        image_sources=images,
        wall_normals=normals,
        wall_offsets=offsets,
        wall_support=support,
        trajectory=trajectory,
        landmarks=landmarks,
        keyframes=keys_out,
        silent=frozen(silent),
        clipped=frozen(is_clipped),
        masked=frozen(np.asarray(masked, dtype=bool)),
        no_echoes=frozen(no_echoes),
    )


# ---- evaluation against ground truth ------------------------------------------------------------


def shoebox_wall_errors(
    wall_normals: ArrayLike,
    wall_offsets: ArrayLike,
    room_size: ArrayLike,
    *,
    max_angle: float = 25.0,
) -> np.ndarray:
    """(6,) metres: how far each wall of the shoebox [0, L] x [0, W] x [0, H] is from its estimate.

    For true wall k (``Room.shoebox`` order, :data:`SHOEBOX_WALLS`), the estimated wall with the
    nearest normal; the error is the distance from the centre of the true wall (the room's centre
    projected onto it) to that plane. inf when no estimated normal is within ``max_angle`` degrees.
    """
    from rangeslam.geometry.room import Room

    normals = as_points(wall_normals, "wall_normals", dim=3)
    offsets = as_float_array(wall_offsets, "wall_offsets")
    if offsets.shape != (len(normals),):
        raise InvalidInputError(
            f"wall_offsets must have shape ({len(normals)},); got {shape_str(offsets.shape)}"
        )
    room = Room.shoebox(room_size)
    centre = np.asarray(room_size, dtype=float) / 2
    out = []
    for n_true, o_true in zip(room.normals, room.offsets, strict=True):
        p = centre + (o_true - n_true @ centre) * n_true
        cos = normals @ n_true
        j = int(np.argmax(cos))
        ok = cos[j] > np.cos(np.radians(max_angle))
        out.append(abs(normals[j] @ p - offsets[j]) if ok else np.inf)
    return np.array(out)


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
    from rangeslam.geometry.alignment import align

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
            traj = float(align(run.trajectory, truth, reflection=True).rmse)
    return RunErrors(
        source_error=src_err,
        wall_errors=None if walls is None else frozen(walls),
        trajectory_rmse=traj,
    )
