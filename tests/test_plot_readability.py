"""Plots a new user could not read (issue 43): Fig. 3 dropped sigma = 0 without a word and its
'not attained' mark looked like a data point; the RIR matrix had a black band nobody explained;
a walk's 2-sigma ellipses were too small to see; a beacon run smeared 600 markers into a band
and left the beacons unnamed. Each fix is read back from the figure."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.lines import Line2D
from matplotlib.patches import Ellipse, Rectangle

from rangeslam.app import plot_style, plotting
from rangeslam.geometry.room import Room


def _legend(fig) -> dict:
    """Legend text -> handle, over the figure's legends."""
    return {
        t.get_text(): h
        for leg in fig.legends
        for t, h in zip(leg.get_texts(), leg.legend_handles, strict=True)
    }


def _fig3_rows(rng) -> list[dict]:
    """Ten trials at sigma = 0 (errors 1e-12 m, one not converged) and at 1 and 5 mm, whose
    oracle misses the bound at 1 mm (0.4x it) and attains it at 5 mm."""
    rows = []
    for s in (0.0, 0.001, 0.005):
        for t in range(10):
            crlb = np.nan if s == 0 else 0.8 * s
            oracle = 0.0 if s == 0 else crlb * (0.4 if s == 0.001 else 1.0)
            rows.append(
                dict(status="ok", sigma=s, trial=t, crlb_m=crlb, oracle_error_m=oracle,
                     oracle_rms_m=oracle, converged=not (s == 0 and t == 0),
                     mic_error_m=1e-12 if s == 0 else oracle * rng.uniform(0.9, 1.1))
            )  # fmt: skip
    return rows


def test_fig3_says_what_it_found_at_sigma_zero(rng, tmp_path, keep_figure):
    """sigma = 0 has no place on the log axis: the legend gives its RMS error and how many of
    its trials converged, and the x ticks stay the noise levels > 0."""
    plotting.plot_fig3(tmp_path / "fig3.png", _fig3_rows(rng))
    fig = keep_figure[-1]
    note = [t for t in _legend(fig) if t.startswith("sigma = 0")]
    assert note == [
        "sigma = 0 (exact ranges; off the log axis): RMS error 1e-09 mm, 9 of 10 trials converged"
    ]
    assert [t.get_text() for t in fig.axes[0].get_xticklabels()] == ["1", "5"]
    assert plot_style.overflow(fig) == []


def test_not_attained_is_a_boxed_note_not_a_point(rng, tmp_path, keep_figure):
    """Where the bound is not attained (1 mm) there is no marker at the top edge: a note in a
    box, and the legend's handle for it is such a box; every line of the axes is data (the
    trials, the RMS, the oracle, the bound)."""
    plotting.plot_fig3(tmp_path / "fig3.png", _fig3_rows(rng))
    fig = keep_figure[-1]
    ax = fig.axes[0]
    (note,) = ax.texts
    assert note.get_text() == "CRLB not\nattained" and note.get_bbox_patch() is not None
    assert note.xy[0] == pytest.approx(1.0)  # over the 1 mm column
    assert plot_style.NOT_ATTAINED not in {ln.get_label() for ln in ax.get_lines()}
    assert all(ln.get_transform() == ax.transData for ln in ax.get_lines())  # none at an edge
    handle = _legend(fig)[plot_style.NOT_ATTAINED]
    assert isinstance(handle, Rectangle) and not isinstance(handle, Line2D)


def test_rir_matrix_greys_the_samples_with_no_signal(tmp_path, keep_figure):
    """A simulated RIR ends after its last reflection: those samples (and those before the
    first non-zero one) are grey and named in the legend; a quiet sample inside the RIR keeps
    the colour map (black at -50 dB)."""
    rirs = np.zeros((3, 100))
    rirs[:, 10] = 1.0
    rirs[:, 40] = 1e-4  # -80 dB: quiet, inside the RIR
    rirs[0, 60] = 0.5  # the first RIR lasts longer
    silent = plotting.no_signal(rirs)
    assert silent[:, :10].all() and not silent[:, 10:41].any()
    assert not silent[0, 10:61].any() and silent[0, 61:].all() and silent[1:, 41:].all()
    plotting.plot_rir_matrix(tmp_path / "m.png", rirs, 1000.0)
    fig = keep_figure[-1]
    image = fig.axes[0].get_images()[0].get_array()
    np.testing.assert_array_equal(np.ma.getmaskarray(image), silent.T)
    handle = _legend(fig)["no signal (before a RIR's first or after its last non-zero sample)"]
    assert handle.get_facecolor()[:3] == pytest.approx((0.8, 0.8, 0.8))


def _walk(n: int):
    """A circle of ``n`` positions in a 5 x 4 m room and three landmarks."""
    t = np.linspace(0, 2 * np.pi, n)
    walk = np.column_stack([2.5 + np.cos(t), 2 + np.sin(t)])
    return walk, np.array([[0.5, 0.5], [4.5, 0.5], [2.5, 3.5]])


@pytest.mark.parametrize(("std", "factor"), [(1e-4, 1000.0), (0.1, 1.0)])
def test_walk_ellipses_are_visible_or_said_to_be_magnified(tmp_path, keep_figure, std, factor):
    """2-sigma ellipses of 0.1 mm in a 5 m room are drawn 1000 x larger, and the title and the
    legend say so; 10 cm ones (20 cm 2-sigma: 2% of the panel or more) are drawn as they are."""
    walk, marks = _walk(15)
    cov = np.tile(np.diag([std**2, (std / 2) ** 2]), (15, 1, 1))
    plotting.plot_walk_estimate(
        tmp_path / "w.png", receivers=walk, sources=marks, receiver_cov=cov,
        source_cov=np.tile(np.eye(2) * std**2, (3, 1, 1)), true_trajectory=walk,
        true_room=Room.shoebox([5.0, 4.0]),
    )  # fmt: skip
    fig = keep_figure[-1]
    ax = fig.axes[0]
    ellipses = [p for p in ax.patches if isinstance(p, Ellipse)]
    assert len(ellipses) == 15
    assert max(e.width for e in ellipses) == pytest.approx(2 * 2 * std * factor)
    lo, hi = ax.get_xlim()
    assert max(e.width for e in ellipses) / 2 >= 0.02 * (hi - lo)
    if factor > 1:
        assert ax.get_title().endswith(", 2-sigma ellipses x1000")
        assert "trajectory: 2-sigma ellipses (GTSAM), drawn 1000 x larger" in _legend(fig)
    else:
        assert ax.get_title().endswith(", 2-sigma ellipses")
        assert "trajectory: 2-sigma ellipses (GTSAM)" in _legend(fig)


def test_a_long_walk_is_a_line_and_named_landmarks_are_named(tmp_path, keep_figure):
    """600 positions (a beacon log): the trajectories are lines without markers; the landmarks
    carry the names given (the beacons' ids); 15 positions keep their markers."""
    walk, marks = _walk(600)
    names = ["beacon 3 (known)", "beacon 7", "beacon 70"]
    plotting.plot_walk_estimate(
        tmp_path / "b.png", receivers=walk, sources=marks, true_trajectory=walk,
        true_landmarks=marks, landmark_names=names,
    )  # fmt: skip
    fig = keep_figure[-1]
    lines = {ln.get_label(): ln for ln in fig.axes[0].get_lines()}
    for label in ("trajectory (true)", "trajectory (est.)"):
        assert lines[label].get_marker() in ("None", "", None)
    assert sorted(t.get_text() for t in fig.axes[1].texts) == sorted(names)
    walk, marks = _walk(15)
    plotting.plot_walk_estimate(tmp_path / "s.png", receivers=walk, sources=marks)
    lines = {ln.get_label(): ln for ln in keep_figure[-1].axes[0].get_lines()}
    assert lines["trajectory (est.)"].get_marker() == "x"
