"""The room from several loudspeakers heard by one known microphone array, walls estimated jointly.

:func:`room_from_loudspeakers` runs detection and :func:`~rangeslam.acoustics.labelling.label_echoes`
on the RIRs of each loudspeaker (J sets of M RIRs, the same microphones), turns each labelled image
source into the wall it implies (the bisector of the loudspeaker and its image, section 2 of the
paper read backwards), matches the walls of different loudspeakers (normals within
``WALL_MATCH_DEGREES``, offsets within ``WALL_MATCH_METRES``), and passes the J range matrices, one
column per matched wall, to :func:`~rangeslam.localization.room_reconstruction.reconstruct_room`,
which fits every loudspeaker and wall jointly (a wall one loudspeaker missed is fitted from the
others' echoes; a wrong pick of one is outvoted). Then the echoes no labelling took are searched
for walls that the loudspeakers hear jointly, each at too few microphones to label it alone
(:func:`~rangeslam.acoustics.shared_walls.shared_walls`: a small wall, such as a cut corner,
reflects a loudspeaker to the few microphones whose specular point falls on it); those found
are added and the room refitted, and an echo set that fits a wall the others do not confirm is
named in the message as left unexplained, and the run is then not converged (OUTLIERS: a wall
they show may be missing). Before that, a wall one loudspeaker alone labelled is
checked against the echoes its image predicts for every loudspeaker (microphones whose specular
point is on its face); one whose predicted echoes are absent (``WALL_CONTRADICTED_MISSING``) is
left out, said so, and its peaks searched again; when its image is then no higher-order image of
the walls found, its echoes stay unexplained and the run is not converged (OUTLIERS).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_points, as_rng, check_options_for, check_positive
from rangeslam.acoustics.echoes import EchoDetection, detect_echoes
from rangeslam.acoustics.labelling import EchoLabelling, detect_with_template, label_echoes
from rangeslam.acoustics.shared_walls import (
    WALL_MATCH_DEGREES,
    WALL_MATCH_METRES,
    SharedWall,
    bisector_planes,
    denied,
    is_higher_order_image,
    predicted_echoes,
    predicted_present,
    shared_walls,
)
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


@dataclass(frozen=True, eq=False)
class RoomFromLoudspeakers(HasStatus):
    """Result of :func:`room_from_loudspeakers`. J loudspeakers, M microphones, K walls matched.

    Attributes:
        detections: the J * M echo detections, loudspeaker by loudspeaker.
        labellings: the J :class:`~rangeslam.acoustics.labelling.EchoLabelling`.
        columns: (J, K) int: the labelling column (1..) of matched wall k for loudspeaker j, 0
            where loudspeaker j did not label that wall.
        shared: the walls found jointly from echoes no labelling took
            (:func:`~rangeslam.acoustics.shared_walls.shared_walls`: a small wall that each
            loudspeaker hears at too few microphones to label it alone); the reconstruction's
            walls are the K matched ones, then these.
        reconstruction: the joint
            :class:`~rangeslam.localization.room_reconstruction.RoomReconstruction`, or None when
            no loudspeaker was located with an echo.
        status: CONVERGED when the joint reconstruction converged and its walls bound a room; else
            the reconstruction's status, OUT_OF_RANGE (walls not bounding a room), OUTLIERS (a
            wall left out as contradicted whose image is no higher-order image of the walls
            found, or an echo set that fits a wall the echoes do not deny but too few confirm:
            echoes stay unexplained; the walls found are kept), or NOT_IDENTIFIABLE (nothing to
            reconstruct).
        message: what happened, each labelling's message included, and the echoes left
            unexplained (an echo set that fits a wall the others do not confirm).
    """

    detections: tuple[EchoDetection, ...]
    labellings: tuple[EchoLabelling, ...]
    columns: np.ndarray
    shared: tuple[SharedWall, ...]
    reconstruction: RoomReconstruction | None
    status: Status
    message: str

    @property
    def located(self) -> np.ndarray:
        """(J,) bool: the loudspeakers in the joint fit (located, with an echo labelled); the
        reconstruction's sources and image sources are theirs, in order."""
        return np.array([lab.has_room for lab in self.labellings], dtype=bool)


def _walls_of(lab: EchoLabelling) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3) outward normals and (K,) offsets of the bisectors of ``lab``'s source and images."""
    return bisector_planes(lab.images, lab.source)


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


def _joint_ranges(labs: Sequence[EchoLabelling], columns: np.ndarray, shared=()):
    """J (M, 1+K+S) range matrices and masks in the matched column order, then the S ``shared``
    walls' echoes (masked: NaN, False)."""
    ranges, masks = [], []
    for j, (lab, cols) in enumerate(zip(labs, columns, strict=True)):
        m = lab.ranges.shape[0]
        r = np.full((m, 1 + len(cols)), np.nan)
        mk = np.zeros((m, 1 + len(cols)), dtype=bool)
        for k, c in enumerate([0, *cols]):
            if k == 0 or c > 0:
                r[:, k], mk[:, k] = lab.ranges[:, c], lab.mask[:, c]
        extra = [(w.ranges[j], w.peaks[j] >= 0) for w in shared]
        if extra:
            r = np.column_stack([r, *(e[0] for e in extra)])
            mk = np.column_stack([mk, *(e[1] for e in extra)])
        ranges.append(np.where(mk, r, np.nan))
        masks.append(mk)
    return ranges, masks


def _drop_lone_wall(pts, labs, cols: np.ndarray, rec, ropts: dict, rng):
    """Walls that do not bound a room: refit without each wall that only one loudspeaker
    labelled (a higher-order image taken for a first-order one, or a chance alignment); the
    first refit that converged and bounds a room is kept. Returns (columns, reconstruction, a
    note naming the wall left out or ""). With d + 1 walls or fewer nothing is left out: the
    rest could not bound a room in d-D (and none would be no room problem at all)."""
    if cols.shape[1] <= pts.shape[1] + 1:
        return cols, rec, ""
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


def _echo_checks(pts, labs, dets, cols: np.ndarray, rec, c: float) -> np.ndarray:
    """(K, 2) int: for each wall that one loudspeaker labelled, the echoes of it that the
    loudspeakers' first-order images in it predict (tests) and the ones their detections hold
    (found); 0, 0 for the other walls. Loudspeaker i tests the wall at microphone m when the
    specular point of its image there lies on the wall's face (the room's other walls hold it,
    within i's labelling tolerance), i's labelling heard an echo of another wall at m and (the
    loudspeaker that labelled the wall) none of this one, and the predicted range is within the
    span of m's detected peaks; the echo is found when a peak is within that tolerance of the
    predicted range."""
    out = np.zeros((rec.wall_normals.shape[0], 2), dtype=int)
    ranges = [[np.asarray(det.times, dtype=float) * c for det in ds] for ds in dets]
    for k in range(cols.shape[1]):
        if (cols[:, k] > 0).sum() != 1:
            continue
        n, o = rec.wall_normals[k], rec.wall_offsets[k]
        for i, lab in enumerate(labs):
            heard = lab.mask[:, 1:].any(axis=1)
            if cols[i, k]:
                heard = heard & ~lab.mask[:, cols[i, k]]
            on_face, pred = predicted_echoes(rec.room, pts, rec.sources[i], n, o, lab.tolerance)
            out[k] += predicted_present(ranges[i], pred, on_face & heard, lab.tolerance)
    return out


def _drop_contradicted(pts, labs, dets, cols: np.ndarray, rec, ropts: dict, c: float, rng):
    """Walls that one loudspeaker labelled and the echoes contradict: at least
    ``WALL_CONTRADICTED_MISSING`` of the echoes they predict (:func:`_echo_checks`) absent, and
    fewer present than absent. They are left out and the rest refitted (a wall the data deny is
    no part of the answer; when the rest do not bound a room the refit says so). Returns
    (columns, reconstruction, the (J, ) lists of labelling columns left out, a note or "")."""
    freed: list[list[int]] = [[] for _ in labs]
    if len(labs) < 2 or not rec.converged or rec.room is None:
        return cols, rec, freed, ""
    checks = _echo_checks(pts, labs, dets, cols, rec, c)[: cols.shape[1]]
    missing = checks[:, 0] - checks[:, 1]
    bad = np.flatnonzero(denied(checks[:, 0], checks[:, 1]))
    if not len(bad) or len(bad) == cols.shape[1]:
        return cols, rec, freed, ""
    said = []
    for k in bad:
        j = int(np.flatnonzero(cols[:, k])[0])
        freed[j].append(int(cols[j, k]))
        said.append(
            f"wall {k} (normal {np.round(rec.wall_normals[k], 2).tolist()}, labelled by "
            f"loudspeaker {j} only): the other loudspeakers' echoes of it are absent at "
            f"{missing[k]} of the {checks[k, 0]} microphones where they are predicted"
        )
    keep = np.delete(cols, bad, axis=1)
    ranges, masks = _joint_ranges(labs, keep)
    trial = reconstruct_room(pts, ranges, mask=masks, rng=rng, **ropts)
    return keep, trial, freed, f"left out {'; '.join(said)}; "


def _unexplained_left_out(labs, freed, rec) -> str:
    """A note when a wall left out as contradicted is no image of order 2 or 3 of the walls
    fitted at the end (its echoes then stay unexplained: the run is not converged), else ""."""
    if rec.room is None:
        return ""
    bad = [
        f"loudspeaker {j}'s image {np.round(lab.images[col - 1], 3).tolist()}"
        for j, (lab, cols) in enumerate(zip(labs, freed, strict=True))
        for col in cols
        if not is_higher_order_image(rec.room, rec.sources[j], lab.images[col - 1], lab.tolerance)
    ]
    if not bad:
        return ""
    return (
        f"; the echoes of the wall(s) left out stay unexplained ({', '.join(bad)} is no image "
        "of order 2 or 3 of the walls found): a wall they show may be missing"
    )


def _add_shared_walls(pts, labs, dets, cols: np.ndarray, rec, ropts: dict, c: float, rng, freed):
    """When the labelled walls converged to a room and several loudspeakers were located: the
    walls their free echoes show jointly (:func:`shared_walls`), added and refitted with the
    others. Returns (the walls added, the reconstruction, a note for the message: the walls
    added, or the echoes left unexplained, or "", and True when echoes are left unexplained)."""
    if len(labs) < 2 or not rec.converged or rec.room is None:
        return (), rec, "", False
    found = shared_walls(
        labs, dets, pts, rec.room, c=c, min_cut=WALL_MATCH_METRES, rng=rng, freed=freed
    )
    note = "".join(f"{u}; " for u in found.unexplained)
    if not found.walls:
        return (), rec, note, bool(found.unexplained)
    ranges, masks = _joint_ranges(labs, cols, found.walls)
    try:
        trial = reconstruct_room(pts, ranges, mask=masks, rng=rng, **ropts)
    except InvalidInputError as exc:  # a wall it cannot start from: reported, not fitted
        trial = None
        why = str(exc)
    said = ", ".join(
        f"normal {np.round(w.normal, 2).tolist()} from {w.support.tolist()} echoes"
        for w in found.walls
    )
    if trial is not None and trial.converged and trial.room is not None:
        return (
            found.walls,
            trial,
            f"{note}added {len(found.walls)} wall(s) found jointly ({said}); ",
            bool(found.unexplained),
        )
    why = why if trial is None else trial.message
    return (
        (),
        rec,
        (
            f"{note}echoes left unexplained: a wall found jointly ({said}) did not fit with the "
            f"others ({why}); "
        ),
        True,
    )


def _rir_sets(rir_sets, m_n: int) -> list[np.ndarray]:
    """The J >= 1 RIR sets as (M, L) float arrays, each checked (messages name ``rir_sets[j]``)."""
    sets = [np.asarray(x, dtype=float) for x in rir_sets]
    if not sets:
        raise InvalidInputError("rir_sets must hold the RIRs of at least one loudspeaker; got none")
    for j, x in enumerate(sets):
        if x.ndim != 2 or x.shape[0] != m_n:
            raise InvalidInputError(
                f"rir_sets[{j}] must be ({m_n}, L), one RIR per microphone; got {x.shape}"
            )
    return sets


def room_from_loudspeakers(
    rir_sets: Sequence[ArrayLike],
    fs: float,
    mics: ArrayLike,
    *,
    c: float,
    rng: np.random.Generator | int | None = None,
    direct_template: tuple[float, float] | None = None,
    detect_options: dict[str, Any] | None = None,
    label_options: dict[str, Any] | None = None,
    reconstruct_options: dict[str, Any] | None = None,
) -> RoomFromLoudspeakers:
    """The room from J loudspeakers' RIRs at the same M known microphones, walls fitted jointly.

    Args:
        rir_sets: J >= 1 arrays (M, L_j), one per loudspeaker, t = 0 at its emission.
        fs: Hz. mics: (M, 3) metres. c: m/s. rng: Generator or seed, passed down.
        direct_template: (before, after) seconds: as
            :func:`~rangeslam.acoustics.labelling.room_from_rirs`, each loudspeaker's RIRs
            matched-filtered with its own strongest direct sound (measured RIRs).
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
    dets_j = [
        detect_with_template(x, fs, direct_template=direct_template, detect_options=opts)
        for x in _rir_sets(rir_sets, len(pts))
    ]
    labs = tuple(label_echoes(d, pts, c=c, rng=rng, **lopts) for d in dets_j)
    dets = tuple(d for ds in dets_j for d in ds)
    notes = "; ".join(f"loudspeaker {j}: {lab.message}" for j, lab in enumerate(labs))
    usable = [j for j, lab in enumerate(labs) if lab.has_room]
    if not usable:
        msg = f"no loudspeaker was located with an echo labelled; {notes}"
        empty = np.zeros((len(labs), 0), dtype=int)
        return RoomFromLoudspeakers(dets, labs, empty, (), None, Status.NOT_IDENTIFIABLE, msg)
    walls = [_walls_of(labs[j]) for j in usable]
    cols = match_walls([w[0] for w in walls], [w[1] for w in walls])
    ulabs, udets = [labs[j] for j in usable], [dets_j[j] for j in usable]
    ranges, masks = _joint_ranges(ulabs, cols)
    tol = max(labs[j].tolerance for j in usable)
    ropts = {"inlier_threshold": 2.0 * tol, **(reconstruct_options or {})}
    rec = reconstruct_room(pts, ranges, mask=masks, rng=rng, **ropts)
    dropped = ""
    if rec.room is None:
        cols, rec, dropped = _drop_lone_wall(pts, ulabs, cols, rec, ropts, rng)
    cols, rec, freed, denied = _drop_contradicted(pts, ulabs, udets, cols, rec, ropts, c, rng)
    columns = np.zeros((len(labs), cols.shape[1]), dtype=int)
    columns[usable] = cols
    shared, rec, added, unexplained = _add_shared_walls(
        pts, ulabs, udets, cols, rec, ropts, c, rng, freed
    )
    msg = (
        f"{len(usable)} of {len(labs)} loudspeakers, {cols.shape[1]} walls matched; {notes}; "
        f"{dropped}{denied}{added}reconstruction: {rec.message}"
    )
    left = _unexplained_left_out(ulabs, freed, rec)
    if unexplained and not left:
        left = "; echoes left unexplained (above): a wall they show may be missing"
    status, msg = _status(rec, cols.shape[1], left, msg)
    return RoomFromLoudspeakers(dets, labs, columns, shared, rec, status, msg)


def _status(rec, k_n: int, left: str, msg: str) -> tuple[Status, str]:
    """The verdict of :func:`room_from_loudspeakers` (its ``status``) and the message."""
    if not rec.converged:
        return Status(rec.status), msg
    if rec.room is None:
        return Status.OUT_OF_RANGE, f"{msg}; the {k_n} walls found do not bound a room"
    if left:
        return Status.OUTLIERS, msg + left
    return Status.CONVERGED, msg
