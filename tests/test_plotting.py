"""Every figure of rangeslam.app is written and non-empty on small synthetic inputs, including a
run that did not converge, an infinite bound and an image source far outside the room; the
properties a reviewer checks (verdict in the title, limits set by the room, plain tick labels)
are read back from the figure."""

from __future__ import annotations

from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest

from rangeslam.app import plot_style, plotting
from rangeslam.app.plaza_plot import failed_methods, plot_plaza
from rangeslam.geometry.room import Room

ROOM = Room.shoebox([5.0, 4.0, 3.0])


@pytest.fixture
def rng():
    return np.random.default_rng(15)


def _written(path):
    assert path.exists() and path.stat().st_size > 1000
    return path


def test_log_ticks_are_plain_numbers_at_1_2_5():
    """Ticks 1-2-5 x 10^k inside the range, labelled without powers of ten."""
    ticks = plot_style.log_ticks(1.5, 60.0)
    np.testing.assert_allclose(ticks, [2, 5, 10, 20, 50])
    fig, ax = plt.subplots()
    ax.plot([1, 5, 10], [1.5, 20, 60], "o-")
    plot_style.plain_log_axis(ax, "x", ticks=[1, 5, 10])
    plot_style.plain_log_axis(ax, "y")
    fig.canvas.draw()
    assert [t.get_text() for t in ax.get_xticklabels()] == ["1", "5", "10"]
    assert all(t.get_text().replace(".", "").isdigit() for t in ax.get_yticklabels())
    plt.close(fig)


def _fig3_rows(rng, inf_at=None):
    rows = []
    for s in (0.001, 0.002, 0.005, 0.01):
        for _ in range(4):
            crlb = np.inf if s == inf_at else 0.8 * s
            row = dict(status="ok", sigma=s, mic_error_m=s * rng.uniform(0.5, 2), crlb_m=crlb)
            rows.append(row | dict(oracle_error_m=0.8 * s, oracle_rms_m=np.nan))  # attained
    return rows


def test_fig3_bound_infinite_is_marked_and_ticks_are_the_noise_levels(rng, tmp_path, keep_figure):
    """The finite bound is drawn with markers, the infinite one marked 'bound infinite', the x
    ticks are the noise levels in mm as plain numbers."""
    _written(plotting.plot_fig3(tmp_path / "fig3.png", _fig3_rows(rng, inf_at=0.005)))
    ax = keep_figure[-1].axes[0]
    labels = [t.get_text() for t in ax.get_xticklabels()]
    assert labels == ["1", "2", "5", "10"]
    assert any(t.get_text() == "bound\ninfinite" for t in ax.texts)
    assert all(line.get_marker() not in (None, "None", "") for line in ax.get_lines())
    assert ax.get_legend() is None and keep_figure[-1].legends  # legend outside the axes


def test_fig5_integer_step_axis_and_infinite_bound(rng, tmp_path, keep_figure):
    """Fig. 5 panels: x ticks at the numbers of steps used (integers), every curve marked."""
    rows = []
    for b in (True, False):
        for m in (4, 6, 10):
            for _ in range(3):
                e = rng.uniform(0.01, 0.1)
                rows.append(
                    dict(
                        status="ok",
                        sigma=0.01,
                        bounds=b,
                        m=m,
                        crlb_m=np.inf if m == 4 else 0.02,
                        a_error_m=e,
                        b_error_m=2 * e,
                    )
                )
    _written(plotting.plot_fig5(tmp_path / "fig5.png", rows, {"a": "A", "b": "B"}))
    fig = keep_figure[-1]
    fig.canvas.draw()
    for ax in fig.axes:
        assert [t.get_text() for t in ax.get_xticklabels()] == ["4", "6", "10"]
        assert all(line.get_marker() not in (None, "None", "") for line in ax.get_lines())
        assert ax.get_legend() is None


def test_fig3_draws_rms_error_against_rms_bound(rng, tmp_path, keep_figure):
    """The Fig. 3 curves are the RMS error over trials and the RMS of the per-trial bounds (not
    medians; here attained by the oracle everywhere), read back from the drawn lines."""
    rows = _fig3_rows(rng)
    rows[0]["mic_error_m"] = 0.05  # one bad trial: moves the RMS, not the median
    _written(plotting.plot_fig3(tmp_path / "fig3.png", rows))
    ax = keep_figure[-1].axes[0]
    err = {line.get_label(): line.get_ydata() for line in ax.get_lines()}
    first = [r["mic_error_m"] for r in rows if r["sigma"] == 0.001]
    np.testing.assert_allclose(
        err["RMS error (calibrate)"][0], np.sqrt(np.mean(np.square(first))) * 1e3, rtol=1e-12
    )
    np.testing.assert_allclose(err["RMS CRLB, where attained"], [0.8, 1.6, 4.0, 8.0], rtol=1e-12)


def test_rms_and_bound_leaves_out_unidentifiable_trials():
    """A cell's RMS error and bound are over the trials with a finite bound; with none finite the
    bound is inf (not identifiable) or NaN (no bound) and the error the RMS of all trials."""
    rms, bound = plotting.rms_and_bound([3.0, 4.0, 100.0], [3.0, 4.0, np.inf])
    np.testing.assert_allclose([rms, bound], [np.sqrt(12.5), np.sqrt(12.5)], rtol=1e-15)
    rms, bound = plotting.rms_and_bound([3.0, 4.0], [np.inf, np.inf])
    assert np.isinf(bound) and rms == pytest.approx(np.sqrt(12.5))
    assert np.isnan(plotting.rms_and_bound([0.0], [np.nan])[1])


def test_room_reconstruction_not_converged_far_image_and_sloped_side_view(
    rng, tmp_path, keep_figure
):
    """A failed room: 'not converged' in the title, the limits stay within the room plus a
    margin though an image source is 367 m away; a sloping ceiling along y is shown in y-z."""
    room = Room.from_planes(
        [[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0.3, 1]],
        [[0, 0, 0], [5, 0, 0], [0, 0, 0], [0, 4, 0], [0, 0, 0], [0, 0, 3]],
    )
    mics = rng.uniform([1, 1, 0.5], [4, 3, 1.5], (6, 3))
    far = np.array([[367.0, 2.0, 1.0], [-2.0, 2.0, 1.0]])
    _written(
        plotting.plot_room_reconstruction(
            tmp_path / "room.png",
            true_room=room,
            estimated_room=None,
            mics=mics,
            true_sources=np.array([2.0, 2.0, 1.0]),
            estimated_sources=np.array([2.1, 2.0, 1.0]),
            image_sources=far,
            title="cut",
            converged=False,
        )
    )
    fig = keep_figure[-1]
    assert "not converged" in fig._suptitle.get_text()
    top, side = fig.axes
    assert side.get_xlabel() == "y [m]"
    assert top.get_xlim()[1] < 5 + 0.5 * 5 + 1 and top.get_xlim()[0] > -5
    assert any("beyond the plot" in t.get_text() for t in fig.axes[0].texts)
    assert plot_style.overflow(fig) == []


def test_room_estimate_walls_only_far_image(rng, tmp_path, keep_figure):
    """plot_room_estimate without a bounded room: wall traces, limits set by the true room."""
    mics = rng.uniform(1, 2.5, (5, 3))
    normals = np.vstack([-np.eye(3), np.eye(3)])
    offsets = np.array([0, 0, 0, 5.0, 4.0, 3.0])
    _written(
        plotting.plot_room_estimate(
            tmp_path / "run_room.png",
            wall_normals=normals,
            wall_offsets=offsets,
            mics=mics,
            source=np.array([2.0, 2.0, 1.0]),
            image_sources=np.array([[2.0, 300.0, 1.0]]),
            true_room=ROOM,
            title="room",
            converged=False,
        )
    )
    fig = keep_figure[-1]
    assert "not converged" in fig._suptitle.get_text()
    assert fig.axes[0].get_ylim()[1] < 10


def test_rir_matrix_with_detections_and_keyframes(rng, tmp_path, keep_figure):
    """RIR matrix in dB, no interpolation, detections overlaid, keyframes marked as frames."""
    fs = 8000.0
    rirs = rng.normal(0, 1e-3, (12, 400))
    rirs[:, 40] = 1.0
    rirs[3] = 0.0  # a silent RIR must not break the per-RIR normalisation
    dets = [SimpleNamespace(found=i != 3, times=np.array([40 / fs, 0.03])) for i in range(12)]
    _written(
        plotting.plot_rir_matrix(
            tmp_path / "rir.png", rirs, fs, detections=dets, keyframes=np.arange(0, 12, 3)
        )
    )
    ax = keep_figure[-1].axes[0]
    assert ax.get_xlabel() == "RIR (frame)"
    assert ax.images[0].get_interpolation() == "nearest"
    assert ax.get_ylabel() == "time [ms]"
    labels = [line.get_label() for line in ax.get_lines()]
    assert "detected echoes" in labels and "keyframe (SLAM step)" in labels


def test_walk_estimate_draws_true_landmarks_and_room(rng, tmp_path, keep_figure):
    """The walk plot shows the true landmarks and room; a far estimate is clipped to the edge."""
    traj = rng.uniform(1, 3, (6, 2))
    marks = np.array([[1.0, -1.0], [6.0, 2.0], [500.0, 1.0]])
    _written(
        plotting.plot_walk_estimate(
            tmp_path / "walk.png",
            receivers=traj,
            sources=marks,
            true_trajectory=traj,
            true_landmarks=marks[:2],
            true_room=Room.shoebox([4.0, 3.0]),
            converged=False,
        )
    )
    fig = keep_figure[-1]
    labels = {line.get_label() for ax in fig.axes for line in ax.get_lines()}
    assert {"landmarks (true)", "true room"} <= labels
    assert fig.axes[1].get_xlim()[1] < 20
    assert "not converged" in fig._suptitle.get_text()


def test_slam_estimate_written(rng, tmp_path):
    """plot_slam_estimate with covariances: written."""
    traj = rng.uniform(0, 2, (5, 2))
    marks = rng.uniform(0, 4, (3, 2))
    cov = np.tile(np.eye(2) * 1e-3, (5, 1, 1))
    _written(
        plotting.plot_slam_estimate(
            tmp_path / "slam.png",
            trajectory=traj,
            landmarks=marks,
            receivers=traj,
            sources=marks,
            receiver_cov=cov,
            source_cov=cov[:3],
            rotation=np.eye(2),
            translation=np.zeros(2),
        )
    )


def test_plaza_failed_baseline_in_its_own_panel(rng, tmp_path):
    """A baseline far off (or not converged) is classed failed and kept off the main panel."""
    t = np.linspace(0, 100, 200)
    truth = np.c_[10 * np.cos(t / 20), 10 * np.sin(t / 20)]
    ds = SimpleNamespace(
        name="Synthetic",
        pose_time=t,
        beacons=np.array([[0.0, 0.0], [12.0, 0.0]]),
        truth_at=lambda times: np.c_[10 * np.cos(times / 20), 10 * np.sin(times / 20)],
    )

    def ev(err):
        e = np.full(len(t), err) * rng.uniform(0.5, 1.5, len(t))
        return SimpleNamespace(
            errors=e,
            aligned=truth + err,
            aligned_beacons=ds.beacons + err,
            beacon_errors=np.zeros(2),
        )

    evs = {"good": ev(0.1), "far": ev(300.0), "stopped": ev(0.12)}
    results = {k: SimpleNamespace(pose_time=t, converged=k != "stopped") for k in evs}
    assert failed_methods(results, evs) == {"far", "stopped"}
    _written(plot_plaza(tmp_path / "plaza.png", ds, results, evs))
