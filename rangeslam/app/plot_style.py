"""Shared pieces of the figures (matplotlib; imported lazily by the CLI): readable log axes,
bounds drawn only where finite, legends outside the data, limits set by the room with far points
marked at the edge, saving at a readable size."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import matplotlib.ticker as mticker
import numpy as np
from matplotlib.patches import Rectangle

__all__ = [
    "DPI",
    "LINESTYLES",
    "MARKERS",
    "NOT_ATTAINED",
    "clip_to_box",
    "legend_below",
    "log_ticks",
    "mark_not_attained",
    "overflow",
    "plain_log_axis",
    "plot_bound",
    "save_figure",
    "verdict_title",
]

#: Resolution of every figure written, dots per inch.
DPI = 130
#: One marker per curve, in the order curves are drawn.
MARKERS = ("o", "s", "^", "v", "D", "P", "X", "<", ">", "h")
#: One line style per curve, in the order curves are drawn (with MARKERS and the colours).
LINESTYLES = ("-", "--", "-.", ":", (0, (5, 1, 1, 1, 1, 1)), (0, (1, 1)))
#: What a plot says where a Cramer-Rao bound is not attained by the oracle (so not drawn).
NOT_ATTAINED = "bound not attained: oracle only"


def log_ticks(lo: float, hi: float, *, max_ticks: int = 9) -> np.ndarray:
    """Tick values 1, 2, 5 x 10^k covering [lo, hi] (both > 0), thinned to 1 x 10^k (then every
    other decade) when more than ``max_ticks`` would be needed; at least two ticks."""
    lo, hi = float(min(lo, hi)), float(max(lo, hi))
    k0, k1 = int(np.floor(np.log10(lo))), int(np.ceil(np.log10(hi)))
    for mantissas in ((1.0, 2.0, 5.0), (1.0, 3.0), (1.0,)):
        vals = np.array([m * 10.0**k for k in range(k0, k1 + 1) for m in mantissas])
        inside = vals[(vals >= lo * 0.999) & (vals <= hi * 1.001)]
        if len(inside) <= max_ticks:
            break
    if len(inside) > max_ticks:
        inside = inside[:: int(np.ceil(len(inside) / max_ticks))]
    if len(inside) < 2:  # a narrow range: the neighbouring 1-2-5 values outside it
        below, above = vals[vals < lo], vals[vals > hi]
        inside = np.concatenate([below[-1:], inside, above[:1]])
    return inside


def _plain(value: float, _pos=None) -> str:
    """A tick label as a plain number: '0.5', '2', '10', '200' (no powers of ten)."""
    return f"{value:.10g}" if 1e-4 <= abs(value) < 1e6 else f"{value:.0e}"


def plain_log_axis(
    ax, which: str, *, ticks: Sequence[float] | None = None, headroom: float = 0.0
) -> None:
    """Make ``which`` ('x' or 'y') of ``ax`` a log axis with plain labels at ``ticks`` (the values
    used, e.g. the noise levels), or at 1-2-5 values covering the current data limits; no minor
    labels. ``headroom``: fraction of the (log) range added above the data, free for marks at
    the top edge. Call once, after the data are drawn."""
    axis = ax.xaxis if which == "x" else ax.yaxis
    (ax.set_xscale if which == "x" else ax.set_yscale)("log")
    lim = ax.get_xlim() if which == "x" else ax.get_ylim()
    if headroom > 0:
        lim = (lim[0], lim[1] * (lim[1] / lim[0]) ** headroom)
    if ticks is None:
        ticks = log_ticks(*lim)
    ticks = np.asarray(sorted(set(float(t) for t in ticks if t > 0)))
    axis.set_major_locator(mticker.FixedLocator(ticks))
    axis.set_major_formatter(mticker.FuncFormatter(_plain))
    axis.set_minor_formatter(mticker.NullFormatter())
    if len(ticks):  # keep every tick inside the limits
        lo, hi = min(lim[0], ticks[0] / 1.15), max(lim[1], ticks[-1] * 1.15)
        (ax.set_xlim if which == "x" else ax.set_ylim)(lo, hi)


def plot_bound(ax, x, bound, *, label: str, color: str = "k", marker: str = "D") -> None:
    """Draw a lower bound against ``x`` where it is finite (dashed, with large hollow markers on
    top, so isolated points show, also over an oracle at the same value; broken where it is
    not) and mark with a boxed note 'bound infinite' at the top edge (in the legend 'bound
    infinite: not identifiable'), each x where it is infinite. NaN (no bound, or one not
    attained) is left out."""
    x, bound = np.asarray(x, dtype=float), np.asarray(bound, dtype=float)
    finite = np.isfinite(bound) & (bound > 0)
    if finite.any():
        shown = np.where(finite, bound, np.nan)
        style = {"marker": marker, "ms": 9, "mfc": "none", "mew": 1.4, "zorder": 4}
        ax.plot(x, shown, ls="--", color=color, label=label, **style)  # hollow: over the oracle
    inf = np.isinf(bound)
    if inf.any():
        label = "bound infinite: not identifiable"
        _top_marks(ax, x[inf], "bound\ninfinite", color=color, label=label)


def mark_not_attained(
    ax, x, *, color: str = "0.35", text: str = "CRLB not\nattained", label: str = NOT_ATTAINED
) -> None:
    """Mark each ``x`` where the bound is not attained by the oracle (and so not drawn): a boxed
    note ``text`` at the top edge (a note, not a point: no marker), ``label`` in the legend
    beside a box like it."""
    x = np.asarray(x, dtype=float)
    if x.size:
        _top_marks(ax, x, text, color=color, label=label)


def _top_marks(ax, x, text: str, *, color: str, label: str) -> None:
    """``text`` in a white box hanging from the top edge of ``ax`` at each ``x`` (data), and a
    legend entry ``label`` whose handle is such a box (a zero-size patch: it draws nothing and
    moves no limit)."""
    edge = ax.get_xaxis_transform()  # x in data, y in axes fraction
    box = {"boxstyle": "round,pad=0.3", "fc": "white", "ec": color, "lw": 0.8}
    for xi in x:
        ax.annotate(
            text,
            (xi, 0.975),
            xycoords=edge,
            ha="center",
            va="top",
            fontsize=6,
            color=color,
            bbox=box,
            zorder=6,
        )
    ax.add_patch(Rectangle((0, 0), 0, 0, fc="white", ec=color, lw=0.8, label=label))


def legend_below(fig, axes, *, ncol: int = 3, fontsize: float = 8) -> None:
    """One legend for the figure below the axes (outside the data), from the labelled artists
    of ``axes`` (duplicates by label dropped), in at most ``ncol`` columns: fewer when the
    labels are too long for the figure's width. The figure grows by the legend's height."""
    handles, labels = [], []
    for ax in np.ravel(axes):
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab not in labels and not lab.startswith("_"):
                handles.append(h)
                labels.append(lab)
    if not handles:
        return
    renderer = fig.canvas.get_renderer()
    for cols in range(min(ncol, len(labels)), 0, -1):
        legend = fig.legend(
            handles,
            labels,
            loc="lower center",
            ncol=cols,
            fontsize=fontsize,
            frameon=False,
            bbox_to_anchor=(0.5, 0.0),
        )
        box = legend.get_window_extent(renderer)
        if cols == 1 or box.width <= 0.98 * fig.bbox.width:
            break
        legend.remove()
    legend_in = box.height / fig.dpi + 0.1
    fig.set_figheight(fig.get_figheight() + legend_in)  # the panels keep their height
    fig.tight_layout(rect=(0, legend_in / fig.get_figheight(), 1, 1))


def overflow(fig) -> list[str]:
    """What of ``fig`` reaches beyond its canvas, so a plain ``savefig`` would cut it off: the
    texts (figure title and notes, axes titles, annotations, legend entries) by their text, an
    axis (its drawn tick labels and its label) as '<axes title>: x axis'; empty when all fit.
    Call after the layout is made."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    x0, y0, x1, y1 = fig.bbox.extents

    def beyond(box) -> bool:
        return box.x0 < x0 - 1 or box.y0 < y0 - 1 or box.x1 > x1 + 1 or box.y1 > y1 + 1

    texts = [*fig.texts, *(t for legend in fig.legends for t in legend.get_texts())]
    found = []
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        texts += [ax.title, *ax.texts]
        for name, axis in (("x", ax.xaxis), ("y", ax.yaxis)):
            box = axis.get_tightbbox(renderer)
            if box is not None and beyond(box):
                found.append(f"{ax.get_title()}: {name} axis")
    for text in texts:
        if text.get_visible() and text.get_text() and beyond(text.get_window_extent(renderer)):
            found.append(text.get_text())
    return found


def verdict_title(title: str, converged: bool | None) -> str:
    """``title`` with the run's verdict: ' (NOT CONVERGED)' appended when ``converged`` is False
    and the title does not already say 'not converged'."""
    if converged is False and "not converged" not in title.lower():
        return f"{title} -- not converged" if title else "not converged"
    return title


def clip_to_box(
    points: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, d) pulled onto the box [lo, hi] (d,) and a (N,) mask of those that were
    outside it (to be drawn as 'beyond the plot' at the edge)."""
    points = np.asarray(points, dtype=float)
    outside = np.any((points < lo) | (points > hi), axis=1)
    return np.clip(points, lo, hi), outside


def save_figure(fig, path: str | Path, *, legend_space: bool = False) -> Path:
    """Write ``fig`` to ``path`` at :data:`DPI` after a tight layout (kept when the layout was
    made for a legend below the axes: ``legend_space``), close it, return the path. The image
    takes in every artist (``bbox_inches='tight'``): a title or legend wider than the layout
    grows the image rather than being cut off."""
    if not legend_space:
        fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=DPI, bbox_inches="tight", pad_inches=0.1)
    plt.close(fig)
    return out
