"""Plots with matplotlib (imported lazily by the CLI; the math modules never import this)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from scipy.spatial import ConvexHull

from .geometry import Room

__all__ = ["plot_room_reconstruction"]

_VIEWS = (("top view", (0, 1), ("x [m]", "y [m]")), ("side view", (0, 2), ("x [m]", "z [m]")))


def _outline(ax, room: Room, axes: tuple[int, int], **style) -> None:
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
        if image_sources is not None:
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
        ax.scatter(
            true_sources[:, axes[0]],
            true_sources[:, axes[1]],
            marker="s",
            s=60,
            facecolors="none",
            edgecolors="k",
            label="loudspeaker (true)",
        )
        ax.scatter(
            estimated_sources[:, axes[0]],
            estimated_sources[:, axes[1]],
            marker="x",
            s=50,
            c="tab:red",
            label="loudspeaker (est.)",
        )
        ax.set_xlabel(labels[0])
        ax.set_ylabel(labels[1])
        ax.set_title(name)
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    axs[0][0].legend(loc="best", fontsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out
