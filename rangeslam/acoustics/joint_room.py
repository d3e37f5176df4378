"""The room from several loudspeakers heard by one known microphone array, walls estimated jointly.

:func:`room_from_loudspeakers` runs detection and :func:`~rangeslam.acoustics.labelling.label_echoes`
on the RIRs of each loudspeaker (J sets of M RIRs, the same microphones), turns each labelled image
source into the wall it implies (the bisector of the loudspeaker and its image, section 2 of the
paper read backwards), matches the walls of different loudspeakers (normals within
``WALL_MATCH_DEGREES``, offsets within ``WALL_MATCH_METRES``), and passes the J range matrices, one
column per matched wall, to :func:`~rangeslam.localization.room_reconstruction.reconstruct_room`,
which fits every loudspeaker and wall jointly (a wall one loudspeaker missed is fitted from the
others' echoes; a wrong pick of one is outvoted).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_points, as_rng, check_options_for, check_positive
from rangeslam.acoustics.echoes import EchoDetection, detect_echoes, detect_echoes_many
from rangeslam.acoustics.labelling import EchoLabelling, label_echoes
from rangeslam.errors import InvalidInputError
from rangeslam.localization.room_reconstruction import RoomReconstruction, reconstruct_room
from rangeslam.status import HasStatus, Status

__all__ = [
    "WALL_MATCH_DEGREES",
    "WALL_MATCH_METRES",
    "RoomFromLoudspeakers",
    "match_walls",
    "room_from_loudspeakers",
]

#: Two loudspeakers' walls are one wall when their outward normals are within this many degrees
#: and their offsets within WALL_MATCH_METRES. A labelled wall is within a degree and a centimetre
#: on simulated RIRs (tests/test_run_sessions.py); distinct walls of a room differ by far more.
WALL_MATCH_DEGREES = 10.0
WALL_MATCH_METRES = 0.15


@dataclass(frozen=True, eq=False)
class RoomFromLoudspeakers(HasStatus):
    """Result of :func:`room_from_loudspeakers`. J loudspeakers, M microphones, K walls matched.

    Attributes:
        detections: the J * M echo detections, loudspeaker by loudspeaker.
        labellings: the J :class:`~rangeslam.acoustics.labelling.EchoLabelling`.
        columns: (J, K) int: the labelling column (1..) of matched wall k for loudspeaker j, 0
            where loudspeaker j did not label that wall.
        reconstruction: the joint
            :class:`~rangeslam.localization.room_reconstruction.RoomReconstruction`, or None when
            no loudspeaker was located with an echo.
        status: CONVERGED when the joint reconstruction converged and its walls bound a room; else
            the reconstruction's status, OUT_OF_RANGE (walls not bounding a room), or
            NOT_IDENTIFIABLE (nothing to reconstruct).
        message: what happened, each labelling's message included.
    """

    detections: tuple[EchoDetection, ...]
    labellings: tuple[EchoLabelling, ...]
    columns: np.ndarray
    reconstruction: RoomReconstruction | None
    status: Status
    message: str


def _walls_of(lab: EchoLabelling) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3) outward normals and (K,) offsets of the bisectors of ``lab``'s source and images."""
    d = lab.images - lab.source
    n = d / np.linalg.norm(d, axis=1, keepdims=True)
    return n, np.einsum("kd,kd->k", n, (lab.images + lab.source) / 2)


def match_walls(
    normals: Sequence[ArrayLike],
    offsets: Sequence[ArrayLike],
    *,
    degrees: float = WALL_MATCH_DEGREES,
    metres: float = WALL_MATCH_METRES,
) -> np.ndarray:
    """(J, K) int: for each of J wall lists (normals (K_j, 3), offsets (K_j,)), the index + 1 of
    its wall matched to each of K distinct walls, 0 where it has none. Greedy, in order: a wall
    joins the first cluster whose first wall is within ``degrees`` and ``metres`` and that has no
    wall of its list yet; else it starts a cluster."""
    cos = np.cos(np.radians(degrees))
    reps: list[tuple[np.ndarray, float]] = []
    rows: list[dict[int, int]] = []
    for n_j, o_j in zip(normals, offsets, strict=True):
        row: dict[int, int] = {}
        for i, (n, o) in enumerate(zip(np.asarray(n_j), np.asarray(o_j), strict=True)):
            hit = next(
                (
                    k
                    for k, (rn, ro) in enumerate(reps)
                    if k not in row and rn @ n >= cos and abs(ro - o) <= metres
                ),
                None,
            )
            if hit is None:
                reps.append((n, float(o)))
                hit = len(reps) - 1
            row[hit] = i + 1
        rows.append(row)
    out = np.zeros((len(rows), len(reps)), dtype=int)
    for j, row in enumerate(rows):
        for k, col in row.items():
            out[j, k] = col
    return out


def _joint_ranges(labs: Sequence[EchoLabelling], columns: np.ndarray):
    """J (M, 1+K) range matrices and masks in the matched column order (masked: NaN, False)."""
    ranges, masks = [], []
    for lab, cols in zip(labs, columns, strict=True):
        m = lab.ranges.shape[0]
        r = np.full((m, 1 + len(cols)), np.nan)
        mk = np.zeros((m, 1 + len(cols)), dtype=bool)
        for k, c in enumerate([0, *cols]):
            if k == 0 or c > 0:
                r[:, k], mk[:, k] = lab.ranges[:, c], lab.mask[:, c]
        ranges.append(np.where(mk, r, np.nan))
        masks.append(mk)
    return ranges, masks


def _drop_lone_wall(pts, labs, cols: np.ndarray, rec, ropts: dict, rng):
    """Walls that do not bound a room: refit without each wall that only one loudspeaker
    labelled (a higher-order image taken for a first-order one, or a chance alignment); the first refit that converged and bounds a room is kept. Returns
    (columns, reconstruction, a note naming the wall left out or "")."""
    lone = [k for k in range(cols.shape[1]) if (cols[:, k] > 0).sum() == 1]
    for k in lone:
        keep = np.delete(cols, k, axis=1)
        ranges, masks = _joint_ranges(labs, keep)
        trial = reconstruct_room(pts, ranges, mask=masks, rng=rng, **ropts)
        if trial.converged and trial.room is not None:
            n = np.round(rec.wall_normals[k], 2).tolist()
            note = (
                f"left out wall {k} (normal {n}, labelled by one loudspeaker only): with it the "
                "walls do not bound a room; "
            )
            return keep, trial, note
    return cols, rec, ""


def room_from_loudspeakers(
    rir_sets: Sequence[ArrayLike],
    fs: float,
    mics: ArrayLike,
    *,
    c: float,
    rng: np.random.Generator | int | None = None,
    detect_options: dict[str, Any] | None = None,
    label_options: dict[str, Any] | None = None,
    reconstruct_options: dict[str, Any] | None = None,
) -> RoomFromLoudspeakers:
    """The room from J loudspeakers' RIRs at the same M known microphones, walls fitted jointly.

    Args:
        rir_sets: J >= 1 arrays (M, L_j), one per loudspeaker, t = 0 at its emission.
        fs: Hz. mics: (M, 3) metres. c: m/s. rng: Generator or seed, passed down.
        detect_options: keywords of :func:`~rangeslam.acoustics.echoes.detect_echoes_many`.
        label_options: keywords of :func:`~rangeslam.acoustics.labelling.label_echoes`; default
            ``n_images=None`` (each loudspeaker labels the walls it confirms; the match joins them).
        reconstruct_options: keywords of ``reconstruct_room`` (default ``inlier_threshold`` twice
            the largest labelling tolerance).

    Returns:
        A :class:`RoomFromLoudspeakers`.

    Raises:
        InvalidInputError: no RIR sets, a set not (M, L) for the M microphones, bad options.
    """
    rng = as_rng(rng)
    c = check_positive(c, "c")
    pts = as_points(mics, "mics", dim=3)
    opts = check_options_for(detect_options, "detect_options", detect_echoes, passed=("rir", "fs"))
    lopts = {"n_images": None}
    lopts.update(
        check_options_for(
            label_options, "label_options", label_echoes, passed=("detections", "mics", "c", "rng")
        )
    )
    sets = [np.asarray(x, dtype=float) for x in rir_sets]
    if not sets:
        raise InvalidInputError("rir_sets must hold the RIRs of at least one loudspeaker; got none")
    for j, x in enumerate(sets):
        if x.ndim != 2 or x.shape[0] != len(pts):
            raise InvalidInputError(
                f"rir_sets[{j}] must be ({len(pts)}, L), one RIR per microphone; got {x.shape}"
            )
    dets_j = [tuple(detect_echoes_many(x, fs, **opts)) for x in sets]
    labs = tuple(label_echoes(d, pts, c=c, rng=rng, **lopts) for d in dets_j)
    dets = tuple(d for ds in dets_j for d in ds)
    notes = "; ".join(f"loudspeaker {j}: {lab.message}" for j, lab in enumerate(labs))
    usable = [j for j, lab in enumerate(labs) if np.all(np.isfinite(lab.source)) and lab.n_images]
    if not usable:
        msg = f"no loudspeaker was located with an echo labelled; {notes}"
        empty = np.zeros((len(labs), 0), dtype=int)
        return RoomFromLoudspeakers(dets, labs, empty, None, Status.NOT_IDENTIFIABLE, msg)
    walls = [_walls_of(labs[j]) for j in usable]
    cols = match_walls([w[0] for w in walls], [w[1] for w in walls])
    columns = np.zeros((len(labs), cols.shape[1]), dtype=int)
    columns[usable] = cols
    ranges, masks = _joint_ranges([labs[j] for j in usable], cols)
    tol = max(labs[j].tolerance for j in usable)
    ropts = {"inlier_threshold": 2.0 * tol, **(reconstruct_options or {})}
    rec = reconstruct_room(pts, ranges, mask=masks, rng=rng, **ropts)
    dropped = ""
    if rec.room is None:
        cols, rec, dropped = _drop_lone_wall(pts, [labs[j] for j in usable], cols, rec, ropts, rng)
        columns = np.zeros((len(labs), cols.shape[1]), dtype=int)
        columns[usable] = cols
    msg = (
        f"{len(usable)} of {len(labs)} loudspeakers, {cols.shape[1]} walls matched; {notes}; "
        f"{dropped}reconstruction: {rec.message}"
    )
    if not rec.converged:
        status = Status(rec.status)
    elif rec.room is None:
        status = Status.OUT_OF_RANGE
        msg += f"; the {cols.shape[1]} walls found do not bound a room"
    else:
        status = Status.CONVERGED
    return RoomFromLoudspeakers(dets, labs, columns, rec, status, msg)
