"""The figure of ``rangeslam bench plaza`` (matplotlib; imported lazily by the CLI): trajectories
on the scale of the ground truth, APE over time, the error CDF, and the failed baselines apart."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from rangeslam.app.plot_style import MARKERS, legend_below, plain_log_axis, save_figure

__all__ = ["failed_methods", "plot_plaza"]

#: A method whose median APE is this many times the best method's (and above FAILED_FLOOR_M)
#: is drawn apart as failed, so that it does not set the scale of the others.
FAILED_RATIO = 5.0
FAILED_FLOOR_M = 1.0


def failed_methods(results: dict, evaluations: dict) -> set[str]:
    """Names of the methods that failed: not converged (``results[name].converged`` False), no
    finite error, or a median APE above FAILED_RATIO times the best median (and FAILED_FLOOR_M)."""
    med = {}
    for name, ev in evaluations.items():
        e = np.asarray(ev.errors, dtype=float)
        med[name] = float(np.median(e[np.isfinite(e)])) if np.isfinite(e).any() else np.inf
    best = min(med.values(), default=np.inf)
    failed = set()
    for name, m in med.items():
        res = results.get(name)
        if (
            getattr(res, "converged", True) is False
            or not np.isfinite(m)
            or m > max(FAILED_RATIO * best, FAILED_FLOOR_M)
        ):
            failed.add(name)
    return failed


def plot_plaza(path: str | Path, dataset, results: dict, evaluations: dict) -> Path:
    """Four panels for a Plaza data set, every method aligned onto the ground truth as the bench
    evaluates it (``evaluations[name]``: :class:`rangeslam.evaluation.metrics.PositionErrors`;
    ``results[name]``: its result, with ``pose_time`` [s] and ``converged``):

    (a) trajectories and beacons of the methods that did not fail, limits set by the ground
    truth and the surveyed beacons; (b) APE [m] against time [s]; (c) the CDF of the APE;
    (d) the failed methods (not converged, or median APE far above the best) on their own
    scale. Returns the path written.
    """
    failed = failed_methods(results, evaluations)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    style = {
        name: {"color": colours[k % len(colours)], "marker": MARKERS[k % len(MARKERS)]}
        for k, name in enumerate(evaluations)
    }
    fig, axs = plt.subplots(2, 2, figsize=(13.0, 11.5))
    truth = dataset.truth_at(dataset.pose_time)
    good = [n for n in evaluations if n not in failed]
    _trajectories(axs[0][0], dataset, truth, {n: evaluations[n] for n in good}, style, limits=True)
    lo, hi = np.nanmin(truth, axis=0), np.nanmax(truth, axis=0)
    core = np.vstack([lo, hi, dataset.beacons.min(axis=0), dataset.beacons.max(axis=0)])
    pad = 0.08 * float(np.ptp(core, axis=0).max())
    axs[0][0].set_xlim(core[:, 0].min() - pad, core[:, 0].max() + pad)
    axs[0][0].set_ylim(core[:, 1].min() - pad, core[:, 1].max() + pad)
    axs[0][0].set_title("(a) trajectories after rigid alignment (limits: ground truth)")
    _ape_over_time(axs[0][1], dataset, results, evaluations, style)
    _error_cdf(axs[1][0], evaluations, style)
    failed_ev = {n: evaluations[n] for n in evaluations if n in failed}
    _trajectories(axs[1][1], dataset, truth, failed_ev, style)
    axs[1][1].set_title("(d) failed methods (own scale)" if failed else "(d) no method failed")
    if not failed:
        axs[1][1].text(0.5, 0.5, "no failed method", ha="center", transform=axs[1][1].transAxes)
    fig.suptitle(f"{dataset.name}: APE after rigid alignment onto the ground truth")
    legend_below(fig, axs, ncol=4, fontsize=9)
    return save_figure(fig, path, legend_space=True)


def _label(name: str, ev) -> str:
    """Legend text of a method: its name and mean APE."""
    e = np.asarray(ev.errors, dtype=float)
    mean = float(np.mean(e[np.isfinite(e)])) if np.isfinite(e).any() else float("nan")
    return f"{name} (mean APE {mean:.2f} m)"


def _trajectories(ax, dataset, truth, evaluations: dict, style: dict, *, limits=False) -> None:
    """Ground truth, surveyed beacons, and each method's aligned trajectory and beacons."""
    ax.plot(*truth.T, color="0.6", lw=2.5, label="ground truth", zorder=1)
    ax.scatter(*dataset.beacons.T, marker="*", s=200, color="k", label="surveyed beacons", zorder=4)
    for name, ev in evaluations.items():
        st = style[name]
        n = len(ev.aligned)
        ax.plot(
            *ev.aligned.T,
            lw=0.8,
            color=st["color"],
            marker=st["marker"],
            ms=4,
            markevery=max(n // 25, 1),
            label=_label(name, ev),
        )
        ok = np.all(np.isfinite(ev.aligned_beacons), axis=1)
        ax.scatter(*ev.aligned_beacons[ok].T, marker="x", s=70, color=st["color"], zorder=5)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="box" if limits else "datalim")
    ax.grid(alpha=0.3)


def _ape_over_time(ax, dataset, results: dict, evaluations: dict, style: dict) -> None:
    """(b) APE of each method against time from the data set's first pose, log axis."""
    t0 = float(dataset.pose_time[0])
    for name, ev in evaluations.items():
        res = results.get(name)
        t = np.asarray(getattr(res, "pose_time", dataset.pose_time[: len(ev.errors)])) - t0
        st = style[name]
        ax.plot(
            t, ev.errors, lw=0.8, ms=4, markevery=max(len(t) // 20, 1), label=_label(name, ev), **st
        )
    if any(np.isfinite(ev.errors).any() for ev in evaluations.values()):
        plain_log_axis(ax, "y")
    ax.set_xlabel("time since the first pose [s]")
    ax.set_ylabel("APE [m]")
    ax.set_title("(b) absolute position error over time")
    ax.grid(alpha=0.3, which="major")


def _error_cdf(ax, evaluations: dict, style: dict) -> None:
    """(c) Empirical CDF of each method's APE (finite errors), log x axis."""
    for name, ev in evaluations.items():
        e = np.sort(np.asarray(ev.errors, dtype=float)[np.isfinite(ev.errors)])
        if not len(e):
            continue
        frac = np.arange(1, len(e) + 1) / len(ev.errors)
        ax.plot(
            e,
            frac,
            lw=1.2,
            ms=5,
            markevery=max(len(e) // 10, 1),
            label=_label(name, ev),
            **style[name],
        )
    if any(np.isfinite(ev.errors).any() for ev in evaluations.values()):
        plain_log_axis(ax, "x")
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("APE [m]")
    ax.set_ylabel("fraction of poses with APE below")
    ax.set_title("(c) cumulative distribution of the APE")
    ax.grid(alpha=0.3, which="major")
