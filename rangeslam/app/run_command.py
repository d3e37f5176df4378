"""``rangeslam run``: the room (known microphones) or the trajectory (step bounds) from RIR files.

One library call does the work (:func:`rangeslam.acoustics.pipeline.run_rirs`, then
:func:`~rangeslam.acoustics.pipeline.evaluate_run` when the file holds ground truth); this module
reads the flags and files, then prints and writes the report (Markdown, CSV, JSON, plots).
Exit 0 converged, 1 not converged, 2 bad input.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rangeslam.app.progress import format_seconds
from rangeslam.app.run_recordings import deconvolve_loaded, emission_lines, emission_plot_rirs
from rangeslam.logsteps import logged_step

__all__ = [
    "RUN_FILES",
    "RunInputs",
    "TruthErrors",
    "check_known",
    "clear_run_files",
    "errors_against_truth",
    "load_for_run",
    "read_matrix",
    "run",
    "run_inputs",
]


log = logging.getLogger(__name__)

#: Every file ``rangeslam run`` writes in its --out folder. A run that gets as far as writing
#: first deletes these (and nothing else) from the folder, so the folder holds one run's files.
RUN_FILES = (
    "run_summary.json",
    "run_summary.md",
    "run_walls.csv",
    "run_trajectory.csv",
    "run_landmarks.csv",
    "run_room.png",
    "run_trajectory.png",
    "run_rir_matrix.png",
)


#: Per-robot files of a PyFG run (run_trajectory.tum, run_trajectory_B.tum, ...), cleared too.
RUN_FILE_PATTERNS = ("run_trajectory*.tum", "run_reference*.tum")


def clear_run_files(out: Path) -> list[Path]:
    """Delete the files of an earlier run (:data:`RUN_FILES`, :data:`RUN_FILE_PATTERNS`) from
    ``out``; returns them."""
    gone = [out / name for name in RUN_FILES if (out / name).is_file()]
    gone += [q for pattern in RUN_FILE_PATTERNS for q in sorted(out.glob(pattern)) if q.is_file()]
    for path in gone:
        path.unlink()
    if gone:
        log.info("run: removed %d files of an earlier run from %s", len(gone), out)
    return gone


@dataclass(frozen=True)
class RunInputs:
    """What ``rangeslam run`` passes to ``run_rirs`` besides the RIRs.

    Attributes:
        mics: (M, 3) microphone positions, metres, or None (walk mode).
        step_bounds: (2, M - 1) step bounds, metres, or None (array mode).
        c: speed of sound, m/s.
        options: further keywords of ``run_rirs`` (the measured preset, keyframes).
        origin: where the geometry and c came from, for the report.
    """

    mics: Any
    step_bounds: Any
    c: float
    options: dict = field(default_factory=dict)
    origin: str = ""


@dataclass(frozen=True)
class RunAttempt:
    """The files loaded and the run, or the bad-input error that stopped it; the warnings seen."""

    loaded: Any = None
    inputs: RunInputs | None = None
    result: Any = None
    warnings: tuple[str, ...] = ()
    error: Exception | None = None
    emission_truth: tuple = ()
    files: tuple = ()  # several loudspeakers: each one's LoadedRirs, in the order given


def read_matrix(path: Path, flag: str):
    """A numeric matrix from .npy, or .csv / .txt (comma- or whitespace-separated, '#' comments)."""
    from rangeslam.datasets.rir_files import read_numbers
    from rangeslam.errors import DataFormatError, InvalidInputError

    if not path.is_file():
        raise InvalidInputError(f"{flag} {path}: no such file")
    try:
        return read_numbers(path, ndmin=2)
    except (OSError, ValueError) as exc:
        raise DataFormatError(f"{flag} {path}: not a readable numeric matrix ({exc})") from exc


def load_for_run(args: argparse.Namespace):
    """The RIRs named on the command line (``load_rirs``), with the errors that concern a flag
    naming it: several files of mixed forms (RIRS), a --fs the files contradict. Several .npz
    files, multichannel WAVs or directories of mono WAVs are several loudspeakers at the same
    microphones (``one_per_loudspeaker``): a list, one LoadedRirs each."""
    from rangeslam.datasets.rir_files import one_per_loudspeaker

    paths = args.rirs
    if len(paths) > 1 and one_per_loudspeaker(paths):
        return [_load_one(args, p) for p in paths]
    return _load_one(args, paths[0] if len(paths) == 1 else paths)


def _load_one(args: argparse.Namespace, source):
    """The RIRs of one loudspeaker (a path or a list of WAVs), --fs checked against them."""
    from rangeslam.datasets import load_rirs
    from rangeslam.errors import DataFormatError, InvalidInputError

    paths = [source] if isinstance(source, Path) else source
    if args.fs is None:
        return load_rirs(source)
    try:
        loaded = load_rirs(source)  # the files' own rate, when they state one
    except DataFormatError:
        return load_rirs(source, fs=args.fs)  # an npz without fs, or another error, raised again
    if loaded.fs != args.fs:
        raise InvalidInputError(
            f"--fs {args.fs:g}: {source if len(paths) == 1 else paths[0]} is sampled at "
            f"{loaded.fs:g} Hz (--fs is a check, never a resampling)"
        )
    return loaded


def _keyframes(args: argparse.Namespace, loaded):
    """(K,) int indices of the RIRs that are steps (--keyframes, else the npz's), or None."""
    import numpy as np

    from rangeslam.errors import InvalidInputError

    keys = loaded.keyframes
    if args.keyframes is not None:
        keys = read_matrix(args.keyframes, "--keyframes").reshape(-1)
        if not np.all(keys == np.round(keys)):
            raise InvalidInputError(f"--keyframes {args.keyframes}: must hold RIR indices")
        keys = keys.astype(int)
    return keys


def _known_geometry(args: argparse.Namespace, loaded, n: int) -> tuple[Any, Any, str]:
    """(mics (M, 3) or None, step bounds (2, n - 1) or None, where they came from): from the
    flags, else from the npz; exactly one of the two."""
    from rangeslam._validation import shape_str
    from rangeslam.datasets.rir_files import check_transposed
    from rangeslam.errors import InvalidInputError

    m = loaded.n_rirs
    if args.mics is not None:
        mics = read_matrix(args.mics, "--mics")
        if mics.shape != (m, 3):
            if mics.shape[1:] == (3,):  # the right microphones, RIRs stored (L, M)?
                check_transposed(loaded, f"--mics {args.mics} {shape_str(mics.shape)}", len(mics))
            raise InvalidInputError(
                f"--mics {args.mics}: must hold one row x y z per RIR, ({m}, 3); got {mics.shape}"
            )
        return mics, None, f"--mics {args.mics}"
    if args.step_bounds is not None:
        b = read_matrix(args.step_bounds, "--step-bounds")
        if b.shape == (n - 1, 2) and b.shape != (2, n - 1):
            b = b.T
        if b.shape != (2, n - 1):
            raise InvalidInputError(
                f"--step-bounds {args.step_bounds}: must hold lower and upper bounds of the "
                f"{n - 1} steps, (2, {n - 1}) or ({n - 1}, 2); got {b.shape}"
            )
        return None, b, f"--step-bounds {args.step_bounds}"
    return _geometry_from_npz(args, loaded)


def _geometry_from_npz(args: argparse.Namespace, loaded) -> tuple[Any, Any, str]:
    """(mics or None, step bounds or None, origin) from the npz, as the flags choose."""
    from rangeslam.errors import InvalidInputError

    kind = Path(args.rirs[0]).suffix.lstrip(".").lower() or "file"  # npz or sofa
    if args.mics_from_npz or args.step_bounds_from_npz:
        want = "mics" if args.mics_from_npz else "step_bounds"
        value = getattr(loaded, want)
        if value is None:
            raise InvalidInputError(f"--{want.replace('_', '-')}-from-npz: the RIRs hold no {want}")
        mics, bounds = (value, None) if want == "mics" else (None, value)
        return mics, bounds, f"{want} from the {kind}"
    if loaded.mics is not None and loaded.step_bounds is not None:
        raise InvalidInputError(
            "the npz holds both mics and step_bounds: choose with --mics-from-npz (the room) or "
            "--step-bounds-from-npz (the trajectory)"
        )
    if loaded.mics is not None:
        return loaded.mics, None, f"mics from the {kind}"
    if loaded.step_bounds is not None:
        return None, loaded.step_bounds, f"step_bounds from the {kind}"
    raise InvalidInputError(
        "say what is known: --mics FILE (microphone positions, (M, 3)) or --step-bounds FILE "
        "(bounds on each step of a moving microphone, (2, M - 1))"
    )


def run_inputs(args: argparse.Namespace, loaded) -> RunInputs:
    """The microphones or step bounds, c, and options of ``run_rirs``, from the flags and npz."""
    import numpy as np

    from rangeslam.acoustics.echoes import SPEED_OF_SOUND
    from rangeslam.acoustics.pipeline import MEASURED_RIR_OPTIONS
    from rangeslam.errors import InvalidInputError

    keys = _keyframes(args, loaded)
    n = loaded.n_rirs if keys is None else len(keys)  # steps
    mics, bounds, origin = _known_geometry(args, loaded, n)
    if bounds is None:
        if args.keyframes is not None:
            raise InvalidInputError(
                "--keyframes: keyframes are steps of a walk: give step bounds with them"
            )
        keys = None  # an npz's keyframes are a walk's; a fixed array ignores them
    check_known(args, loaded.n_rirs, keys, mics, bounds, origin)
    if args.measured and bounds is not None:
        raise InvalidInputError(
            "--measured is a preset of the array mode (room_from_rirs); not for --step-bounds"
        )
    if args.c is not None:
        c, c_origin = args.c, "--c"
    elif loaded.c is not None:
        c, c_origin = loaded.c, "the npz"
    else:
        c, c_origin = SPEED_OF_SOUND, "default"
    options = dict(MEASURED_RIR_OPTIONS) if args.measured else {}
    unknown = getattr(args, "unknown_emission", False)
    if unknown and mics is None:
        raise InvalidInputError(
            "--unknown-emission: for a known array (--mics); a walk's RIRs must start at the "
            "emission"
        )
    if unknown:
        options["unknown_emission"] = True
        c_origin += "; emission time unknown, so c as given"
    elif mics is not None and not args.measured and not getattr(args, "fixed_c", False):
        options["estimate_c"] = True
    if keys is not None:
        options["keyframes"] = keys
    return RunInputs(
        mics=None if mics is None else np.asarray(mics),
        step_bounds=bounds,
        c=float(c),
        options=options,
        origin=f"{origin}; c = {c:g} m/s ({c_origin})",
    )


def check_known(args: argparse.Namespace, m: int, keys, mics, bounds, origin: str) -> None:
    """Refuse, naming the flag or the npz key, what run_rirs would refuse in its own terms:
    keyframes that are not increasing indices of the ``m`` RIRs, microphones or bounds that are
    not finite, bounds of the wrong count or with lower > upper, --dim 2 for a room."""
    import numpy as np

    from rangeslam.errors import InvalidInputError

    if keys is not None:
        where = f"--keyframes {args.keyframes}" if args.keyframes else "the npz's keyframes"
        if len(keys) < 3 or np.any(np.diff(keys) <= 0) or keys[0] < 0 or keys[-1] >= m:
            raise InvalidInputError(
                f"{where}: must be at least 3 increasing RIR indices from 0 to {m - 1}; got "
                f"{len(keys)} from {keys.min()} to {keys.max()}"
            )
    if mics is not None:
        if args.dim == 2:
            raise InvalidInputError("--dim 2: a room is 3-D; --dim 2 is for walks (step bounds)")
        if not np.all(np.isfinite(mics)):
            raise InvalidInputError(f"{origin}: microphone positions must be finite numbers")
        return
    b = np.asarray(bounds, dtype=float)
    steps = (len(keys) if keys is not None else m) - 1
    if b.shape != (2, steps):
        raise InvalidInputError(
            f"{origin}: must hold lower and upper bounds of the {steps} steps, (2, {steps}); "
            f"got {b.shape}"
        )
    bad = np.flatnonzero(~np.isfinite(b).all(axis=0) | (b[0] < 0) | (b[0] > b[1]))
    if len(bad):
        k = int(bad[0])
        raise InvalidInputError(
            f"{origin}: step {k} has bounds [{b[0, k]:g}, {b[1, k]:g}]; each step needs "
            "0 <= lower <= upper, finite"
        )


def _announce(loaded, inputs: RunInputs, *, loudspeakers: int = 1) -> float:
    """Say on standard error what the run is about to do (a walk takes about a minute); returns
    the start time (``time.perf_counter``)."""
    if loudspeakers > 1:
        what = (
            f"{loudspeakers} loudspeakers: detecting and labelling each one's echoes, "
            "matching their walls, reconstructing the room jointly"
        )
    elif inputs.mics is not None:
        what = "detecting echoes, labelling them, reconstructing the room"
    else:
        what = "detecting and tracking echoes, then SLAM (EDM start, GTSAM); about a minute"
    files = f", {loudspeakers} files of {loaded.n_rirs}" if loudspeakers > 1 else ""
    print(
        f"rangeslam: run: {loaded.n_rirs * loudspeakers} RIRs read ({loaded.fs:g} Hz{files}); "
        f"{what} ...",
        file=sys.stderr,
        flush=True,
    )
    return time.perf_counter()


def _attempt(args: argparse.Namespace) -> RunAttempt:
    """Load the RIRs, read what is known, run the pipeline; bad input and warnings recorded."""
    import dataclasses
    import warnings

    from rangeslam.acoustics.pipeline import run_rirs
    from rangeslam.errors import DegenerateGeometryError, InvalidInputError

    loaded = inputs = res = error = None
    truth: tuple = ()
    files: tuple = ()
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always", UserWarning)
        try:
            loaded = _as_rirs(args, load_for_run(args))
            truth = tuple(
                s.emission_delay for s in (loaded if isinstance(loaded, list) else [loaded])
            )
            if isinstance(loaded, list):  # several loudspeakers
                files = tuple(loaded)
                inputs = run_inputs(args, loaded[0])
                loaded, res = _run_loudspeakers(args, loaded, inputs)
                raise _Done
            inputs = run_inputs(args, loaded)
            started = _announce(loaded, inputs)
            res = run_rirs(
                loaded.rirs,
                loaded.fs,
                mics=inputs.mics,
                step_bounds=inputs.step_bounds,
                c=inputs.c,
                dim=args.dim,
                rng=args.seed,
                clipped="use" if args.use_clipped else "mask",
                **inputs.options,
            )
            if res.emission_offsets is not None:  # the RIRs as the pipeline saw them, for the plot
                moved = emission_plot_rirs(loaded.rirs, loaded.fs, res.emission_offsets[0])
                loaded = dataclasses.replace(loaded, rirs=moved)
            print(
                f"rangeslam: run: finished in {format_seconds(time.perf_counter() - started)}",
                file=sys.stderr,
                flush=True,
            )
        except _Done:
            pass
        except (InvalidInputError, DegenerateGeometryError) as exc:
            error = exc
    caught = tuple(
        str(w.message)
        if issubclass(w.category, UserWarning)
        else f"{w.category.__name__}: {w.message}"
        for w in seen
    )
    return RunAttempt(
        loaded=loaded,
        inputs=inputs,
        result=res,
        warnings=caught,
        error=error,
        emission_truth=truth,
        files=files,
    )


def _as_rirs(args: argparse.Namespace, loaded):
    """The files read (one LoadedRirs, or one per loudspeaker) as RIRs: recordings deconvolved
    with their excitation (``deconvolve_loaded``)."""
    if isinstance(loaded, list):
        return [deconvolve_loaded(args, x, p) for x, p in zip(loaded, args.rirs, strict=True)]
    return deconvolve_loaded(args, loaded, args.rirs[0] if len(args.rirs) == 1 else args.rirs)


class _Done(Exception):
    """The several-loudspeaker run is done (leaves the one-loudspeaker path of _attempt)."""


def _run_loudspeakers(args: argparse.Namespace, sets: list, inputs: RunInputs):
    """Several .npz files, one per loudspeaker, the same microphones: the walls fitted jointly
    (``run_loudspeakers``). Returns (the files as one LoadedRirs for the report: the RIRs stacked
    loudspeaker by loudspeaker, zero-padded to the longest for the plot only, the first file's
    truth; the RunResult)."""
    import dataclasses

    import numpy as np

    from rangeslam.acoustics.pipeline import run_loudspeakers
    from rangeslam.errors import InvalidInputError

    if inputs.mics is None:
        raise InvalidInputError(
            "several RIRS files are several loudspeakers at one known array: give --mics (or "
            "npz files holding mics); a walk takes one file"
        )
    first = sets[0]
    for path, other in zip(args.rirs[1:], sets[1:], strict=True):
        if other.fs != first.fs:
            raise InvalidInputError(
                f"RIRS: {path} is sampled at {other.fs:g} Hz, {args.rirs[0]} at {first.fs:g} Hz"
            )
        if other.n_rirs != first.n_rirs:
            raise InvalidInputError(
                f"RIRS: {path} holds {other.n_rirs} RIRs, {args.rirs[0]} {first.n_rirs}: one "
                "per microphone in each"
            )
        if other.mics is not None and not np.allclose(other.mics, inputs.mics, atol=1e-6):
            raise InvalidInputError(
                f"RIRS: {path} holds other microphone positions than {inputs.origin.split(';')[0]}"
            )
    started = _announce(first, inputs, loudspeakers=len(sets))
    res = run_loudspeakers(
        [s.rirs for s in sets],
        first.fs,
        mics=inputs.mics,
        c=inputs.c,
        rng=args.seed,
        clipped="use" if args.use_clipped else "mask",
        direct_template=inputs.options.get("direct_template"),
        detect_options=inputs.options.get("detect_options"),
        label_options=inputs.options.get("label_options"),
        estimate_c=bool(inputs.options.get("estimate_c", False)),
        unknown_emission=bool(inputs.options.get("unknown_emission", False)),
    )
    print(
        f"rangeslam: run: finished in {format_seconds(time.perf_counter() - started)}",
        file=sys.stderr,
        flush=True,
    )
    length = max(s.rirs.shape[1] for s in sets)
    seen = [s.rirs for s in sets]
    if res.emission_offsets is not None:  # the RIRs as the pipeline saw them, for the plot
        seen = [
            emission_plot_rirs(x, first.fs, t)
            for x, t in zip(seen, res.emission_offsets, strict=True)
        ]
    rirs = np.vstack([np.pad(x, ((0, 0), (0, length - x.shape[1]))) for x in seen])
    names = tuple(n for s in sets for n in s.names)
    return dataclasses.replace(first, rirs=rirs, names=names, keyframes=None), res


@dataclass(frozen=True, eq=False)
class TruthErrors:
    """Errors of a run against the ground truth its file holds (None where there was none).

    Attributes:
        source_error: metres, estimated to true loudspeaker (array mode; walk mode: landmark 0,
            after the trajectory's alignment, up to its mirror image in a planar walk's plane).
        wall_errors: (W,) metres, centre of each true wall to the estimated plane with the nearest
            normal (inf: not found); the shoebox's six walls (``room_size``) or any convex room's
            (``wall_normals`` and ``wall_offsets``).
        wall_names: (W,) the true walls' names, for the report.
        trajectory_rmse: metres, RMS error of the trajectory after the best rigid motion with
            reflection (walk mode).
        landmark_errors: (K,) metres, each estimated landmark (after the trajectory's alignment)
            to the nearest true one, up to its mirror image in a planar walk's plane (walk mode,
            with the file's ``landmarks``).
    """

    source_error: float | None = None
    wall_errors: Any = None
    wall_names: tuple[str, ...] = ()
    trajectory_rmse: float | None = None
    landmark_errors: Any = None


def _wall_truth(res, loaded) -> tuple[Any, tuple[str, ...]]:
    """(W,) wall errors and names against the file's shoebox or convex room, or (None, ())."""
    import numpy as np

    from rangeslam.evaluation.metrics import SHOEBOX_WALLS
    from rangeslam.evaluation.truth import matched_wall_errors
    from rangeslam.geometry.room import Room

    if res.mode != "array" or (loaded.room_size is None and loaded.wall_normals is None):
        return None, ()
    if loaded.room_size is not None:
        room, names = Room.shoebox(loaded.room_size), SHOEBOX_WALLS
    else:
        room = Room(loaded.wall_normals, loaded.wall_offsets)
        names = tuple(
            f"wall {k} ({', '.join(f'{v:+.2f}' for v in n)})" for k, n in enumerate(room.normals)
        )
    if res.wall_normals is None or len(res.wall_normals) == 0:
        return np.full(room.n_walls, np.inf), tuple(names)
    return matched_wall_errors(res.wall_normals, res.wall_offsets, room), tuple(names)


def _landmark_truth(res, loaded) -> tuple[Any, float | None]:
    """((K,) landmark errors or None, the loudspeaker's error or None) of a walk."""
    import numpy as np

    from rangeslam.evaluation.truth import landmark_errors, walk_plane
    from rangeslam.geometry.alignment import align

    truth, marks = loaded.trajectory, res.landmarks
    if res.mode != "walk" or truth is None or res.trajectory is None or marks is None:
        return None, None
    if len(truth) == res.n_rirs and res.keyframes is not None:
        truth = truth[res.keyframes]
    if truth.shape != res.trajectory.shape or not np.all(np.isfinite(marks)):
        return None, None
    a = align(res.trajectory, truth, reflection=True)
    plane = walk_plane(truth)
    errs = src = None
    if loaded.landmarks is not None and loaded.landmarks.shape[1] == marks.shape[1]:
        errs = landmark_errors(marks, loaded.landmarks, a, plane=plane)
    if loaded.source is not None and loaded.source.shape == (marks.shape[1],):
        src = float(landmark_errors(marks[:1], loaded.source[None], a, plane=plane)[0])
    return errs, src


def errors_against_truth(res, loaded) -> TruthErrors:
    """The run ``res`` against the ground truth of ``loaded`` (source, room_size or
    wall_normals/wall_offsets, trajectory, landmarks); a truth that cannot be compared is a
    warning (the answer stands) and no errors."""
    from rangeslam.acoustics.pipeline import evaluate_run
    from rangeslam.errors import DegenerateGeometryError, InvalidInputError

    try:
        base = evaluate_run(res, source=loaded.source, trajectory=loaded.trajectory)
        walls, names = _wall_truth(res, loaded)
        marks, walk_source = _landmark_truth(res, loaded)
    except (InvalidInputError, DegenerateGeometryError) as exc:  # the answer stands; the truth not
        print(f"rangeslam: warning: ground truth not compared: {exc}", file=sys.stderr)
        return TruthErrors()
    return TruthErrors(
        source_error=base.source_error if res.mode == "array" else walk_source,
        wall_errors=walls,
        wall_names=names,
        trajectory_rmse=base.trajectory_rmse,
        landmark_errors=marks,
    )


def run(args: argparse.Namespace) -> int:
    """`rangeslam run`: the map or the trajectory from RIRs, printed, written and plotted; a
    progress line on standard error every 10 s with the step under way."""
    from rangeslam.app.beacon_run import beacon_log_given, beacon_run
    from rangeslam.app.progress import Heartbeat
    from rangeslam.app.pyfg_run import pyfg_given, pyfg_run

    if beacon_log_given(args.rirs):  # a beacon log (rangeslam.datasets.beacon_log)
        with Heartbeat("run"):
            return beacon_run(args)
    if pyfg_given(args.rirs):  # a range-aided SLAM problem (rangeslam.datasets.pyfg)
        with Heartbeat("run"):
            return pyfg_run(args)
    with Heartbeat("run"):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    """The body of :func:`run`."""
    from rangeslam.app.reports import versions, write_summary
    from rangeslam.app.run_report import (
        array_report,
        report_header,
        run_plots,
        run_record,
        walk_report,
    )

    attempt = _attempt(args)
    for text in attempt.warnings:
        print(f"rangeslam: warning: {text}", file=sys.stderr)
    if attempt.error is not None:
        print(f"rangeslam: error: {attempt.error}", file=sys.stderr)
        return 2
    res, loaded = attempt.result, attempt.loaded
    clear_run_files(args.out)
    errs = errors_against_truth(res, loaded)
    lines = report_header(args, attempt)
    record = run_record(args, attempt)
    if res.mode == "array":
        speakers = {"files": attempt.files, "paths": args.rirs}
        written = array_report(args.out, res, errs, loaded, lines, record, **speakers)
        if res.c_std is not None:
            lines += ["", f"speed of sound: {res.c:.3f} +- {res.c_std:.2g} m/s (estimated)"]
            record["c_estimated"], record["c_std"] = res.c, res.c_std
        emission_lines(res, list(attempt.emission_truth), lines, record)
    else:
        written = walk_report(args.out, res, errs, lines, record)
    plots = logged_step(log, "run: drawing the plots")(run_plots)
    written += plots(args, loaded, res, files=attempt.files)
    text = "\n".join(lines)
    (args.out / "run_summary.md").write_text(text + "\n")
    written.insert(0, write_summary(args.out / "run_summary.json", **record, versions=versions()))
    print(text)
    print("\nwritten: " + ", ".join(str(p) for p in written))
    if not res.converged:
        print(f"rangeslam: not converged: {res.message}", file=sys.stderr)
        return 1
    return 0
