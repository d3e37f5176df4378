"""The benchmark figures (Fig. 3, Fig. 5, compare) draw the two yardsticks as they are: the
oracle's RMS as its own line, the Cramer-Rao bound only where the oracle attains it (elsewhere
'bound not attained: oracle only'), the landmark panels beside the trajectory ones, the EKF only
where it filtered, and nothing cut off. Each property is read back from the figure."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest

from rangeslam.app import bench_plot, plot_style, plotting

#: The demo's compare run: one noise level, bounds, three M, every method (long legend).
COMPARE = {
    "edm": "EDM only",
    "edm_gtsam": "EDM + GTSAM",
    "gtsam": "GTSAM without EDM",
    "ekf": "EKF",
    "ekf_rts": "EKF + RTS",
}


def _slam_rows(rng, *, sigmas=(0.01,), bounds=(True,), steps=(5, 10, 20), trials=4, **kw):
    """Synthetic Fig. 5 rows: the bound 3 sigma / sqrt(M); the oracle attains it (within 3%)
    except at the M in ``missed`` (0.3x the bound: not attained); ``filtered`` the EKF's
    ``ekf_filtered_steps`` as a function of M (None: the key left out, an older CSV);
    ``oracle`` False leaves the oracle columns out."""
    missed, filtered, oracle = kw.get("missed", (5,)), kw.get("filtered"), kw.get("oracle", True)
    rows = []
    for s in sigmas:
        for b in bounds:
            for m in steps:
                for t in range(trials):
                    crlb = 3 * s / np.sqrt(m)
                    o = crlb * (0.3 if m in missed else rng.uniform(0.97, 1.03))
                    row = dict(status="ok", sigma=s, bounds=b, m=m, trial=t, crlb_m=crlb)
                    for k, key in enumerate(COMPARE):
                        row[f"{key}_error_m"] = o * (1 + 0.5 * k) * rng.uniform(1.0, 1.1)
                    row["landmark_error_m"] = 100 * s * rng.uniform(0.5, 1.5)
                    if oracle:
                        row["oracle_error_m"] = o
                        row["oracle_rms_m"] = o if t % 2 else np.nan
                        row["oracle_landmark_error_m"] = 0.8 * row["landmark_error_m"]
                    if filtered is not None:
                        row["ekf_filtered_steps"] = filtered(m)
                    rows.append(row)
    return rows


def _lines(ax) -> dict:
    return {line.get_label(): line for line in ax.get_lines()}


def _oracle(ax):
    """The oracle's line of a panel (its label starts 'oracle:')."""
    (line,) = [v for k, v in _lines(ax).items() if k.startswith("oracle:")]
    return line


def _legend_texts(fig) -> list[str]:
    return [t.get_text() for leg in fig.legends for t in leg.get_texts()]


def _rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def test_fig5_has_a_landmark_panel_beside_each_trajectory_panel(rng, tmp_path, keep_figure):
    """Two noise levels x two bound settings: 8 panels, trajectory and landmarks alternating;
    the landmark panel draws EDM + GTSAM's RMS landmark error and the oracle's, in cm."""
    rows = _slam_rows(rng, sigmas=(0.001, 0.01), bounds=(True, False))
    plotting.plot_fig5(tmp_path / "fig5.png", rows, COMPARE)
    axes = keep_figure[-1].axes
    assert len(axes) == 8
    assert [ax.get_title().split("\n")[0] for ax in axes[:2]] == [
        "trajectory",
        "landmarks (image sources)",
    ]
    land = _lines(axes[1])
    at_5 = [r for r in rows if r["sigma"] == 0.001 and r["bounds"] and r["m"] == 5]
    edm_gtsam = land["EDM + GTSAM"].get_ydata()[0]
    assert edm_gtsam == pytest.approx(_rms([r["landmark_error_m"] for r in at_5]) * 100)
    oracle = _oracle(axes[1]).get_ydata()[0]
    assert oracle == pytest.approx(0.8 * edm_gtsam)
    assert axes[1].get_ylabel() == "landmark RMS error [cm]"


def test_fig5_bound_drawn_only_where_the_oracle_attains_it(rng, tmp_path, keep_figure):
    """At M = 5 the oracle is 0.3x the bound: no bound point there, a 'not attained' mark and the
    legend entry 'bound not attained: oracle only'; at M = 10, 20 the bound is drawn and labelled
    'where attained'. The oracle's line is the RMS of oracle_rms_m where finite, else
    oracle_error_m. Nowhere the word 'beats'."""
    rows = _slam_rows(rng)
    plotting.plot_fig5(tmp_path / "fig5.png", rows, COMPARE)
    fig = keep_figure[-1]
    lines = _lines(fig.axes[0])
    bound = lines["RMS CRLB (ranges + step prior), where attained"].get_ydata()
    assert np.isnan(bound[0]) and np.all(np.isfinite(bound[1:]))
    np.testing.assert_allclose(bound[1:], [300 * 0.01 / np.sqrt(m) for m in (10, 20)])
    assert [t.get_text() for t in fig.axes[0].texts] == ["CRLB not\nattained"]
    assert plot_style.NOT_ATTAINED in _legend_texts(fig)
    at_10 = [r for r in rows if r["m"] == 10]
    yard = [
        r["oracle_rms_m"] if np.isfinite(r["oracle_rms_m"]) else r["oracle_error_m"] for r in at_10
    ]
    assert "Monte-Carlo RMS" in _oracle(fig.axes[0]).get_label()
    oracle = _oracle(fig.axes[0]).get_ydata()
    assert oracle[1] == pytest.approx(_rms(yard) * 100)
    texts = _legend_texts(fig) + [t.get_text() for ax in fig.axes for t in ax.texts]
    assert not any("beat" in t.lower() for t in [*texts, fig.get_suptitle()])


def test_fig5_without_an_oracle_draws_no_bound_and_says_so(rng, tmp_path, keep_figure):
    """Rows of an older CSV (no oracle columns): the bound is not judged, so not drawn, and the
    legend says why; the methods are drawn as before."""
    plotting.plot_fig5(tmp_path / "fig5.png", _slam_rows(rng, oracle=False), COMPARE)
    fig = keep_figure[-1]
    labels = set(_lines(fig.axes[0]))
    assert not any("CRLB" in label for label in labels)
    assert bench_plot.NO_ORACLE in _legend_texts(fig)
    assert "EDM + GTSAM" in labels


def test_fig5_ekf_left_out_where_its_window_covers_every_step(rng, tmp_path, keep_figure):
    """ekf_filtered_steps = M - 5: at M = 5 the EKF is a batch fit, not drawn (NaN), at M = 10
    and 20 drawn; its legend entry names the 5-step batch window. Rows without the count (an
    older CSV) draw the EKF everywhere under its plain name."""
    rows = _slam_rows(rng, filtered=lambda m: max(m - 5, 0))
    plotting.plot_fig5(tmp_path / "fig5.png", rows, COMPARE)
    ekf = [
        v for k, v in _lines(keep_figure[-1].axes[0]).items() if k.startswith("EKF") and "(" in k
    ]
    assert len(ekf) == 2  # the EKF and its RTS smoothing
    for line in ekf:
        assert "filtered after a 5-step batch window" in line.get_label()
        assert "M = 5" in line.get_label()
        y = line.get_ydata()
        assert np.isnan(y[0]) and np.all(np.isfinite(y[1:]))
    plotting.plot_fig5(tmp_path / "old.png", _slam_rows(rng), COMPARE)
    old = _lines(keep_figure[-1].axes[0])
    assert np.all(np.isfinite(old["EKF"].get_ydata()))


def test_ekf_left_out_entirely_when_it_never_filtered(rng, tmp_path, keep_figure):
    """Every M within the window (ekf_filtered_steps 0 throughout): no EKF curve at all."""
    rows = _slam_rows(rng, steps=(4, 5), filtered=lambda m: 0)
    plotting.plot_fig5(tmp_path / "fig5.png", rows, COMPARE)
    assert not any(k.startswith("EKF") for k in _lines(keep_figure[-1].axes[0]))


@pytest.mark.parametrize("grid", [((0.01,), (True,)), ((0.001, 0.01), (True, False))])
def test_fig5_fits_its_figure(rng, tmp_path, keep_figure, grid):
    """The demo's compare (one panel pair, every method, long EKF labels) and the full grid:
    no title, label or legend entry reaches beyond the canvas."""
    rows = _slam_rows(rng, sigmas=grid[0], bounds=grid[1], filtered=lambda m: max(m - 5, 0))
    plotting.plot_fig5(tmp_path / "compare.png", rows, COMPARE)
    assert plot_style.overflow(keep_figure[-1]) == []


def test_overflow_finds_a_title_wider_than_the_figure():
    """The check the fit tests rely on: a suptitle wider than a small figure is reported."""
    fig, _ax = plt.subplots(figsize=(3, 3))
    fig.suptitle("a title far too long for a figure three inches wide, so it is cut off")
    assert plot_style.overflow(fig) == [fig.get_suptitle()]
    plt.close(fig)


def _calibration_rows(rng, *, attained_up_to=0.005):
    rows = []
    for s in (0.001, 0.005, 0.01):
        for t in range(6):
            crlb = 0.8 * s
            o = crlb * (rng.uniform(0.97, 1.03) if s <= attained_up_to else 0.4)
            rows.append(
                dict(
                    status="ok",
                    sigma=s,
                    mic_error_m=o * rng.uniform(1.0, 1.2),
                    crlb_m=crlb,
                    oracle_error_m=o,
                    oracle_rms_m=o if t % 3 else np.nan,
                )
            )
    return rows


def test_fig3_oracle_line_and_bound_only_where_attained(rng, tmp_path, keep_figure):
    """Fig. 3: the oracle's RMS is a line at every noise level; the bound is drawn at 1 and 5 mm
    (attained) and not at 10 mm (oracle 0.4x the bound), which is marked 'not attained'."""
    rows = _calibration_rows(rng)
    plotting.plot_fig3(tmp_path / "fig3.png", rows)
    fig = keep_figure[-1]
    ax = fig.axes[0]
    lines = _lines(ax)
    bound = lines["RMS CRLB, where attained"].get_ydata()
    np.testing.assert_allclose(bound[:2], [0.8, 4.0], rtol=1e-12)
    assert np.isnan(bound[2])
    oracle = _oracle(ax).get_ydata()
    at_10 = [r for r in rows if r["sigma"] == 0.01]
    yard = [
        r["oracle_rms_m"] if np.isfinite(r["oracle_rms_m"]) else r["oracle_error_m"] for r in at_10
    ]
    assert oracle[2] == pytest.approx(_rms(yard) * 1e3)
    assert [t.get_text() for t in ax.texts] == ["CRLB not\nattained"]
    assert plot_style.overflow(fig) == []
