"""Plots with matplotlib (imported lazily by the CLI; the math modules never import this). The
benchmark figures (Fig. 3, Fig. 5) live in :mod:`rangeslam.app.bench_plot`, the Plaza figure in
:mod:`rangeslam.app.plaza_plot`; their plot functions are importable from here too."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Rectangle
from scipy.spatial import ConvexHull

from rangeslam.app.bench_plot import plot_fig3, plot_fig5, rms_and_bound
from rangeslam.app.plaza_plot import plot_plaza
from rangeslam.app.plot_style import clip_to_box, legend_below, save_figure, verdict_title
from rangeslam.geometry.room import Room

__all__ = [
    "MARKED_POSITIONS",
    "NO_SIGNAL_GREY",
    "ellipse_magnification",
    "no_signal",
    "plot_fig3",
    "plot_fig5",
    "plot_plaza",
    "plot_rir_matrix",
    "plot_room_estimate",
    "plot_room_reconstruction",
    "plot_slam_estimate",
    "plot_walk_estimate",
    "rms_and_bound",
]

_TOP = ("top view", (0, 1), ("x [m]", "y [m]"))
_SIDES = (("side view", (0, 2), ("x [m]", "z [m]")), ("side view", (1, 2), ("y [m]", "z [m]")))
_VIEWS = (_TOP, _SIDES[0])


def room_views(rooms: list[Room | None], *, normals: np.ndarray | None = None) -> tuple:
    """The views of a 3-D figure: the top view and the side view in which the most tilted wall
    (normal farthest from the coordinate axes, e.g. a sloping ceiling) is seen edge-on: x-z when
    that normal leans along x, y-z when it leans along y. The walls are those of ``rooms`` and
    the extra unit ``normals`` (W, 3). 2-D rooms: the top view alone."""
    rooms = [r for r in rooms if r is not None]
    if rooms and rooms[0].dim == 2:
        return (_TOP,)
    sets = [r.normals for r in rooms] + ([normals] if normals is not None else [])
    normals = np.vstack(sets) if sets else np.zeros((0, 3))
    normals = normals[np.all(np.isfinite(normals), axis=1)]
    if not len(normals):
        return _VIEWS
    tilt = np.minimum(np.abs(normals[:, 2]), np.linalg.norm(normals[:, :2], axis=1))
    if tilt.max() < 0.05:
        return _VIEWS
    n = normals[int(np.argmax(tilt))]
    return (_TOP, _SIDES[0] if abs(n[0]) >= abs(n[1]) else _SIDES[1])


def _outline(ax, room: Room, axes: tuple[int, int], **style) -> None:
    """The room's outline projected on two coordinate ``axes`` (the convex hull of its corners)."""
    pts = room.vertices[:, list(axes)]
    hull = ConvexHull(pts)
    loop = np.append(hull.vertices, hull.vertices[0])
    ax.plot(pts[loop, 0], pts[loop, 1], **style)


def room_window(core: list, extra: list) -> tuple[np.ndarray, np.ndarray]:
    """Axis limits (lo, hi), each (d,), set by the room: the box around the ``core`` points (the
    rooms' corners, microphones, loudspeaker; arrays (N, d) or None), grown to take in the
    ``extra`` points (image sources) lying within one room extent of it, plus a 10% margin.
    Points farther out are not in the window (draw them clipped at its edge). With no finite
    core point, the window is [-1, 1] on every axis."""
    pts = np.vstack([np.reshape(p, (-1, np.shape(p)[-1])) for p in core if p is not None])
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:  # nothing finite to frame (a failed run without truth): a unit window
        return -np.ones(np.shape(pts)[1]), np.ones(np.shape(pts)[1])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    size = float(np.max(hi - lo))
    near = [np.reshape(p, (-1, len(lo))) for p in extra if p is not None and np.size(p)]
    if near:
        e = np.vstack(near)
        e = e[np.all(np.isfinite(e) & (e >= lo - size) & (e <= hi + size), axis=1)]
        if len(e):
            lo, hi = np.minimum(lo, e.min(axis=0)), np.maximum(hi, e.max(axis=0))
    pad = 0.1 * float(np.max(hi - lo)) + 0.1
    return lo - pad, hi + pad


def plot_room_reconstruction(
    path: str | Path,
    *,
    true_room: Room,
    estimated_room: Room | None,
    mics: np.ndarray,
    true_sources: np.ndarray,
    estimated_sources: np.ndarray,
    image_sources: np.ndarray | None = None,
    title: str = "",
    converged: bool | None = None,
) -> Path:
    """Write a figure of the true and reconstructed rooms (outlines), microphones and sources.

    3-D rooms are shown in a top view and the side view that shows the most tilted wall edge-on
    (:func:`room_views`), 2-D rooms once. The limits are set by the true room (plus the image
    sources near it); estimates beyond are drawn at the edge and counted in a note. ``converged``
    False puts 'not converged' in the title. Returns the path written.
    """
    d = true_room.dim
    views = room_views([true_room, estimated_room])
    lo, hi = room_window([true_room.vertices, mics, true_sources], [image_sources])
    fig, axs = plt.subplots(1, len(views), figsize=(6.0 * len(views), 5.6), squeeze=False)
    for ax, (name, axes, labels) in zip(axs[0], views, strict=True):
        _outline(ax, true_room, axes, color="0.3", lw=2.0, label="true room")
        if estimated_room is not None:
            _outline(
                ax, estimated_room, axes, color="tab:red", lw=1.2, ls="--", label="reconstructed"
            )
        pts = (mics, image_sources, true_sources, estimated_sources)
        _scatter_room_points(ax, axes, *pts, box=(lo, hi))
        _view_axes(ax, axes, labels, name, (lo, hi))
    if estimated_room is None:
        title = f"{title}: no room reconstructed" if title else "no room reconstructed"
    fig.suptitle(verdict_title(title, converged))
    _note_far(axs[0][0], (lo, hi), image_sources, estimated_sources, d=d)
    legend_below(fig, axs, ncol=4)
    return save_figure(fig, path, legend_space=True)


def _view_axes(ax, axes, labels, name: str, box) -> None:
    """Labels, title, limits from ``box`` ((d,) lo, (d,) hi), equal aspect, grid of one view."""
    lo, hi = box
    ax.set_xlim(lo[axes[0]], hi[axes[0]])
    ax.set_ylim(lo[axes[1]], hi[axes[1]])
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_title(name)
    ax.set_aspect("equal", adjustable="box")
    ax.grid(alpha=0.3)


def _note_far(ax, box, *point_sets, d: int) -> None:
    """A note above the title of ``ax`` (the first view, so the layout leaves room for it and it
    does not run into the figure's title) counting the points of ``point_sets`` (arrays (N, d)
    or None) outside ``box`` and the farthest one's distance from the box's centre."""
    lo, hi = box
    pts = [np.reshape(p, (-1, d)) for p in point_sets if p is not None and np.size(p)]
    if not pts:
        return
    pts = np.vstack(pts)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    _, outside = clip_to_box(pts, lo, hi)
    if outside.any():
        far = float(np.max(np.linalg.norm(pts[outside] - (lo + hi) / 2, axis=1)))
        ax.annotate(
            f"{int(outside.sum())} estimated point(s) beyond the plot, drawn at its edge "
            f"(farthest {far:.1f} m from the room's centre)",
            (0, 1),
            xycoords="axes fraction",
            xytext=(0, 24),
            textcoords="offset points",
            fontsize=8,
            va="bottom",
            color="tab:red",
            annotation_clip=False,
        )


def _scatter_room_points(
    ax, axes, mics, image_sources, true_sources, estimated_sources, *, box=None
) -> None:
    """Microphones, image sources and the loudspeaker (true and estimated) in one view; any of
    the last three may be None. Points as rows, one point as (d,). With ``box`` (lo, hi), the
    estimated points outside it are drawn on its edge as hollow triangles."""
    d = mics.shape[1]
    if image_sources is not None and len(image_sources):
        ims = image_sources.reshape(-1, d)
        ims = ims[np.all(np.isfinite(ims), axis=1)]
        _scatter_clipped(
            ax, ims, axes, box, marker="*", s=40, c="tab:orange", label="image sources (est.)"
        )
    ax.scatter(
        mics[:, axes[0]], mics[:, axes[1]], marker="o", s=18, c="tab:blue", label="microphones"
    )
    if true_sources is not None:
        pts = np.reshape(true_sources, (-1, d))
        style = {"marker": "s", "s": 60, "facecolors": "none", "edgecolors": "k"}
        ax.scatter(pts[:, axes[0]], pts[:, axes[1]], label="loudspeaker (true)", **style)
    if estimated_sources is not None:
        pts = np.reshape(estimated_sources, (-1, d))
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        style = {"marker": "x", "s": 50, "c": "tab:red"}
        _scatter_clipped(ax, pts, axes, box, label="loudspeaker (est.)", **style)


def _scatter_clipped(ax, pts, axes, box, *, label: str, **style) -> None:
    """Scatter ``pts`` (N, d) in the view ``axes``; those outside ``box`` go on its edge as
    hollow triangles labelled 'beyond the plot'."""
    if box is None:
        inside, out = pts, pts[:0]
    else:
        clipped, far = clip_to_box(pts, *box)
        inside, out = pts[~far], clipped[far]
    ax.scatter(inside[:, axes[0]], inside[:, axes[1]], label=label, **style)
    if len(out):
        colour = style.get("c", "tab:red")
        ax.scatter(
            out[:, axes[0]],
            out[:, axes[1]],
            marker="^",
            s=50,
            facecolors="none",
            edgecolors=colour,
            clip_on=False,
            label=f"{label}, beyond the plot",
        )


def _top_view_axes(ax) -> None:
    """Style a top view: x and y in metres, equal aspect, a light grid, a small legend."""
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)


def _ellipse(ax, centre, cov2, nsig: float = 2.0, **style) -> None:
    """The ``nsig``-sigma ellipse of the 2 x 2 covariance ``cov2`` (m^2) around ``centre``."""
    from matplotlib.patches import Ellipse

    w, v = np.linalg.eigh(cov2)
    w = np.clip(w, 0, None)
    angle = np.degrees(np.arctan2(v[1, 1], v[0, 1]))
    ax.add_patch(
        Ellipse(centre, 2 * nsig * np.sqrt(w[1]), 2 * nsig * np.sqrt(w[0]), angle=angle, **style)
    )


def plot_slam_estimate(
    path: str | Path,
    *,
    trajectory: np.ndarray,
    landmarks: np.ndarray,
    receivers: np.ndarray,
    sources: np.ndarray,
    receiver_cov: np.ndarray,
    source_cov: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    title: str = "",
) -> Path:
    """Top view of a SLAM answer mapped onto the truth by (rotation, translation), with the 2-sigma
    ellipses of its covariances (rotated alike): trajectory on the left, landmarks on the right."""
    rec = receivers @ rotation.T + translation
    src = sources @ rotation.T + translation
    rot_cov = lambda c: np.einsum("ij,njk,lk->nil", rotation, c, rotation)  # noqa: E731
    fig, axs = plt.subplots(1, 2, figsize=(12.0, 5.0))
    for ax, true, est, cov, name in (
        (axs[0], trajectory, rec, rot_cov(receiver_cov), "trajectory"),
        (axs[1], landmarks, src, rot_cov(source_cov), "landmarks"),
    ):
        style = "o-" if name == "trajectory" else "s"
        ax.plot(true[:, 0], true[:, 1], style, c="k", mfc="none", ms=5, label=f"{name} (true)")
        ax.plot(
            est[:, 0], est[:, 1], style.replace("s", "x"), c="tab:red", ms=5, label=f"{name} (est.)"
        )
        for p, c in zip(est, cov, strict=True):
            _ellipse(ax, p[:2], c[:2, :2], fc="tab:red", ec="tab:red", alpha=0.2)
        _top_view_axes(ax)
        ax.set_title(f"{name}, top view, 2-sigma ellipses (GTSAM)")
    if title:
        fig.suptitle(title)
    legend_below(fig, axs, ncol=4)
    return save_figure(fig, path, legend_space=True)


def plot_rir_matrix(
    path: str | Path,
    rirs: np.ndarray,
    fs: float,
    title: str = "",
    *,
    xlabel: str = "step",
    detections=None,
    used: np.ndarray | None = None,
    used_label: str = "echoes used",
    true_times: np.ndarray | None = None,
    keyframes: np.ndarray | None = None,
    dynamic_range_db: float = 50.0,
    groups: list[tuple[str, int]] | None = None,
) -> Path:
    """The "RIR matrix" of Fig. 4C: one RIR per column (``rirs`` (M, L), index 0..M-1 along x,
    named by ``xlabel``), time in ms along y, |rir| in dB relative to each RIR's own peak and
    clipped at -``dynamic_range_db`` as colour, one cell per sample (no interpolation).

    ``detections``: M echo detections (with ``found`` and ``times`` in seconds, e.g.
    :class:`rangeslam.acoustics.echoes.EchoDetection`) drawn over their columns: those ``used``
    ((M, K) index into each ``detections[m].times``, -1 for none: the labelling's ``peaks`` or
    the tracks' ``detection``) as large hollow circles named ``used_label``, the others as small
    white dots. ``true_times``: (M, J) the true arrival times [s] (direct path and image sources,
    NaN where none) as dashes, when the file has the truth. ``keyframes``:
    indices of the RIRs that are steps, marked at the top when there are more RIRs than steps
    (then the x axis is 'RIR (frame)'). ``groups``: (name, count) of consecutive blocks of
    columns (e.g. each loudspeaker's RIRs), separated by white lines and named at the top.
    Samples before a RIR's first non-zero sample or after its last (no signal: a simulated RIR
    ends after its last reflection) are grey, not the black of a quiet sample. Returns the path
    written.
    """
    rirs = np.asarray(rirs, dtype=float)
    m, length = rirs.shape
    peak = np.max(np.abs(rirs), axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        mag = 20 * np.log10(np.abs(rirs) / np.where(peak > 0, peak, 1.0))
    mag = np.clip(np.nan_to_num(mag, nan=-np.inf), -dynamic_range_db, 0.0)
    silent = no_signal(rirs)
    fig, ax = plt.subplots(figsize=(8.0, 6.0))
    t_end = length / fs * 1e3
    im = ax.imshow(
        np.ma.masked_array(mag, mask=silent).T,
        aspect="auto",
        origin="lower",
        interpolation="nearest",
        extent=(-0.5, m - 0.5, 0, t_end),
        vmin=-dynamic_range_db,
        vmax=0,
        cmap=matplotlib.colormaps["magma"].with_extremes(bad=NO_SIGNAL_GREY),
    )
    fig.colorbar(im, ax=ax, label="|RIR| relative to its peak [dB]")
    if silent.any():  # a zero-size patch: the legend's entry for the grey
        label = "no signal (before a RIR's first or after its last non-zero sample)"
        ax.add_patch(Rectangle((0, 0), 0, 0, fc=NO_SIGNAL_GREY, ec="0.5", lw=0.5, label=label))
    if groups:
        _mark_groups(ax, groups)
    if detections is not None:
        _overlay_detections(ax, detections, t_end, used=used, used_label=used_label)
    if true_times is not None:
        _overlay_truth(ax, true_times, t_end)
    frames = keyframes is not None and len(keyframes) < m
    if frames:
        ax.plot(
            np.asarray(keyframes),
            np.full(len(keyframes), 1.0),
            ls="none",
            marker="v",
            ms=7,
            color="tab:cyan",
            transform=ax.get_xaxis_transform(),
            clip_on=False,
            label="keyframe (SLAM step)",
        )
    ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
    ax.set_xlabel("RIR (frame)" if frames else f"{xlabel} (RIR index)")
    ax.set_ylabel("time [ms]")
    ax.set_title(title or "RIR at each step of the walk (Fig. 4C)", pad=12)
    legend_below(fig, [ax], ncol=2)
    return save_figure(fig, path, legend_space=True)


#: The colour of the samples of the RIR matrix with no signal (:func:`no_signal`).
NO_SIGNAL_GREY = "0.8"


def no_signal(rirs: np.ndarray) -> np.ndarray:
    """(M, L) True at the samples of ``rirs`` (M, L) before each one's first non-zero sample or
    after its last (all of an all-zero RIR): where there is no signal, as opposed to a quiet
    one."""
    nonzero = np.asarray(rirs) != 0
    before = np.cumsum(nonzero, axis=1) == 0
    after = np.cumsum(nonzero[:, ::-1], axis=1)[:, ::-1] == 0
    return before | after


def _mark_groups(ax, groups: list[tuple[str, int]]) -> None:
    """White lines between consecutive blocks of columns, each block named at the top."""
    start = 0
    edge = ax.get_xaxis_transform()  # x in data, y in axes fraction
    for k, (name, count) in enumerate(groups):
        if k:
            ax.axvline(start - 0.5, color="white", lw=1.5, zorder=6)
        ax.text(start - 0.5 + count / 2, 0.985, name, transform=edge, ha="center", va="top",
                fontsize=8, color="white", zorder=7,
                bbox={"boxstyle": "round,pad=0.2", "fc": "black", "ec": "none", "alpha": 0.6})  # fmt: skip
        start += count


def _overlay_detections(ax, detections, t_end: float, *, used=None, used_label: str) -> None:
    """Detected echo times (ms) over their RIR's column, those within the plotted time span
    (0..``t_end`` ms): the ``used`` ones (see :func:`plot_rir_matrix`) as large hollow lime
    circles, the other detections as small white dots."""
    picked = {}
    if used is not None:
        for i, row in enumerate(np.asarray(used, dtype=int)):
            picked[i] = {int(k) for k in row if k >= 0}
    pts = {True: ([], []), False: ([], [])}
    col = _column_points(ax, len(detections))
    for i, det in enumerate(detections):
        if det is None or not det.found:
            continue
        t = np.asarray(det.times, dtype=float) * 1e3
        for k, tk in enumerate(t):
            if 0 <= tk <= t_end:
                xs, ts = pts[k in picked.get(i, ())]
                xs.append(i)
                ts.append(tk)
    styles = {
        True: {"marker": "o", "ms": min(8.0, 0.8 * col), "mfc": "none", "mec": "lime", "mew": 1.4},
        False: {
            "marker": ".",
            "ms": min(7.0, 0.7 * col),
            "mfc": "white",
            "mec": "black",
            "mew": 0.5,
        },
    }
    for is_used in (True, False):
        xs, ts = pts[is_used]
        if xs:
            label = used_label if is_used else "other detections"
            if used is None:
                label = "detected echoes"
            ax.plot(xs, ts, ls="none", label=label, zorder=5 - is_used, **styles[is_used])


def _column_points(ax, m: int) -> float:
    """Width of one of ``m`` columns of ``ax`` in points (marker sizes are in points)."""
    return ax.get_window_extent().width * 72.0 / ax.figure.dpi / max(m, 1)


def _overlay_truth(ax, true_times, t_end: float) -> None:
    """True arrival times (M, J) [s] as cyan dashes over their RIR's column, within 0..``t_end``
    ms; NaN entries left out."""
    t = np.asarray(true_times, dtype=float) * 1e3
    cols = np.broadcast_to(np.arange(t.shape[0])[:, None], t.shape)
    keep = np.isfinite(t) & (t >= 0) & (t <= t_end)
    if keep.any():
        ax.plot(
            cols[keep],
            t[keep],
            ls="none",
            marker="_",
            ms=min(14.0, 1.2 * _column_points(ax, t.shape[0])),
            mew=1.2,
            color="cyan",
            zorder=3,  # under the detections, which are drawn over the truth they match
            label="true arrivals (direct path, image sources)",
        )


def _wall_trace(ax, normal, offset, axes, at, extent, **style) -> bool:
    """Draw the line where the plane normal . x = offset cuts the view plane through ``at`` (the
    third coordinate), within ``extent`` ((2, 2) lower and upper corner); False when the plane is
    within 30 degrees of the view plane (no useful trace)."""
    a, b = axes
    c = 3 - a - b
    n2 = np.array([normal[a], normal[b]])
    if np.linalg.norm(n2) < 0.5:
        return False
    rhs = offset - normal[c] * at[c]
    p0 = n2 * rhs / (n2 @ n2)
    u = np.array([-n2[1], n2[0]]) / np.linalg.norm(n2)
    span = 2 * np.linalg.norm(extent[1] - extent[0]) + np.linalg.norm(p0)
    seg = p0 + np.outer([-span, span], u)
    ax.plot(seg[:, 0], seg[:, 1], **style)
    return True


def plot_room_estimate(
    path: str | Path,
    *,
    wall_normals: np.ndarray | None,
    wall_offsets: np.ndarray | None,
    mics: np.ndarray,
    source: np.ndarray | None,
    image_sources: np.ndarray | None = None,
    room: Room | None = None,
    true_room: Room | None = None,
    true_source: np.ndarray | None = None,
    title: str = "",
    converged: bool | None = None,
) -> Path:
    """A room estimated from RIRs (``rangeslam run``), top and side views, with or without truth.

    The estimated room's outline when the walls bound one (``room``); otherwise each wall as the
    line where it cuts the view plane through the loudspeaker (walls nearly parallel to the view
    are left out of it), named as found in a run that did not converge (``converged`` False:
    e.g. the walls a failed labelling found). Microphones, loudspeaker, image sources; the true
    room and loudspeaker when given. The limits are set by the rooms, microphones and loudspeaker (plus the image
    sources within one room extent); farther estimates are drawn at the edge and counted in a
    note. ``converged`` False puts 'not converged' in the title. ``source`` (J, 3) and
    ``true_source`` (J, 3) are several loudspeakers (NaN rows: not located, or no truth): each
    is numbered, and the walls are cut through the first one located. Returns the path written.
    """
    located = None if source is None else np.reshape(source, (-1, mics.shape[1]))
    located = None if located is None else located[np.all(np.isfinite(located), axis=1)]
    centre = located[0] if located is not None and len(located) else mics.mean(axis=0)
    core = [mics, centre[None], true_source]
    core += [r.vertices for r in (true_room, room) if r is not None]
    feet = None
    if wall_normals is not None and wall_offsets is not None:  # foot of the loudspeaker on each
        feet = centre + (wall_offsets - wall_normals @ centre)[:, None] * wall_normals
    lo, hi = room_window(core, [image_sources, feet])
    views = room_views([true_room, room], normals=wall_normals)
    fig, axs = plt.subplots(1, len(views), figsize=(6.0 * len(views), 5.8), squeeze=False)
    for ax, (name, axes, labels) in zip(axs[0], views, strict=True):
        if true_room is not None:
            _outline(ax, true_room, axes, color="0.3", lw=2.0, label="true room")
        if room is not None:
            label = "reconstructed" + (" (run not converged)" if converged is False else "")
            _outline(ax, room, axes, color="tab:red", lw=1.2, ls="--", label=label)
        elif wall_normals is not None and wall_offsets is not None:
            found = converged is False
            _wall_traces(ax, wall_normals, wall_offsets, axes, centre, (lo, hi), found=found)
        _scatter_room_points(ax, axes, mics, image_sources, true_source, source, box=(lo, hi))
        if source is not None and np.ndim(source) == 2 and len(source) > 1:
            _number_loudspeakers(ax, axes, np.asarray(source, dtype=float), (lo, hi), true_source)
        _view_axes(ax, axes, labels, name, (lo, hi))
        if room is None:
            ax.set_title(name + " (walls cut through the loudspeaker)", fontsize=10)
    fig.suptitle(verdict_title(title or "room from RIRs", converged))
    _note_far(axs[0][0], (lo, hi), image_sources, source, d=mics.shape[1])
    legend_below(fig, axs, ncol=4)
    return save_figure(fig, path, legend_space=True)


def _number_loudspeakers(ax, axes, sources: np.ndarray, box, truths=None) -> None:
    """Each loudspeaker of ``sources`` (J, d; NaN rows not located) numbered by its row beside
    its marker (above it and below it in turn, so that neighbours do not overlap), within
    ``box``; one not located is named at its true position (``truths`` (J, d)) when known."""
    lo, hi = box
    truths = np.full_like(sources, np.nan) if truths is None else np.reshape(truths, sources.shape)
    for j, (p, t) in enumerate(zip(sources, truths, strict=True)):
        name, colour = f"loudspeaker {j}", "tab:red"
        if not np.all(np.isfinite(p)):
            p, name, colour = t, f"loudspeaker {j} (not located)", "k"
        if np.all(np.isfinite(p)) and np.all((p >= lo) & (p <= hi)):
            ax.annotate(
                name,
                (p[axes[0]], p[axes[1]]),
                xytext=(6, 6 if j % 2 == 0 else -14),
                textcoords="offset points",
                fontsize=8,
                color=colour,
            )


def _wall_traces(ax, normals, offsets, axes, centre, box, *, found: bool = False) -> None:
    """Each estimated wall as its trace in the view through ``centre`` (see _wall_trace),
    labelled as found in a run that did not converge when ``found``."""
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    lo, hi = box
    extent = np.array([lo[list(axes)], hi[list(axes)]])
    for k, (n, o) in enumerate(zip(normals, offsets, strict=True)):
        style = {"color": colours[k % len(colours)], "lw": 1.2, "ls": "--"}
        label = f"wall {k}" + (" (found; run not converged)" if found else "")
        _wall_trace(ax, n, o, axes, centre, extent, label=label, **style)


#: Above this many positions a trajectory is a line, without a marker at each position (600
#: markers smear into a thick band).
MARKED_POSITIONS = 60


def plot_walk_estimate(
    path: str | Path,
    *,
    receivers: np.ndarray,
    sources: np.ndarray,
    receiver_cov: np.ndarray | None = None,
    source_cov: np.ndarray | None = None,
    true_trajectory: np.ndarray | None = None,
    rotation: np.ndarray | None = None,
    translation: np.ndarray | None = None,
    title: str = "",
    true_landmarks: np.ndarray | None = None,
    true_room: Room | None = None,
    converged: bool | None = None,
    landmark_names: list[str] | None = None,
) -> Path:
    """Top view of a trajectory and its landmarks estimated from RIRs (``rangeslam run``), with
    2-sigma ellipses when covariances are given (magnified by a power of ten, said in the title
    and the legend, when the largest would span under 2% of its panel). With
    ``true_trajectory`` the estimate is mapped onto it by (``rotation``, ``translation``), e.g.
    from :func:`rangeslam.align`; otherwise it is drawn in its own frame. ``true_landmarks``
    (K, d) and ``true_room`` (in the frame of the true trajectory) are drawn when given;
    ``landmark_names`` (K,) are written beside the estimated landmarks (a beacon's id). Over
    :data:`MARKED_POSITIONS` positions a trajectory is a line without markers. The limits are
    set by the truth when there is one (estimates beyond are drawn at the edge). Returns the
    path written."""
    d = receivers.shape[1]
    rot = np.eye(d) if rotation is None else rotation
    shift = np.zeros(d) if translation is None else translation
    rec = receivers @ rot.T + shift
    src = sources @ rot.T + shift
    rot_cov = lambda c: None if c is None else np.einsum("ij,njk,lk->nil", rot, c, rot)  # noqa: E731
    corners = None if true_room is None else true_room.vertices
    truth = [true_trajectory, true_landmarks, corners]
    has_truth = any(t is not None for t in truth)
    land_window = room_window(truth if has_truth else [rec, src], [src] if has_truth else [])
    # the trajectory's panel is set by the room and the walk, not by far image sources
    walk_core = [true_trajectory, corners] if true_trajectory is not None else [rec, corners]
    walk_window = room_window(walk_core, [])
    fig, axs = plt.subplots(1, 2, figsize=(12.0, 6.0))
    for ax, est, cov, name, (lo, hi) in (
        (axs[0], rec, rot_cov(receiver_cov), "trajectory", walk_window),
        (axs[1], src, rot_cov(source_cov), "landmarks", land_window),
    ):
        if true_room is not None:
            _outline(ax, true_room, (0, 1), color="0.3", lw=1.5, label="true room")
        true_pts = true_trajectory if name == "trajectory" else true_landmarks
        if true_pts is not None:
            style = "s" if name == "landmarks" else _path_style(len(true_pts), "o")
            ax.plot(*true_pts[:, :2].T, style, c="k", mfc="none", ms=6, label=f"{name} (true)")
        box = (lo, hi) if has_truth else None
        _walk_estimate(ax, est, rec, name, box)
        if name == "landmarks" and landmark_names is not None:
            _name_points(ax, est, landmark_names, (lo, hi))
        ellipses = _walk_ellipses(ax, est, cov, name, float(np.max(hi - lo)))
        _view_axes(ax, (0, 1), ("x [m]", "y [m]"), name, (lo, hi))
        frame = "aligned onto the truth" if true_trajectory is not None else "SLAM frame"
        ax.set_title(f"{name}, top view ({frame}){ellipses}", fontsize=11)
    fig.suptitle(verdict_title(title or "walk from RIRs", converged))
    _note_far(axs[0], land_window, rec, src, d=d)
    legend_below(fig, axs, ncol=4)
    return save_figure(fig, path, legend_space=True)


def _path_style(n: int, marker: str) -> str:
    """A path of ``n`` positions: line and ``marker`` at each, a line alone beyond
    :data:`MARKED_POSITIONS`."""
    return f"{marker}-" if n <= MARKED_POSITIONS else "-"


def _walk_estimate(ax, est, rec, name: str, box) -> None:
    """The estimated trajectory (line with markers up to :data:`MARKED_POSITIONS` positions,
    first step circled) or landmarks (crosses; with the estimated walk in grey for scale),
    clipped to ``box``."""
    if name == "landmarks":
        style = _path_style(len(rec), ".")
        ax.plot(rec[:, 0], rec[:, 1], style, c="0.6", lw=1.0, ms=3, label="_walk for scale")
    if name == "trajectory":
        shown = est if box is None else clip_to_box(est, *box)[0]
        style = _path_style(len(est), "x")
        ax.plot(*shown[:, :2].T, style, c="tab:red", ms=6, label="trajectory (est.)")
        if len(est):
            ax.plot(*shown[0, :2], "o", c="tab:red", ms=9, mfc="none", label="first step")
    else:
        _scatter_clipped(
            ax, est, (0, 1), box, marker="x", s=40, c="tab:red", label=f"{name} (est.)"
        )


def _name_points(ax, pts: np.ndarray, names: list[str], box) -> None:
    """Each of ``pts`` (N, d) inside ``box`` named by ``names`` (N,) beside it."""
    lo, hi = box
    for p, name in zip(pts, names, strict=True):
        if np.all(np.isfinite(p[:2])) and np.all((p[:2] >= lo[:2]) & (p[:2] <= hi[:2])):
            ax.annotate(name, p[:2], xytext=(6, 5), textcoords="offset points", fontsize=8,
                        color="tab:red", zorder=6)  # fmt: skip


def ellipse_magnification(covs, span: float) -> float:
    """The factor by which 2-sigma ellipses of ``covs`` (N, >= 2, >= 2; their x-y blocks) are
    drawn so that the largest reaches 2% of a panel ``span`` metres wide: 1 when it does
    already, else a power of ten; 1 without a finite, non-zero covariance."""
    blocks = [np.asarray(c, dtype=float)[:2, :2] for c in covs]
    blocks = [c for c in blocks if np.all(np.isfinite(c))]
    if not blocks:
        return 1.0
    largest = 2.0 * float(np.sqrt(max(max(np.linalg.eigvalsh(c).max(), 0.0) for c in blocks)))
    if largest <= 0 or largest >= 0.02 * span:
        return 1.0
    return float(10.0 ** np.ceil(np.log10(0.02 * span / largest)))


def _walk_ellipses(ax, est, cov, name: str, span: float) -> str:
    """The 2-sigma ellipses of ``cov`` around ``est`` (magnified by
    :func:`ellipse_magnification` when too small to see in a panel ``span`` metres wide, the
    first one labelled for the legend); returns what the panel's title says of them."""
    if cov is None:
        return ""
    k = ellipse_magnification(cov, span)
    drawn = f", drawn {k:g} x larger" if k > 1 else ""
    label = f"{name}: 2-sigma ellipses (GTSAM){drawn}"
    style = {"fc": "tab:red", "ec": "tab:red", "alpha": 0.25}
    for p, c in zip(est, cov, strict=True):
        if np.all(np.isfinite(c[:2, :2])):
            _ellipse(ax, p[:2], c[:2, :2], nsig=2.0 * k, label=label, **style)
            label = "_nolegend_"  # one legend entry per panel
    return f", 2-sigma ellipses x{k:g}" if k > 1 else ", 2-sigma ellipses"
