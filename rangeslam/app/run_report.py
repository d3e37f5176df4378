"""The report of ``rangeslam run``: Markdown lines, the JSON record, CSV files and plots of a
:class:`~rangeslam.acoustics.pipeline.RunResult`. Formatting only; the numbers come from the run
and from :func:`~rangeslam.acoustics.pipeline.evaluate_run`."""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rangeslam.app.reports import fmt, markdown, write_csv
from rangeslam.evaluation.metrics import SHOEBOX_WALLS

__all__ = [
    "WALL_COUNTS_NOTE",
    "Loudspeaker",
    "array_report",
    "loudspeaker_lines",
    "loudspeakers_of",
    "report_header",
    "run_plots",
    "run_record",
    "walk_report",
    "wall_counts",
]


def report_header(args: argparse.Namespace, attempt) -> list[str]:
    """The report's first lines: RIRs, mode, inputs, the verdict, and a table of flagged RIRs."""
    res, loaded = attempt.result, attempt.loaded
    m, length = loaded.rirs.shape
    mode_text = (
        "array mode (known microphones: the room)"
        if res.mode == "array"
        else "walk mode (step bounds: the trajectory)"
    )
    lines = [
        f"# rangeslam run: {m} RIRs, {loaded.fs:g} Hz, {length} samples "
        f"({length / loaded.fs:.3f} s), {mode_text}",
        "",
        f"inputs: {', '.join(str(p) for p in args.rirs)}; {attempt.inputs.origin}"
        + ("; measured-RIR preset" if args.measured else "")
        + f"; seed {args.seed}",
        "",
        f"**converged: {res.converged}**. {res.message}",
        "",
    ]
    flagged = res.silent | res.no_echoes | res.clipped
    if flagged.any():
        rows = [[f"rirs[{i}]", loaded.names[i], _problems(res, i)] for i in np.flatnonzero(flagged)]
        lines += [markdown(["RIR", "file", "problem"], rows), ""]
    return lines


def _problems(res, i: int) -> str:
    """What was wrong with RIR ``i``: silent, clipped, no echo detected, masked."""
    return ", ".join(
        w
        for w, f in (
            ("silent", res.silent[i]),
            ("clipped", res.clipped[i]),
            ("no echo detected", res.no_echoes[i] and not res.masked[i]),
            ("masked", res.masked[i]),
        )
        if f
    )


def run_record(args: argparse.Namespace, attempt) -> dict:
    """The JSON record's common part: inputs, mode, verdict, flagged RIRs, warnings."""
    res, loaded = attempt.result, attempt.loaded
    return {
        "command": "run",
        "inputs": [str(p) for p in args.rirs],
        "names": list(loaded.names),
        "fs": loaded.fs,
        "c": attempt.inputs.c,
        "mode": res.mode,
        "converged": res.converged,
        "message": res.message,
        "seed": args.seed,
        "measured_preset": bool(args.measured),
        "silent": [int(i) for i in np.flatnonzero(res.silent)],
        "no_echoes": [int(i) for i in np.flatnonzero(res.no_echoes)],
        "clipped": [int(i) for i in np.flatnonzero(res.clipped)],
        "masked": [int(i) for i in np.flatnonzero(res.masked)],
        "use_clipped": bool(args.use_clipped),
        "warnings": list(attempt.warnings),
    }


def array_report(
    out: Path, res, errs, loaded, lines: list[str], record: dict, *, files=(), paths=()
) -> list[Path]:
    """Array mode: the loudspeaker (every one of a several-loudspeaker run: ``files``, the
    LoadedRirs of each, read from ``paths``, with its error when its file holds the truth), the
    walls and their errors against the true room, appended to ``lines`` and ``record``; writes
    run_walls.csv; returns the files written."""
    src = res.source
    if len(files) > 1:
        lines += loudspeaker_lines(loudspeakers_of(res, files, paths), record)
    else:
        lines += [
            "| loudspeaker | x [m] | y [m] | z [m] | error [mm] |",
            "|---|---|---|---|---|",
            "| estimated | "
            + (" | ".join(fmt(float(v)) for v in src) if src is not None else "- | - | -")
            + f" | {fmt(errs.source_error, 1e3, 1)} |",
        ]
        if loaded.source is not None:
            lines.append("| true | " + " | ".join(fmt(float(v)) for v in loaded.source) + " | |")
    record["source"] = None if src is None else src.tolist()
    record["source_error_m"] = errs.source_error
    wall_rows = _wall_rows(res, loudspeakers=len(files))
    lines += ["", f"{len(wall_rows)} walls (normal . x = offset, outward normal):", ""]
    lines.append(_wall_table(wall_rows))
    if len(files) > 1 and wall_rows:
        lines += ["", WALL_COUNTS_NOTE]
    record["walls"] = wall_rows
    if errs.wall_errors is not None:
        names = getattr(errs, "wall_names", ()) or SHOEBOX_WALLS
        lines += _shoebox_lines(errs.wall_errors, names)
        record["wall_errors_m"] = dict(
            zip(names, (float(e) for e in errs.wall_errors), strict=True)
        )
    return [write_csv(out / "run_walls.csv", wall_rows)] if wall_rows else []


#: What the walls table of a several-loudspeaker run counts.
WALL_COUNTS_NOTE = (
    "microphones: those whose echo of the wall the joint fit used, from any loudspeaker; "
    "echoes: the microphone-loudspeaker pairs it used (per loudspeaker in brackets)."
)


@dataclass(frozen=True)
class Loudspeaker:
    """One loudspeaker of a several-loudspeaker run, for the report.

    Attributes:
        index: its place in the run (the order of the files). file: the file its RIRs came from.
        estimate: (3,) where the run put it, or None when it was not located.
        truth: (3,) where its file says it is, or None when the file does not say.
        error: metres from the estimate to the truth (inf: not located), or None without truth.
    """

    index: int
    file: str
    estimate: np.ndarray | None
    truth: np.ndarray | None
    error: float | None


def loudspeakers_of(res, files, paths) -> list[Loudspeaker]:
    """Every loudspeaker of a several-loudspeaker run ``res`` (``files``: each one's LoadedRirs,
    in order, read from ``paths``): its estimate, its file's truth and the error between them."""
    sources = getattr(res, "sources", None)
    out = []
    for j, f in enumerate(files):
        est = None if sources is None else np.asarray(sources[j], dtype=float)
        est = est if est is not None and np.all(np.isfinite(est)) else None
        truth = None if f.source is None else np.asarray(f.source, dtype=float).reshape(-1)
        err = None
        if truth is not None:
            err = math.inf if est is None else float(np.linalg.norm(est - truth))
        name = str(paths[j]) if j < len(paths) else f.names[0].split(":")[0]
        out.append(Loudspeaker(j, name, est, truth, err))
    return out


def loudspeaker_lines(speakers: list[Loudspeaker], record: dict) -> list[str]:
    """Every loudspeaker as Markdown lines (estimate, truth, error) and in ``record``: one entry
    per loudspeaker under "loudspeakers" (and the estimates alone under "sources", null where
    not located)."""
    errors = [s.error for s in speakers if s.error is not None and math.isfinite(s.error)]
    located = sum(s.estimate is not None for s in speakers)
    worst = f"; worst error {fmt(max(errors), 1e3, 1)} mm" if errors else ""
    if located < len(speakers):
        worst = f"; {located} of {len(speakers)} located{worst}"
    lines = [
        f"{len(speakers)} loudspeakers (fitted jointly with the walls{worst}):",
        "",
        "| loudspeaker | file | | x [m] | y [m] | z [m] | error [mm] |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in speakers:
        cells = "not located | - | - | - | -"
        if s.estimate is not None:
            where = " | ".join(fmt(float(v)) for v in s.estimate)
            cells = f"estimated | {where} | {fmt(s.error, 1e3, 1)}"
        lines.append(f"| {s.index} | {s.file} | {cells} |")
        if s.truth is not None:
            lines.append(
                f"| {s.index} | | true | " + " | ".join(fmt(float(v)) for v in s.truth) + " | |"
            )
    record["sources"] = [None if s.estimate is None else s.estimate.tolist() for s in speakers]
    record["loudspeakers"] = [
        {
            "loudspeaker": s.index,
            "file": s.file,
            "located": s.estimate is not None,
            "position": None if s.estimate is None else s.estimate.tolist(),
            "true_position": None if s.truth is None else s.truth.tolist(),
            "error_m": s.error,
        }
        for s in speakers
    ]
    return lines


def _wall_rows(res, *, loudspeakers: int = 1) -> list[dict]:
    """One CSV row per estimated wall: normal (nx, ny, nz), offset in metres, the microphones
    that heard it; with several loudspeakers also the echoes (microphone-loudspeaker pairs) the
    joint fit used, in all and per loudspeaker (:func:`wall_counts`)."""
    if res.wall_normals is None:
        return []
    counts = wall_counts(res, loudspeakers) if loudspeakers > 1 else None
    rows = []
    for k, (n, o) in enumerate(zip(res.wall_normals, res.wall_offsets, strict=True)):
        row = {"wall": k, "nx": float(n[0]), "ny": float(n[1]), "nz": float(n[2])}
        row["offset_m"] = float(o)
        if counts is None:
            row["microphones"] = int(res.wall_support[k])
        else:
            mics, per = counts
            row["microphones"] = int(mics[k])
            row["echoes"] = int(per[:, k].sum())
            row.update({f"echoes_loudspeaker{j}": int(per[j, k]) for j in range(len(per))})
        rows.append(row)
    return rows


def wall_counts(res, loudspeakers: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Of a several-loudspeaker run's joint fit: ((K,) the microphones whose echo of each wall
    it used, from any loudspeaker; (J, K) the echoes of each wall it used per loudspeaker, 0 for
    one not located), or None when there is no joint fit."""
    rec = getattr(res.result, "reconstruction", None)
    located = getattr(res.result, "located", None)
    if rec is None or located is None:
        return None
    used = np.asarray(rec.inliers, dtype=bool)[:, :, 1:]  # (located, M, K): wall echoes used
    per = np.zeros((loudspeakers, used.shape[2]), dtype=int)
    per[np.flatnonzero(located)] = used.sum(axis=1)
    return used.any(axis=0).sum(axis=0), per


def _wall_table(wall_rows: list[dict]) -> str:
    """The walls as a Markdown table (normals to 3 decimals, offsets to 0.1 mm, the microphones
    that heard each; with several loudspeakers the echoes used, per loudspeaker in brackets)."""
    per = [k for k in (wall_rows[0] if wall_rows else {}) if k.startswith("echoes_loudspeaker")]
    echoes = ["echoes (" + " + ".join(f"loudspeaker {k.removeprefix('echoes_loudspeaker')}"
                                      for k in per) + ")"] if per else []  # fmt: skip
    return markdown(
        ["wall", "normal", "offset [m]", "microphones", *echoes],
        [
            [
                str(w["wall"]),
                "(" + ", ".join(f"{round(w[a], 3) + 0.0:+.3f}" for a in ("nx", "ny", "nz")) + ")",
                f"{round(w['offset_m'], 4) + 0.0:.4f}",
                str(w["microphones"]),
                *([f"{w['echoes']} ({' + '.join(str(w[k]) for k in per)})"] if per else []),
            ]
            for w in wall_rows
        ],
    )


def _shoebox_lines(wall_errors, names=SHOEBOX_WALLS) -> list[str]:
    """The error of each true wall (mm; the shoebox's six, or any room's ``names``), as Markdown
    lines."""
    room = "shoebox" if tuple(names) == SHOEBOX_WALLS else "room"
    found = np.isfinite(wall_errors)
    worst = (
        f"; worst {fmt(float(np.max(wall_errors[found])), 1e3, 1)} mm, "
        f"{int(found.sum())} of {len(found)} found"
        if found.any()
        else ""
    )
    return [
        "",
        f"Against the true {room} (distance from the centre of each true wall to the estimated "
        f"plane with the nearest normal, within 25 degrees{worst}):",
        "",
        markdown(
            ["true wall", "error [mm]"],
            [
                [name, fmt(float(e), 1e3, 1) if np.isfinite(e) else "no wall found"]
                for name, e in zip(names, wall_errors, strict=True)
            ],
        ),
    ]


def walk_report(out: Path, res, errs, lines: list[str], record: dict) -> list[Path]:
    """Walk mode: the trajectory's length and error and the landmarks, appended to ``lines``
    and ``record``; writes run_trajectory.csv and run_landmarks.csv; returns the files."""
    from rangeslam.sim.trajectories import step_lengths

    written = []
    traj, marks = res.trajectory, res.landmarks
    if traj is not None and not (np.all(np.isfinite(traj)) and np.all(np.isfinite(marks))):
        lines.append("the trajectory or the landmarks are not finite: no answer to report")
    elif traj is not None:
        path_len = float(step_lengths(traj).sum())
        lines += [
            f"trajectory: {len(traj)} positions, {path_len:.3f} m long"
            + (
                f", RMS error {errs.trajectory_rmse * 100:.2f} cm after rigid alignment "
                "(with reflection) onto the true one"
                if errs.trajectory_rmse is not None and np.isfinite(errs.trajectory_rmse)
                else ""
            ),
            *_landmark_lines(errs),
            "",
            f"{len(marks)} landmarks (loudspeaker and image sources), SLAM frame:",
            "",
            markdown(
                ["landmark", *("xyz"[: marks.shape[1]])],
                [[str(k), *(f"{v:.4f}" for v in p)] for k, p in enumerate(marks)],
            ),
        ]
        written.append(write_csv(out / "run_trajectory.csv", _point_rows("step", traj)))
        written.append(write_csv(out / "run_landmarks.csv", _point_rows("landmark", marks)))
        record["trajectory"] = traj.tolist()
        record["landmarks"] = marks.tolist()
        record["trajectory_length_m"] = path_len
    else:
        lines.append("no trajectory: the tracking gave SLAM nothing to work on")
    record["trajectory_rmse_m"] = errs.trajectory_rmse
    land = getattr(errs, "landmark_errors", None)
    record["landmark_errors_m"] = None if land is None else [float(e) for e in land]
    record["source_error_m"] = errs.source_error
    return written


def _landmark_lines(errs) -> list[str]:
    """The loudspeaker's and the landmarks' errors against the truth (after the trajectory's
    alignment, each up to its mirror image in a planar walk's plane), when there is a truth."""
    land = getattr(errs, "landmark_errors", None)
    lines = []
    if errs.source_error is not None:
        lines.append(f"loudspeaker (landmark 0): error {errs.source_error * 100:.2f} cm")
    if land is not None and len(land):
        lines.append(
            f"landmarks: each to the nearest true image source, RMS {np.sqrt(np.mean(land**2)) * 100:.2f} "
            f"cm, median {np.median(land) * 100:.2f} cm, worst {np.max(land) * 100:.2f} cm "
            "(after the trajectory's alignment)"
        )
    return ["", *lines] if lines else []


def _point_rows(key: str, points: np.ndarray) -> list[dict]:
    """One CSV row per point (N, d): its index under ``key``, then x, y (, z)."""
    axes = "xyz"[: points.shape[1]]
    return [
        {key: i, **{a: float(v) for a, v in zip(axes, p, strict=True)}}
        for i, p in enumerate(points)
    ]


def run_plots(args: argparse.Namespace, loaded, res, *, files=()) -> list[Path]:
    """The RIR matrix (dB, detected echoes overlaid, keyframes marked), and the room (array) or
    the trajectory with the true landmarks and room when the file holds them (walk). ``files``:
    a several-loudspeaker run's LoadedRirs, one per loudspeaker (their RIRs are ``loaded``'s,
    stacked): each one's RIRs a block of the matrix with its own true arrivals, and every
    loudspeaker in the room."""
    from rangeslam.app.plotting import plot_rir_matrix

    out = args.out
    fs = loaded.fs
    latest = max((float(d.times[-1]) for d in res.detections if d.found), default=0.0)
    n = min(loaded.rirs.shape[1], max(int(1.25 * latest * fs) + 1, 64))
    verdict = "converged" if res.converged else "not converged"
    what = "microphones" if res.mode == "array" else "walk"
    if len(files) > 1:
        what = f"{files[0].n_rirs} microphones x {len(files)} loudspeakers"
    written = [
        plot_rir_matrix(
            out / "run_rir_matrix.png",
            loaded.rirs[:, :n],
            fs,
            title=f"{loaded.n_rirs} RIRs ({what}), detected echoes overlaid: {verdict}",
            xlabel=("microphone" if len(files) < 2 else "microphone, loudspeaker by loudspeaker")
            if res.mode == "array"
            else "step",
            detections=res.detections,
            used=_used_peaks(res),
            used_label="echoes labelled" if res.mode == "array" else "echoes in tracks",
            true_times=true_arrival_times(loaded, res, files=files),
            keyframes=loaded.keyframes,
            groups=[(f"loudspeaker {j}", f.n_rirs) for j, f in enumerate(files)] or None,
        )
    ]
    if res.mode == "array":
        written.append(_room_plot(out, loaded, res, verdict, files=files))
    elif res.trajectory is not None:
        written.append(_walk_plot(out, loaded, res, verdict))
    return written


def _used_peaks(res) -> np.ndarray | None:
    """(M, K) index of each used echo in its RIR's detection (-1: none): the labelled peaks
    (array mode; several loudspeakers: each one's, stacked) or the tracks' detections (walk
    mode); None when the pipeline has neither."""
    lab = getattr(res.result, "labelling", None)
    if lab is not None:
        return np.asarray(lab.peaks)
    labs = getattr(res.result, "labellings", None)
    if labs:  # several loudspeakers: each one's labelled peaks at its own RIRs
        peaks = [np.asarray(one.peaks, dtype=int) for one in labs]
        width = max(p.shape[1] for p in peaks)
        return np.vstack([np.pad(p, ((0, 0), (0, width - p.shape[1])), constant_values=-1)
                          for p in peaks])  # fmt: skip
    tracks = getattr(res.result, "tracks", None)
    return None if tracks is None else np.asarray(tracks.detection)


def true_arrival_times(loaded, res, *, files=()) -> np.ndarray | None:
    """(M, J) true arrival times [s] at each RIR, at the file's speed of sound (else the run's):
    the direct path and the first-order image sources of the true room (array mode; with
    several loudspeakers' ``files``, each one's at its own RIRs, NaN rows for a file without
    its loudspeaker), or the true landmarks from the true trajectory (walk mode; rows without a
    true position NaN). None when the file lacks the truth."""
    c = float(loaded.c) if loaded.c is not None else float(res.c)
    m = loaded.n_rirs
    if res.mode == "array":
        if len(files) > 1:
            blocks = [_direct_and_images(f, res, c, true_room_of(loaded)) for f in files]
            if all(b is None for b in blocks):
                return None
            width = max(b.shape[1] for b in blocks if b is not None)
            return np.vstack(
                [np.full((f.n_rirs, width), np.nan) if b is None else b
                 for b, f in zip(blocks, files, strict=True)]
            )  # fmt: skip
        return _direct_and_images(loaded, res, c, true_room_of(loaded))
    if loaded.trajectory is None or loaded.landmarks is None:
        return None
    traj = np.asarray(loaded.trajectory, dtype=float)
    marks = np.asarray(loaded.landmarks, dtype=float)
    if len(traj) == m:
        rows = np.arange(m)
    elif loaded.keyframes is not None:
        rows = np.asarray(loaded.keyframes, dtype=int)
    else:
        return None
    if len(rows) != len(traj) or traj.shape[1] != marks.shape[1]:
        return None
    times = np.full((m, len(marks)), np.nan)
    times[rows] = np.linalg.norm(traj[:, None, :] - marks[None], axis=2) / c
    return times


def _direct_and_images(loaded, res, c: float, room) -> np.ndarray | None:
    """(M, 7) true arrival times [s] of the direct path and the first-order image sources of
    ``loaded``'s loudspeaker in the true ``room`` at the run's microphones; None without them."""
    from rangeslam.errors import RangeSlamError

    if room is None or loaded.source is None or res.mics is None:
        return None
    src = np.asarray(loaded.source, dtype=float)
    try:
        points = np.vstack([src, room.image_sources(src, order=1).positions])
    except RangeSlamError:  # a true source outside the true room: no truth to draw
        return None
    mics = np.asarray(res.mics, dtype=float)
    return np.linalg.norm(mics[:, None, :] - points[None], axis=2) / c


def true_room_of(loaded):
    """The true room a loaded file describes (:class:`~rangeslam.geometry.room.Room`): from its
    wall normals and offsets, else its shoebox size; None when it has neither (or they do not
    bound a room)."""
    from rangeslam.errors import RangeSlamError
    from rangeslam.geometry.room import Room

    try:
        if loaded.wall_normals is not None and loaded.wall_offsets is not None:
            return Room(loaded.wall_normals, loaded.wall_offsets)
        if loaded.room_size is not None:
            return Room.shoebox(loaded.room_size)
    except (RangeSlamError, ValueError):
        return None
    return None


def _room_plot(out: Path, loaded, res, verdict: str, *, files=()) -> Path:
    """run_room.png: the estimated room against the true one when the file has it; every
    loudspeaker (and its image sources) of a several-loudspeaker run, numbered."""
    from rangeslam.app.plotting import plot_room_estimate

    rec = res.result.reconstruction
    normals, offsets, images = res.wall_normals, res.wall_offsets, res.image_sources
    source, true_source = res.source, loaded.source
    lab = getattr(res.result, "labelling", None)
    if normals is None and res.source is not None and lab is not None:  # the walls it found
        normals, offsets, images = labelled_walls(res.source, lab.images)
    title = f"room from {loaded.n_rirs} RIRs: {verdict}"
    if len(files) > 1:
        speakers = loudspeakers_of(res, files, ())
        source = np.array([np.full(3, np.nan) if s.estimate is None else s.estimate
                           for s in speakers])  # fmt: skip
        true_source = np.array([np.full(3, np.nan) if s.truth is None else s.truth
                                for s in speakers])  # fmt: skip
        if rec is not None:
            images = np.asarray(rec.image_sources, dtype=float).reshape(-1, 3)
        title = f"room from {loaded.n_rirs} RIRs ({len(files)} loudspeakers): {verdict}"
    return plot_room_estimate(
        out / "run_room.png",
        wall_normals=normals,
        wall_offsets=offsets,
        mics=res.mics,
        source=source,
        image_sources=images,
        room=None if rec is None else rec.room,
        true_room=true_room_of(loaded),
        true_source=true_source,
        title=title,
        converged=bool(res.converged),
    )


def labelled_walls(source, images) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray]:
    """The walls of the first-order image sources (K, 3) found (finite rows): each the bisector
    plane of ``source`` and its image, as (K, 3) outward unit normals and (K,) offsets (None,
    None when there is none), and the images used."""
    src = np.asarray(source, dtype=float)
    imgs = np.asarray(images, dtype=float).reshape(-1, src.shape[0])
    imgs = imgs[np.all(np.isfinite(imgs), axis=1) & (np.linalg.norm(imgs - src, axis=1) > 0)]
    if not len(imgs):
        return None, None, imgs
    normals = (imgs - src) / np.linalg.norm(imgs - src, axis=1, keepdims=True)
    return normals, np.einsum("kd,kd->k", normals, (imgs + src) / 2), imgs


def _walk_plot(out: Path, loaded, res, verdict: str) -> Path:
    """run_trajectory.png: the estimated walk, aligned onto the true one when the file has it
    (at every RIR: taken at the keyframes), with the true landmarks and room."""
    from rangeslam.app.plotting import plot_walk_estimate
    from rangeslam.geometry.alignment import align

    s = res.result.slam
    rot = shift = None
    truth = loaded.trajectory
    if truth is not None and loaded.keyframes is not None and len(truth) == loaded.n_rirs:
        truth = truth[np.asarray(loaded.keyframes)]
    finite = np.all(np.isfinite(res.trajectory))
    if truth is not None and truth.shape == res.trajectory.shape and finite:
        a = align(res.trajectory, truth, reflection=True)
        rot, shift = a.rotation, a.translation
        true_marks, room = loaded.landmarks, true_room_of(loaded)
    else:  # no truth in the estimate's frame: the true landmarks and room cannot be placed
        truth = true_marks = room = None
    return plot_walk_estimate(
        out / "run_trajectory.png",
        receivers=res.trajectory,
        sources=res.landmarks,
        receiver_cov=getattr(s, "receiver_cov", None),
        source_cov=getattr(s, "source_cov", None),
        true_trajectory=truth,
        rotation=rot,
        translation=shift,
        title=f"walk from {loaded.n_rirs} RIRs: {verdict}",
        true_landmarks=true_marks,
        true_room=room,
        converged=bool(res.converged),
    )
