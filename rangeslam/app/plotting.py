"""Plots with matplotlib (imported lazily by the CLI; the math modules never import this)."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from scipy.spatial import ConvexHull

from rangeslam.geometry.room import Room

__all__ = [
    "plot_fig3",
    "plot_fig5",
    "plot_plaza",
    "plot_rir_matrix",
    "plot_room_estimate",
    "plot_room_reconstruction",
    "plot_slam_estimate",
    "plot_walk_estimate",
]

_VIEWS = (("top view", (0, 1), ("x [m]", "y [m]")), ("side view", (0, 2), ("x [m]", "z [m]")))


def _outline(ax, room: Room, axes: tuple[int, int], **style) -> None:
    """The room's outline projected on two coordinate ``axes`` (the convex hull of its corners)."""
    pts = room.vertices[:, list(axes)]
    hull = ConvexHull(pts)
    loop = np.append(hull.vertices, hull.vertices[0])
    ax.plot(pts[loop, 0], pts[loop, 1], **style)


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
) -> Path:
    """Write a figure of the true and reconstructed rooms (outlines), microphones and sources.

    3-D rooms are shown in a top and a side projection, 2-D rooms once. Returns the path written.
    """
    d = true_room.dim
    views = _VIEWS if d == 3 else _VIEWS[:1]
    fig, axs = plt.subplots(1, len(views), figsize=(6.0 * len(views), 5.0), squeeze=False)
    for ax, (name, axes, labels) in zip(axs[0], views, strict=True):
        _outline(ax, true_room, axes, color="0.3", lw=2.0, label="true room")
        if estimated_room is not None:
            _outline(
                ax, estimated_room, axes, color="tab:red", lw=1.2, ls="--", label="reconstructed"
            )
        _scatter_room_points(ax, axes, mics, image_sources, true_sources, estimated_sources)
        ax.set_xlabel(labels[0])
        ax.set_ylabel(labels[1])
        ax.set_title(name)
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    axs[0][0].legend(loc="best", fontsize=7)
    if title:
        fig.suptitle(title)
    return _save(fig, path)


def _scatter_room_points(ax, axes, mics, image_sources, true_sources, estimated_sources) -> None:
    """Microphones, image sources and the loudspeaker (true and estimated) in one view; any of
    the last three may be None. Points as rows, one point as (d,)."""
    d = mics.shape[1]
    if image_sources is not None and len(image_sources):
        ims = image_sources.reshape(-1, d)
        ax.scatter(
            ims[:, axes[0]],
            ims[:, axes[1]],
            marker="*",
            s=40,
            c="tab:orange",
            label="image sources (est.)",
        )
    ax.scatter(
        mics[:, axes[0]], mics[:, axes[1]], marker="o", s=18, c="tab:blue", label="microphones"
    )
    for pts, label, style in (
        (
            true_sources,
            "loudspeaker (true)",
            {"marker": "s", "s": 60, "facecolors": "none", "edgecolors": "k"},
        ),
        (estimated_sources, "loudspeaker (est.)", {"marker": "x", "s": 50, "c": "tab:red"}),
    ):
        if pts is not None:
            pts = np.reshape(pts, (-1, d))
            ax.scatter(pts[:, axes[0]], pts[:, axes[1]], label=label, **style)


def _save(fig, path: str | Path) -> Path:
    """Write ``fig`` to ``path`` (120 dpi), close it, return the path."""
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def plot_fig3(path: str | Path, rows: list[dict]) -> Path:
    """The Fig. 3 analogue: microphone error after alignment against the range noise, every trial
    as a dot, the median as a line, and the median CRLB (``rows`` of a ``bench fig3`` run)."""
    ok = [r for r in rows if r["status"] == "ok" and r["sigma"] > 0]
    sigmas = sorted({r["sigma"] for r in ok})
    fig, ax = plt.subplots(figsize=(6.0, 4.5))
    if sigmas:
        x = np.array([r["sigma"] for r in ok]) * 1e3
        jitter = np.exp(np.random.default_rng(0).uniform(-0.08, 0.08, len(x)))
        ax.scatter(x * jitter, [r["mic_error_m"] * 1e3 for r in ok], s=6, alpha=0.3, c="tab:blue")
        med = [np.median([r["mic_error_m"] for r in ok if r["sigma"] == s]) * 1e3 for s in sigmas]
        crlb = [np.median([r["crlb_m"] for r in ok if r["sigma"] == s]) * 1e3 for s in sigmas]
        s_mm = np.array(sigmas) * 1e3
        ax.plot(s_mm, med, "o-", c="tab:blue", label="median error (calibrate)")
        ax.plot(s_mm, crlb, "k--", label="median CRLB")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
        ax.yaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.set_xlabel("range noise sigma [mm]")
    ax.set_ylabel("microphone RMS error after alignment [mm]")
    ax.set_title("Fig. 3: zero-knowledge array calibration")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_fig5(path: str | Path, rows: list[dict], methods: dict[str, str]) -> Path:
    """The Fig. 5 analogue: trajectory error against the number of steps, with and without step
    bounds (columns) and per noise level (rows); median per method, inter-quartile band."""
    rows = [r for r in rows if r["status"] == "ok"]
    sigmas = sorted({r["sigma"] for r in rows})
    bounds = sorted({r["bounds"] for r in rows}, reverse=True)
    fig, axs = plt.subplots(
        len(sigmas), len(bounds), figsize=(5.5 * len(bounds), 4.0 * len(sigmas)), squeeze=False
    )
    for i, sigma in enumerate(sigmas):
        for j, b in enumerate(bounds):
            ax = axs[i][j]
            cell = [r for r in rows if r["sigma"] == sigma and r["bounds"] == b]
            steps = sorted({r["m"] for r in cell})
            for key, name in methods.items():
                per_m = [
                    np.array([r.get(f"{key}_error_m", np.nan) for r in cell if r["m"] == m]) * 100
                    for m in steps
                ]
                if not any(np.isfinite(v).any() for v in per_m):
                    continue
                q = np.array([np.nanpercentile(v, [25, 50, 75]) for v in per_m])
                ax.plot(steps, q[:, 1], "o-", label=name)
                ax.fill_between(steps, q[:, 0], q[:, 2], alpha=0.15)
            crlb = [np.median([r["crlb_m"] for r in cell if r["m"] == m]) * 100 for m in steps]
            ax.plot(steps, crlb, "k--", label="CRLB (ranges alone)")
            ax.set_yscale("log")
            ax.yaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
            ax.set_xlabel("number of steps M")
            ax.set_ylabel("trajectory RMS error [cm]")
            ax.set_title(
                f"sigma = {sigma * 1e3:g} mm, " + ("+-20% step bounds" if b else "no bounds")
            )
            ax.grid(alpha=0.3, which="both")
    axs[0][0].legend(fontsize=7)
    fig.suptitle("Fig. 5: range-only SLAM on the lemniscate (median, 25-75%)")
    return _save(fig, path)


def _top_view_axes(ax) -> None:
    """Style a top view: x and y in metres, equal aspect, a light grid, a small legend."""
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)


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
        ax.plot(est[:, 0], est[:, 1], style.replace("s", "x"), c="tab:red", ms=5, label="estimate")
        for p, c in zip(est, cov, strict=True):
            _ellipse(ax, p[:2], c[:2, :2], fc="tab:red", ec="tab:red", alpha=0.2)
        _top_view_axes(ax)
        ax.set_title(f"{name}, top view, 2-sigma ellipses (GTSAM)")
    if title:
        fig.suptitle(title)
    return _save(fig, path)


def plot_rir_matrix(
    path: str | Path, rirs: np.ndarray, fs: float, title: str = "", *, xlabel: str = "step"
) -> Path:
    """The "RIR matrix" of Fig. 4C: steps (or microphones: ``xlabel``) along x, time along y,
    magnitude in dB as colour."""
    mag = 20 * np.log10(np.abs(rirs) / np.max(np.abs(rirs)) + 1e-6)
    fig, ax = plt.subplots(figsize=(7.0, 5.0))
    im = ax.imshow(
        mag.T,
        aspect="auto",
        origin="lower",
        extent=(0.5, len(rirs) + 0.5, 0, rirs.shape[1] / fs * 1e3),
        vmin=-60,
        vmax=0,
        cmap="magma",
    )
    fig.colorbar(im, ax=ax, label="magnitude [dB]")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("time [ms]")
    ax.set_title(title or "RIR at each step of the walk (Fig. 4C)")
    return _save(fig, path)


def plot_plaza(path: str | Path, dataset, results: dict, evaluations: dict) -> Path:
    """Trajectories and beacons of each method on a Plaza data set, rigidly aligned onto the
    ground truth (as evaluated), with the ground truth and the surveyed beacons."""
    fig, ax = plt.subplots(figsize=(8, 8))
    truth = dataset.truth_at(dataset.pose_time)
    ax.plot(truth[:, 0], truth[:, 1], color="0.6", lw=2.5, label="ground truth", zorder=1)
    ax.scatter(*dataset.beacons.T, marker="*", s=250, color="k", label="surveyed beacons", zorder=4)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, (name, ev) in enumerate(evaluations.items()):
        colour = colours[k % len(colours)]
        ax.plot(
            *ev.aligned.T, lw=0.8, color=colour, label=f"{name} ({np.nanmean(ev.errors):.2f} m)"
        )
        ok = np.all(np.isfinite(ev.aligned_beacons), axis=1)
        ax.scatter(*ev.aligned_beacons[ok].T, marker="x", s=80, color=colour, zorder=5)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{dataset.name}: trajectories and beacons after rigid alignment (mean APE)")
    ax.legend(fontsize=8, loc="best")
    return _save(fig, path)


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
) -> Path:
    """A room estimated from RIRs (``rangeslam run``), top and side views, with or without truth.

    The estimated room's outline when the walls bound one (``room``); otherwise each wall as the
    line where it cuts the view plane through the loudspeaker (walls nearly parallel to the view
    are left out of it). Microphones, loudspeaker, image sources; the true room and loudspeaker
    when given. Returns the path written.
    """
    centre = source if source is not None else mics.mean(axis=0)
    pts = [mics, centre[None]]
    if image_sources is not None and len(image_sources):
        pts.append(image_sources.reshape(-1, 3))
    if true_room is not None:
        pts.append(true_room.vertices)
    if room is not None:
        pts.append(room.vertices)
    if wall_normals is not None and wall_offsets is not None:  # foot of the loudspeaker on each
        foot = centre + (wall_offsets - wall_normals @ centre)[:, None] * wall_normals
        pts.append(foot)
    allpts = np.vstack(pts)
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    pad = 0.08 * np.max(hi - lo) + 0.1
    lo, hi = lo - pad, hi + pad
    fig, axs = plt.subplots(1, 2, figsize=(12.0, 5.6), squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (name, axes, labels) in zip(axs[0], _VIEWS, strict=True):
        if true_room is not None:
            _outline(ax, true_room, axes, color="0.3", lw=2.0, label="true room")
        if room is not None:
            _outline(ax, room, axes, color="tab:red", lw=1.2, ls="--", label="reconstructed")
        elif wall_normals is not None and wall_offsets is not None:
            for k, (n, o) in enumerate(zip(wall_normals, wall_offsets, strict=True)):
                _wall_trace(
                    ax,
                    n,
                    o,
                    axes,
                    centre,
                    np.array([lo[list(axes)], hi[list(axes)]]),
                    color=colours[k % len(colours)],
                    lw=1.2,
                    ls="--",
                    label=f"wall {k}",
                )
        _scatter_room_points(ax, axes, mics, image_sources, true_source, source)
        ax.set_xlim(lo[axes[0]], hi[axes[0]])
        ax.set_ylim(lo[axes[1]], hi[axes[1]])
        ax.set_xlabel(labels[0])
        ax.set_ylabel(labels[1])
        ax.set_title(name + ("" if room is not None else " (walls cut through the loudspeaker)"))
        ax.set_aspect("equal", adjustable="box")
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=7)
    if title:
        fig.suptitle(title)
    return _save(fig, path)


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
) -> Path:
    """Top view of a trajectory and its landmarks estimated from RIRs (``rangeslam run``), with
    2-sigma ellipses when covariances are given. With ``true_trajectory`` the estimate is mapped
    onto it by (``rotation``, ``translation``), e.g. from :func:`rangeslam.align`; otherwise it
    is drawn in its own frame. Returns the path written."""
    d = receivers.shape[1]
    rot = np.eye(d) if rotation is None else rotation
    shift = np.zeros(d) if translation is None else translation
    rec = receivers @ rot.T + shift
    src = sources @ rot.T + shift
    rot_cov = lambda c: None if c is None else np.einsum("ij,njk,lk->nil", rot, c, rot)  # noqa: E731
    fig, axs = plt.subplots(1, 2, figsize=(12.0, 5.0))
    for ax, est, cov, name in (
        (axs[0], rec, rot_cov(receiver_cov), "trajectory"),
        (axs[1], src, rot_cov(source_cov), "landmarks"),
    ):
        if name == "trajectory" and true_trajectory is not None:
            ax.plot(
                true_trajectory[:, 0],
                true_trajectory[:, 1],
                "o-",
                c="k",
                mfc="none",
                ms=5,
                label="trajectory (true)",
            )
        if name == "landmarks":  # the walk, for scale
            ax.plot(rec[:, 0], rec[:, 1], "-", c="0.6", lw=1.0, label="trajectory (est.)")
        style = "x-" if name == "trajectory" else "x"
        ax.plot(est[:, 0], est[:, 1], style, c="tab:red", ms=6, label=f"{name} (est.)")
        if name == "trajectory" and len(est):
            ax.plot(est[0, 0], est[0, 1], "o", c="tab:red", ms=8, mfc="none", label="first step")
        if cov is not None:
            for p, c in zip(est, cov, strict=True):
                _ellipse(ax, p[:2], c[:2, :2], fc="tab:red", ec="tab:red", alpha=0.2)
        _top_view_axes(ax)
        frame = "aligned onto the truth" if true_trajectory is not None else "SLAM frame"
        ax.set_title(f"{name}, top view ({frame})" + (", 2-sigma" if cov is not None else ""))
    if title:
        fig.suptitle(title)
    return _save(fig, path)
