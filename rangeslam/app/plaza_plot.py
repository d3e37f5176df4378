"""The figure of ``rangeslam bench plaza`` (matplotlib; imported lazily by the CLI): trajectories
on the scale of the ground truth, APE over time, the error CDF, and the methods off that scale
(not converged, or far off the best) apart."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from rangeslam.app.plot_style import LINESTYLES, MARKERS, legend_below, plain_log_axis, save_figure

__all__ = ["failed_methods", "method_labels", "off_scale_reasons", "plot_plaza"]

#: A method whose median APE is this many times the best method's (and above FAILED_FLOOR_M)
#: is drawn apart, so that it does not set the scale of the others.
FAILED_RATIO = 5.0
FAILED_FLOOR_M = 1.0


def _median_ape(ev) -> float:
    """Median of the finite APE of an evaluation (inf when there is none)."""
    e = np.asarray(ev.errors, dtype=float)
    return float(np.median(e[np.isfinite(e)])) if np.isfinite(e).any() else np.inf


def off_scale_reasons(results: dict, evaluations: dict) -> dict[str, str]:
    """Why each method drawn apart is drawn apart: 'not converged' (``results[name].converged``
    False), 'no finite error', or 'converged, far off' (a median APE above FAILED_RATIO times the
    best median and FAILED_FLOOR_M). Methods that are none of these are left out."""
    med = {name: _median_ape(ev) for name, ev in evaluations.items()}
    best = min(med.values(), default=np.inf)
    reasons = {}
    for name, m in med.items():
        if getattr(results.get(name), "converged", True) is False:
            reasons[name] = "not converged"
        elif not np.isfinite(m):
            reasons[name] = "no finite error"
        elif m > max(FAILED_RATIO * best, FAILED_FLOOR_M):
            reasons[name] = "converged, far off"
    return reasons


def failed_methods(results: dict, evaluations: dict) -> set[str]:
    """Names of the methods drawn apart (see :func:`off_scale_reasons`)."""
    return set(off_scale_reasons(results, evaluations))


def method_labels(evaluations: dict, rows: list[dict] | None = None) -> dict[str, str]:
    """Legend text of each method: the statistic of the bench's table ("mean [m]": the mean APE,
    for methods run several times the median over the trials and the worst trial) from
    ``rows`` (the bench rows, see :func:`rangeslam.app.plaza_bench.method_rows`); the trial
    drawn (the row whose mean is the drawn one's) is named when its mean is not that median.
    Without rows, the drawn trial's mean APE."""
    labels = {}
    for name, ev in evaluations.items():
        e = np.asarray(ev.errors, dtype=float)
        drawn = float(np.mean(e[np.isfinite(e)])) if np.isfinite(e).any() else float("nan")
        mine = [r for r in rows or () if r["method"] == name and r["status"] == "ok"]
        means = [float(r["mean"]) for r in mine]
        if len(means) <= 1:
            labels[name] = f"{name} (mean APE {drawn:.2f} m)"
            continue
        median, worst = float(np.median(means)), float(np.max(means))
        text = f"{name} (mean APE {median:.2f} m, median of {len(means)} trials, worst {worst:.2f}"
        if f"{drawn:.2f}" != f"{median:.2f}":
            trial = int(mine[int(np.nanargmin(np.abs(np.array(means) - drawn)))]["trial"])
            text += f"; drawn: trial {trial + 1}, {drawn:.2f}"
        labels[name] = text + " m)"
    return labels


def _styles(names) -> dict[str, dict]:
    """One look per method, no two alike: colour, marker and line style; the first drawn is
    the widest and lowest, so that a later method on the same path leaves it showing."""
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    names = list(names)
    return {
        name: {
            "color": colours[k % len(colours)],
            "marker": MARKERS[k % len(MARKERS)],
            "ls": LINESTYLES[k % len(LINESTYLES)],
            "lw": 1.0 + 1.6 * (len(names) - 1 - k) / max(len(names) - 1, 1),
            "zorder": 2 + 0.1 * k,
            "offset": k,
        }
        for k, name in enumerate(names)
    }


def plot_plaza(
    path: str | Path, dataset, results: dict, evaluations: dict, *, rows: list[dict] | None = None
) -> Path:
    """Four panels for a Plaza data set, every method aligned onto the ground truth as the bench
    evaluates it (``evaluations[name]``: :class:`rangeslam.evaluation.metrics.PositionErrors`;
    ``results[name]``: its result, with ``pose_time`` [s] and ``converged``; ``rows``: the
    bench's rows, whose statistic the legend quotes, see :func:`method_labels`):

    (a) trajectories and beacons of the methods on the scale of the ground truth, limits set by
    it and the surveyed beacons; (b) APE [m] against time [s]; (c) the CDF of the APE;
    (d) the methods that did not converge or are far off the best, each with its reason, on
    their own scale. Every method has its own colour, marker and line style. Returns the path
    written.
    """
    apart = off_scale_reasons(results, evaluations)
    style = _styles(evaluations)
    labels = method_labels(evaluations, rows)
    fig, axs = plt.subplots(2, 2, figsize=(13.0, 11.5))
    truth = dataset.truth_at(dataset.pose_time)
    good = {n: evaluations[n] for n in evaluations if n not in apart}
    _trajectories(axs[0][0], dataset, truth, good, style, labels, limits=True)
    lo, hi = np.nanmin(truth, axis=0), np.nanmax(truth, axis=0)
    core = np.vstack([lo, hi, dataset.beacons.min(axis=0), dataset.beacons.max(axis=0)])
    pad = 0.08 * float(np.ptp(core, axis=0).max())
    axs[0][0].set_xlim(core[:, 0].min() - pad, core[:, 0].max() + pad)
    axs[0][0].set_ylim(core[:, 1].min() - pad, core[:, 1].max() + pad)
    axs[0][0].set_title("(a) trajectories after rigid alignment (limits: ground truth)")
    _ape_over_time(axs[0][1], dataset, results, evaluations, style, labels)
    _error_cdf(axs[1][0], evaluations, style, labels)
    _apart_panel(axs[1][1], dataset, truth, evaluations, apart, style, labels)
    fig.suptitle(f"{dataset.name}: APE after rigid alignment onto the ground truth")
    legend_below(fig, axs, ncol=3, fontsize=9)
    return save_figure(fig, path, legend_space=True)


def _apart_panel(ax, dataset, truth, evaluations, apart: dict, style, labels) -> None:
    """(d) the methods drawn apart, each named with its reason in the panel."""
    shown = {n: evaluations[n] for n in evaluations if n in apart}
    _trajectories(ax, dataset, truth, shown, style, labels)
    if not apart:
        ax.set_title("(d) every method converged and is on the scale of (a)")
        ax.text(0.5, 0.5, "no method drawn apart", ha="center", transform=ax.transAxes)
        return
    ax.set_title("(d) not converged, or converged but far off (own scale)")
    text = "\n".join(f"{n}: {why}" for n, why in apart.items())
    ax.text(
        0.02,
        0.98,
        text,
        transform=ax.transAxes,
        va="top",
        fontsize=8,
        zorder=10,
        bbox={"fc": "white", "ec": "0.7", "alpha": 0.85},
    )


def _line(st: dict, n: int, every: int) -> dict:
    """Line keywords of a method's style, its markers shifted so that methods' markers differ."""
    step = max(n // every, 1)
    kw = {k: st[k] for k in ("color", "marker", "ls", "lw", "zorder")}
    return {**kw, "markevery": (st["offset"] * step // 7 % step, step)}


def _trajectories(ax, dataset, truth, evaluations, style, labels, *, limits=False) -> None:
    """Ground truth, surveyed beacons, and each method's aligned trajectory and beacons."""
    ax.plot(*truth.T, color="0.6", lw=4.0, label="ground truth", zorder=1)
    ax.scatter(*dataset.beacons.T, marker="*", s=200, color="k", label="surveyed beacons", zorder=6)
    for name, ev in evaluations.items():
        st = style[name]
        ax.plot(*ev.aligned.T, ms=5, label=labels[name], **_line(st, len(ev.aligned), 25))
        ok = np.all(np.isfinite(ev.aligned_beacons), axis=1)
        ax.scatter(*ev.aligned_beacons[ok].T, marker="x", s=70, color=st["color"], zorder=7)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="box" if limits else "datalim")
    ax.grid(alpha=0.3)


def _ape_over_time(ax, dataset, results, evaluations, style, labels) -> None:
    """(b) APE of each method against time from the data set's first pose, log axis."""
    t0 = float(dataset.pose_time[0])
    for name, ev in evaluations.items():
        res = results.get(name)
        t = np.asarray(getattr(res, "pose_time", dataset.pose_time[: len(ev.errors)])) - t0
        ax.plot(t, ev.errors, ms=5, label=labels[name], **_line(style[name], len(t), 20))
    if any(np.isfinite(ev.errors).any() for ev in evaluations.values()):
        plain_log_axis(ax, "y")
    ax.set_xlabel("time since the first pose [s]")
    ax.set_ylabel("APE [m]")
    ax.set_title("(b) absolute position error over time")
    ax.grid(alpha=0.3, which="major")


def _error_cdf(ax, evaluations, style, labels) -> None:
    """(c) Empirical CDF of each method's APE (finite errors), log x axis."""
    for name, ev in evaluations.items():
        e = np.sort(np.asarray(ev.errors, dtype=float)[np.isfinite(ev.errors)])
        if not len(e):
            continue
        frac = np.arange(1, len(e) + 1) / len(ev.errors)
        ax.plot(e, frac, ms=6, label=labels[name], **_line(style[name], len(e), 10))
    if any(np.isfinite(ev.errors).any() for ev in evaluations.values()):
        plain_log_axis(ax, "x")
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("APE [m]")
    ax.set_ylabel("fraction of poses with APE below")
    ax.set_title("(c) cumulative distribution of the APE")
    ax.grid(alpha=0.3, which="major")
