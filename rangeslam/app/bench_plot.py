"""Figures of the simulated benchmarks, Fig. 3 (calibration) and Fig. 5 (SLAM; ``compare``), with
the two yardsticks of :func:`rangeslam.evaluation.metrics.rms_against_bound`: the oracle (the
estimator's own cost minimised from the truth, drawn as its own line) and the Cramer-Rao bound,
drawn only at the cells where the oracle's RMS attains it; elsewhere the panel says 'bound not
attained: oracle only' (matplotlib; imported lazily by the CLI)."""

from __future__ import annotations

from pathlib import Path

import matplotlib.ticker
import numpy as np
from matplotlib.patches import Rectangle

from rangeslam.app.plot_style import (
    MARKERS,
    legend_below,
    mark_not_attained,
    plain_log_axis,
    plot_bound,
    plt,
    save_figure,
)
from rangeslam.evaluation.metrics import BoundComparison, rms_against_bound

__all__ = [
    "EKF_METHODS",
    "NO_ORACLE",
    "ORACLE_STYLE",
    "column",
    "draw_yardsticks",
    "ekf_label",
    "ekf_used",
    "exact_note",
    "fig5_landmark_panel",
    "fig5_trajectory_panel",
    "judge_bound",
    "oracle_label",
    "oracle_yardstick",
    "plot_fig3",
    "plot_fig5",
    "rms_and_bound",
]

#: How the oracle's RMS is drawn in every panel.
ORACLE_STYLE = {"color": "0.35", "ls": ":", "lw": 1.6, "marker": "*", "ms": 9}
#: What a plot says where its rows have a bound but no oracle to judge it by (older CSVs).
NO_ORACLE = "no oracle in the rows: bound not judged, not drawn"
#: The methods whose rows carry ``ekf_filtered_steps`` (the EKF and its RTS smoothing).
EKF_METHODS = ("ekf", "ekf_rts")


def column(rows: list[dict], key: str) -> np.ndarray:
    """The values of ``key`` over ``rows`` as floats, NaN where a row lacks it (an older CSV)."""
    return np.array([r.get(key, np.nan) for r in rows], dtype=float)


def _rms_finite(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(finite**2))) if finite.size else float("nan")


def rms_and_bound(errors, bounds) -> tuple[float, float]:
    """(RMS error, RMS bound) of one cell as the comparison plots draw them: over the trials with
    a finite bound; where every bound is inf, the RMS of all finite errors and inf (drawn as
    'bound infinite'); where there is no bound (zero noise), that RMS and NaN."""
    errors = np.asarray(errors, dtype=float)
    cmp = rms_against_bound(errors, bounds)
    if cmp.trials:
        return cmp.rms_error, cmp.rms_bound
    return _rms_finite(errors), float("inf") if cmp.unidentifiable else float("nan")


def oracle_yardstick(rows: list[dict]) -> np.ndarray:
    """Per trial, the oracle's figure its bound is checked against: its Monte-Carlo RMS
    (``oracle_rms_m``) where finite, else its error on the trial's own data (``oracle_error_m``);
    NaN where the row has neither (no oracle was run)."""
    mc, same = column(rows, "oracle_rms_m"), column(rows, "oracle_error_m")
    return np.where(np.isfinite(mc), mc, same)


def oracle_label(what: str, rows: list[dict], *, where: str = "") -> str:
    """The oracle's legend entry: 'oracle: ``what``', with '(``where``Monte-Carlo RMS over fresh
    noise)' when any row has its Monte-Carlo figure (``oracle_rms_m``), which is then drawn."""
    if np.isfinite(column(rows, "oracle_rms_m")).any():
        return f"oracle: {what} ({where}Monte-Carlo RMS over fresh noise)"
    return f"oracle: {what}"


def judge_bound(rows: list[dict], error_key: str) -> tuple[BoundComparison, float]:
    """The comparison of one cell's ``error_key`` errors with its bounds (``crlb_m``) judged by
    its oracle, and the oracle's RMS as drawn: over the trials the comparison used, else (every
    bound inf or none) over every trial with a finite oracle figure."""
    yard = oracle_yardstick(rows)
    errors = column(rows, error_key)
    cmp = rms_against_bound(errors, column(rows, "crlb_m"), column(rows, "oracle_error_m"), yard)
    return cmp, cmp.rms_oracle if cmp.trials else _rms_finite(yard)


def _drawn_bound(cmp: BoundComparison) -> float:
    """The bound a plot may draw: the RMS bound where attained, inf where not identifiable (a
    mark at the top edge), else NaN (not drawn)."""
    return float("inf") if cmp.regime == "not identifiable" else cmp.lower_bound


def draw_yardsticks(ax, x, cells: list[list[dict]], error_key: str, *, labels, scale: float):
    """The oracle's RMS and the bound at each x (``cells`` of rows, one per x; values times
    ``scale``): the bound where attained (``labels`` = (oracle, bound)), 'not attained' marked at
    the top edge where it is not, 'no oracle' where the rows have none to judge it by, 'bound
    infinite' where not identifiable. Returns whether
    anything was marked at the top edge (the axis then needs headroom)."""
    x = np.asarray(x, dtype=float)
    judged = [judge_bound(c, error_key) for c in cells]
    oracle = np.array([o for _, o in judged]) * scale
    if np.isfinite(oracle).any():
        ax.plot(x, oracle, label=labels[0], zorder=3, **ORACLE_STYLE)
    bound = np.array([_drawn_bound(cmp) for cmp, _ in judged]) * scale
    plot_bound(ax, x, bound, label=labels[1])
    missed = np.array([cmp.regime == "not attained" for cmp, _ in judged])
    mark_not_attained(ax, x[missed])
    unjudged = np.array(
        [cmp.regime == "no bound" and np.isfinite(column(c, "crlb_m")).any()
         for (cmp, _), c in zip(judged, cells, strict=True)]
    )  # fmt: skip
    mark_not_attained(ax, x[unjudged], text="no\noracle", label=NO_ORACLE)
    return bool(missed.any() or unjudged.any() or np.isinf(bound).any())


def plot_fig3(path: str | Path, rows: list[dict]) -> Path:
    """The Fig. 3 analogue: microphone error after alignment against the range noise, every trial
    as a dot, the RMS error over trials as a line, the oracle's RMS (calibrate's own cost
    minimised from the truth: Monte-Carlo ``oracle_rms_m`` where finite, else ``oracle_error_m``)
    as a line, and the RMS of the per-trial CRLBs only at the noise levels where the oracle
    attains it (``rows`` of a ``bench fig3`` run; keys status, sigma [m], mic_error_m, crlb_m,
    oracle_error_m, oracle_rms_m), on log axes labelled at the noise levels used. Trials at
    sigma = 0, which a log axis cannot place, are summed up in the legend (:func:`exact_note`)."""
    ok = [r for r in rows if r["status"] == "ok" and r["sigma"] > 0]
    sigmas = sorted({r["sigma"] for r in ok})
    fig, ax = plt.subplots(figsize=(7.0, 5.6))
    if sigmas:
        x = np.array([r["sigma"] for r in ok]) * 1e3
        jitter = np.exp(np.random.default_rng(0).uniform(-0.06, 0.06, len(x)))
        err = column(ok, "mic_error_m") * 1e3
        ax.scatter(x * jitter, err, s=10, alpha=0.35, c="tab:blue", label="one trial")
        cells = [[r for r in ok if r["sigma"] == s] for s in sigmas]
        rms = [rms_and_bound(column(c, "mic_error_m"), column(c, "crlb_m"))[0] for c in cells]
        s_mm = np.array(sigmas) * 1e3
        ax.plot(s_mm, np.array(rms) * 1e3, "o-", c="tab:blue", ms=7, label="RMS error (calibrate)")
        oracle = oracle_label("calibrate's cost minimised from the truth", ok)
        labels = (oracle, "RMS CRLB, where attained")
        top = draw_yardsticks(ax, s_mm, cells, "mic_error_m", labels=labels, scale=1e3)
        plain_log_axis(ax, "y", headroom=0.2 if top else 0.0)
        plain_log_axis(ax, "x", ticks=s_mm)
    exact = [r for r in rows if r["sigma"] == 0]
    if exact:  # sigma = 0 has no place on a log axis: said in the legend, not dropped
        ax.add_patch(Rectangle((0, 0), 0, 0, fc="none", ec="none", label=exact_note(exact)))
    ax.set_xlabel("range noise sigma [mm]")
    ax.set_ylabel("microphone RMS error after alignment [mm]")
    ax.set_title("Fig. 3: zero-knowledge array calibration\n(RMS over trials)")
    ax.grid(alpha=0.3, which="major")
    legend_below(fig, [ax], ncol=2)
    return save_figure(fig, path, legend_space=True)


def exact_note(rows: list[dict]) -> str:
    """What Fig. 3 says of its trials at sigma = 0 (``rows``), which a log axis cannot show:
    their RMS microphone error and how many converged (or failed)."""
    ok = [r for r in rows if r["status"] == "ok"]
    rms = _rms_finite(column(ok, "mic_error_m")) * 1e3
    converged = sum(bool(r.get("converged", False)) for r in ok)
    failed = f", {len(rows) - len(ok)} failed" if len(ok) < len(rows) else ""
    error = f"RMS error {rms:.2g} mm" if np.isfinite(rms) else "no error to show"
    return (
        f"sigma = 0 (exact ranges; off the log axis): {error}, {converged} of {len(rows)} "
        f"trials converged{failed}"
    )


def ekf_used(row: dict) -> bool:
    """Whether a row's EKF errors are a filter's: it filtered at least one step beyond its
    initialisation window (``ekf_filtered_steps`` > 0). Rows without the count (older CSVs)
    are taken as they are."""
    steps = row.get("ekf_filtered_steps")
    return steps is None or not np.isfinite(float(steps)) or float(steps) > 0


def ekf_label(name: str, rows: list[dict]) -> str:
    """The EKF's legend entry: ``name`` with the batch window it filtered after (M minus the
    filtered steps, when one for every trial that filtered) and the M at which it is left out
    (every trial a batch fit)."""
    counted = [r for r in rows if r.get("ekf_filtered_steps") is not None]
    if not counted:
        return name
    windows = {int(r["m"] - r["ekf_filtered_steps"]) for r in counted if ekf_used(r)}
    window = f"a {windows.pop()}-step" if len(windows) == 1 else "a"
    batch = sorted({int(r["m"]) for r in counted} - {int(r["m"]) for r in counted if ekf_used(r)})
    if not windows and not batch:
        return name
    label = f"{name} (filtered after {window} batch window"
    if batch:
        label += f"; M = {', '.join(map(str, batch))}: a batch fit, not drawn"
    return label + ")"


def plot_fig5(path: str | Path, rows: list[dict], methods: dict[str, str]) -> Path:
    """The Fig. 5 analogue: per noise level (rows of panels) and step-bound setting, a trajectory
    panel and a landmark (image-source) panel against the number of steps M. Trajectory: per
    method the RMS error over trials (markers) and the 25-75% band, the oracle's RMS (the GTSAM
    graph minimised from the truth) and the RMS CRLB with the step prior (``crlb_m``) only where
    the oracle attains it. Landmarks: EDM + GTSAM's RMS error and the oracle's. The EKFs only at
    the M where they filtered (:func:`ekf_used`). One legend below the panels."""
    rows = [r for r in rows if r["status"] == "ok"]
    sigmas = sorted({r["sigma"] for r in rows})
    bounds = sorted({r["bounds"] for r in rows}, reverse=True)
    n_rows, n_cols = max(len(sigmas), 1), 2 * max(len(bounds), 1)
    oracle = oracle_label("GTSAM graph minimised from the truth", rows, where="trajectory: ")
    fig, axs = plt.subplots(n_rows, n_cols, figsize=(4.6 * n_cols, 3.9 * n_rows), squeeze=False)
    for i, sigma in enumerate(sigmas):
        for j, b in enumerate(bounds):
            cell = [r for r in rows if r["sigma"] == sigma and r["bounds"] == b]
            setting = f"sigma = {sigma * 1e3:g} mm, " + ("+-20% step bounds" if b else "no bounds")
            fig5_trajectory_panel(axs[i][2 * j], cell, methods, oracle=oracle)
            axs[i][2 * j].set_title(f"trajectory\n{setting}", fontsize=10)
            fig5_landmark_panel(axs[i][2 * j + 1], cell, oracle=oracle)
            axs[i][2 * j + 1].set_title(f"landmarks (image sources)\n{setting}", fontsize=10)
    fig.suptitle("Fig. 5: range-only SLAM on the lemniscate (RMS over trials, band 25-75%)")
    legend_below(fig, axs, ncol=3)
    return save_figure(fig, path, legend_space=True)


def _curve(ax, steps, per_m: list[np.ndarray], *, k: int, label: str, scale: float) -> None:
    """One method's RMS over the trials at each M (markers, the ``k``-th colour and marker) and
    its 25-75% band; M with no finite error are gaps."""
    colour = plt.rcParams["axes.prop_cycle"].by_key()["color"][k % 10]
    rms = np.array([_rms_finite(v) for v in per_m]) * scale
    q = np.array(
        [np.nanpercentile(v, [25, 75]) if np.isfinite(v).any() else [np.nan] * 2 for v in per_m]
    )
    ax.plot(steps, rms, ls="-", marker=MARKERS[k % len(MARKERS)], c=colour, label=label)
    ax.fill_between(steps, q[:, 0] * scale, q[:, 1] * scale, alpha=0.12, color=colour, lw=0)


def _method_errors(cell: list[dict], key: str, steps) -> list[np.ndarray]:
    """Per M, the method's errors over the trials with a finite bound (all trials where none is
    finite: :func:`rms_and_bound`); an EKF's only in the trials where it filtered."""
    out = []
    for m in steps:
        at = [r for r in cell if r["m"] == m]
        e = np.array(
            [r.get(f"{key}_error_m", np.nan) if key not in EKF_METHODS or ekf_used(r) else np.nan
             for r in at],
            dtype=float,
        )  # fmt: skip
        b = column(at, "crlb_m")
        out.append(e[np.isfinite(b)] if np.isfinite(b).any() else e)
    return out


def _step_axis(ax, steps, ylabel: str, *, headroom: bool) -> None:
    """Integer x ticks at the numbers of steps used, a plain log y axis, labels, grid."""
    if steps:
        plain_log_axis(ax, "y", headroom=0.2 if headroom else 0.0)
        ax.xaxis.set_major_locator(matplotlib.ticker.FixedLocator(steps))
        ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%d"))
        ax.set_xlim(steps[0] - 0.5, steps[-1] + 0.5)
    ax.set_xlabel("number of steps M")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3, which="major")


def fig5_trajectory_panel(ax, cell: list[dict], methods: dict[str, str], *, oracle: str) -> None:
    """One Fig. 5 trajectory panel: the rows of one (sigma, bounds) cell against M, errors in cm:
    each method, the oracle's RMS (labelled ``oracle``), the bound where the oracle attains it."""
    steps = sorted({r["m"] for r in cell})
    for k, (key, name) in enumerate(methods.items()):
        per_m = _method_errors(cell, key, steps)
        if any(np.isfinite(v).any() for v in per_m):
            label = ekf_label(name, cell) if key in EKF_METHODS else name
            _curve(ax, steps, per_m, k=k, label=label, scale=100)
    top = False
    if steps:
        prior = " (ranges + step prior)" if any(r["bounds"] for r in cell) else " (ranges)"
        labels = (oracle, f"RMS CRLB{prior}, where attained")
        cells = [[r for r in cell if r["m"] == m] for m in steps]
        top = draw_yardsticks(ax, steps, cells, "edm_gtsam_error_m", labels=labels, scale=100)
    _step_axis(ax, steps, "trajectory RMS error [cm]", headroom=top)


def fig5_landmark_panel(ax, cell: list[dict], *, oracle: str) -> None:
    """One Fig. 5 landmark panel (the loudspeaker and its image sources): EDM + GTSAM's RMS
    landmark error over trials (and the 25-75% band) and the oracle's (labelled ``oracle``; on
    the trials' own data), in cm, against M."""
    steps = sorted({r["m"] for r in cell})
    per_m = [column([r for r in cell if r["m"] == m], "landmark_error_m") for m in steps]
    if any(np.isfinite(v).any() for v in per_m):
        _curve(ax, steps, per_m, k=1, label="EDM + GTSAM", scale=100)
    best = [column([r for r in cell if r["m"] == m], "oracle_landmark_error_m") for m in steps]
    if any(np.isfinite(v).any() for v in best):
        rms = np.array([_rms_finite(v) for v in best]) * 100
        ax.plot(steps, rms, label=oracle, zorder=3, **ORACLE_STYLE)
    _step_axis(ax, steps, "landmark RMS error [cm]", headroom=False)
