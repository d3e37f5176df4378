"""Figures of the regime map (:mod:`rangeslam.app.regime_map`): one per figure of merit.

Each figure has a panel per family of cells (walk x bounds x noise, and the variants of random
walks with bounds: 2-D, missing echoes, wrong picks), the number of steps M on the x axis and a
curve per method.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rangeslam.app.plot_style import MARKERS, legend_below, plain_log_axis, plt, save_figure
from rangeslam.app.regime_map import METHOD_LABELS, cell_of_row
from rangeslam.app.regimes import REGIME_METHODS, SUCCESS_M
from rangeslam.evaluation.metrics import rms_against_bound

__all__ = ["REGIME_FIGURES", "plot_regimes"]


def family(row: dict) -> str:
    """The panel a row belongs to: the cell's label without its M."""
    cell = cell_of_row(row)
    return ", ".join(p for p in cell.label.split(", ") if not p.startswith("M="))


def success(rows: list[dict], method: str) -> float:
    """Percent of trials with a trajectory error under SUCCESS_M."""
    return 100 * float(np.mean([r[f"{method}_success"] for r in rows]))


def oracle_ratio(rows: list[dict], method: str) -> float:
    """RMS error over the trials / the oracle's (NaN where there is none)."""
    return rms_against_bound(
        [r[f"{method}_error_m"] for r in rows],
        [r["crlb_m"] for r in rows],
        [r.get("oracle_error_m", np.nan) for r in rows],
    ).search


def median_time(rows: list[dict], method: str) -> float:
    """Median wall time, seconds."""
    v = np.asarray([r[f"{method}_seconds"] for r in rows], float)
    return float(np.median(v[np.isfinite(v)])) if np.isfinite(v).any() else float("nan")


#: file stem -> (figure of merit, y label, log y axis)
REGIME_FIGURES = {
    "regimes_success": (success, f"success (error < {SUCCESS_M * 100:g} cm) [%]", False),
    "regimes_oracle": (oracle_ratio, "RMS error / the oracle's RMS error (search)", True),
    "regimes_time": (median_time, "median wall time [s]", True),
}


def merit_panel(ax, rows: list[dict], merit, methods) -> None:
    """One panel: ``merit`` of each method against M."""
    steps = sorted({int(r["m"]) for r in rows})
    width = 0.06 * (max(steps) - min(steps) or 4)  # methods side by side, none hidden
    for k, method in enumerate(methods):
        values = [merit([r for r in rows if r["m"] == m], method) for m in steps]
        x = np.array(steps) + width * (k - (len(methods) - 1) / 2)
        ax.plot(x, values, marker=MARKERS[k % len(MARKERS)], label=METHOD_LABELS[method])
    ax.set_xticks(steps)
    ax.set_xlabel("steps M")
    ax.grid(True, alpha=0.3)


def plot_regimes(out: Path, rows: list[dict], methods=REGIME_METHODS) -> list[Path]:
    """The figures of :data:`REGIME_FIGURES` for ``rows`` into folder ``out``; their paths."""
    families: dict[str, list[dict]] = {}
    for r in rows:
        if r["status"] == "ok":
            families.setdefault(family(r), []).append(r)
    n = len(families)
    cols = min(4, max(n, 1))
    n_rows = int(np.ceil(n / cols))
    written = []
    for stem, (merit, ylabel, log) in REGIME_FIGURES.items():
        fig, axs = plt.subplots(
            n_rows, cols, figsize=(4.2 * cols, 3.4 * n_rows + 1.2), squeeze=False
        )
        for ax, (name, fam_rows) in zip(axs.flat, families.items(), strict=False):
            merit_panel(ax, fam_rows, merit, methods)
            ax.set_title(name, fontsize=9)
            ax.set_ylabel(ylabel, fontsize=8)
            if merit is oracle_ratio:
                ax.axhline(1.0, color="k", lw=0.8, ls=":", label="the oracle")
            if log:
                ax.set_yscale("log")
                plain_log_axis(ax, "y")
            if merit is success:
                ax.set_ylim(-5, 105)
        for ax in list(axs.flat)[n:]:
            ax.set_visible(False)
        fig.suptitle(f"Regime map: {ylabel} against the number of steps")
        legend_below(fig, axs, ncol=3)
        written.append(save_figure(fig, Path(out) / f"{stem}.png", legend_space=True))
    return written
