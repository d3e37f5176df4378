"""What a reader of the Plaza, RIR-matrix and room figures must be able to tell apart, read back
from the figures: every Plaza method visible and distinct, its legend quoting the bench table's
statistic, panel (d) naming why each method is there; used echoes, other detections and the true
arrivals in the RIR matrix; the walls found by a run that did not converge."""

from __future__ import annotations

from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")
import matplotlib.colors as mcolors
import numpy as np
import pytest

from rangeslam.app import plaza_bench, plotting, run_report
from rangeslam.app.plaza_plot import method_labels, off_scale_reasons, plot_plaza
from rangeslam.geometry.room import Room


@pytest.fixture
def rng():
    return np.random.default_rng(36)


def _plaza(rng, errors: dict):
    """A synthetic Plaza data set and one evaluation per method with the given APE scale; the
    methods with equal errors follow exactly the same path."""
    t = np.linspace(0, 100, 200)
    truth = np.c_[10 * np.cos(t / 20), 10 * np.sin(t / 20)]
    ds = SimpleNamespace(
        name="Synthetic",
        pose_time=t,
        beacons=np.array([[0.0, 0.0], [12.0, 0.0]]),
        truth_at=lambda times: np.c_[10 * np.cos(times / 20), 10 * np.sin(times / 20)],
    )
    noise = rng.uniform(0.5, 1.5, len(t))
    evs = {
        name: SimpleNamespace(
            errors=err * noise,
            aligned=truth + err,
            aligned_beacons=ds.beacons + err,
            beacon_errors=np.zeros(2),
        )
        for name, err in errors.items()
    }
    return ds, evs


def _pixels_of(fig, ax, colour) -> int:
    """Pixels of ``ax`` within a small distance of ``colour`` in the drawn figure."""
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(float) / 255
    x0, y0, x1, y1 = ax.bbox.extents
    h = img.shape[0]
    crop = img[int(h - y1) : int(h - y0), int(x0) : int(x1)]
    return int(np.sum(np.linalg.norm(crop - np.array(mcolors.to_rgb(colour)), axis=2) < 0.08))


def test_plaza_methods_on_the_same_path_all_show(rng, tmp_path, keep_figure):
    """Three methods with the same trajectory (edm+gtsam and the random starts converge to one
    answer) each have their own colour, marker and line style, and each colour shows in (a)."""
    ds, evs = _plaza(rng, {"edm+gtsam": 0.1, "edm+isam2": 0.1, "gtsam random beacons": 0.1})
    results = {k: SimpleNamespace(pose_time=ds.pose_time, converged=True) for k in evs}
    plot_plaza(tmp_path / "plaza.png", ds, results, evs)
    fig = keep_figure[-1]
    ax = fig.axes[0]
    lines = [ln for ln in ax.get_lines() if ln.get_label().split(" (")[0] in evs]
    assert len(lines) == 3
    looks = {(ln.get_color(), ln.get_marker(), str(ln.get_linestyle())) for ln in lines}
    assert len({c for c, _, _ in looks}) == 3
    assert len({m for _, m, _ in looks}) == 3
    assert len({s for _, _, s in looks}) == 3
    counts = [_pixels_of(fig, ax, ln.get_color()) for ln in lines]
    assert min(counts) > 0.2 * max(counts), counts


def _bench_row(method: str, trial: int, mean: float) -> dict:
    """A bench row (see plaza_bench._row) with the mean APE ``mean``."""
    return {
        "method": method,
        "trial": trial,
        "status": "ok",
        "mean": mean,
        "median": mean,
        "max": 3 * mean,
        "beacon_max": mean,
        "beacons_placed": 2,
        "beacon_1": mean,
        "beacon_2": mean,
        "range_scale": 1.0,
        "seconds": 1.0,
        "converged": True,
    }


def test_plaza_legend_quotes_the_table_statistic(rng, tmp_path, keep_figure):
    """The legend quotes the mean APE the bench table reports (the median over the trials), not
    the first trial's when that is the worst (19.72 m against 1.08 m on Plaza1)."""
    ds, evs = _plaza(rng, {"edm+gtsam": 0.2, "gtsam example": 19.72})
    rows = [_bench_row("edm+gtsam", 0, float(np.mean(evs["edm+gtsam"].errors)))]
    rows += [_bench_row("gtsam example", k, m) for k, m in enumerate((19.72, 1.08, 0.9))]
    _, table = plaza_bench.methods_table(rows)
    results = {k: SimpleNamespace(pose_time=ds.pose_time, converged=True) for k in evs}
    plot_plaza(tmp_path / "plaza.png", ds, results, evs, rows=rows)
    legend = [t.get_text() for t in keep_figure[-1].legends[0].get_texts()]
    for method, _, mean_cell, *_ in table:
        quoted = mean_cell.split()[0]
        (text,) = [t for t in legend if t.startswith(method + " (")]
        assert text.startswith(f"{method} (mean APE {quoted} m"), (text, mean_cell)
    assert "1.08" in method_labels(evs, rows)["gtsam example"]
    assert "mean APE 19.72" not in method_labels(evs, rows)["gtsam example"]


def test_plaza_panel_d_names_why_each_method_is_there(rng, tmp_path, keep_figure):
    """A converged method far off the best is not called failed: panel (d) says which methods
    did not converge and which converged far off."""
    ds, evs = _plaza(rng, {"good": 0.1, "far": 300.0, "stopped": 0.12})
    results = {k: SimpleNamespace(pose_time=ds.pose_time, converged=k != "stopped") for k in evs}
    assert off_scale_reasons(results, evs) == {
        "far": "converged, far off",
        "stopped": "not converged",
    }
    plot_plaza(tmp_path / "plaza.png", ds, results, evs)
    panel = keep_figure[-1].axes[3]
    assert "failed" not in panel.get_title()
    note = " ".join(t.get_text() for t in panel.texts)
    assert "far: converged, far off" in note and "stopped: not converged" in note
    shown = {ln.get_label().split(" (")[0] for ln in panel.get_lines()}
    assert {"far", "stopped"} <= shown and "good" not in shown


def test_rir_matrix_tells_used_echoes_other_detections_and_truth_apart(rng, tmp_path, keep_figure):
    """Used echoes, the other detections and the true arrivals are three legend entries with
    three markers, each drawn at its own times."""
    fs, m = 8000.0, 6
    rirs = rng.normal(0, 1e-3, (m, 400))
    rirs[:, 40] = 1.0
    times = np.array([40, 120, 250]) / fs
    dets = [SimpleNamespace(found=True, times=times) for _ in range(m)]
    used = np.tile([0, 1, -1], (m, 1))  # the direct path and one echo used; the third not
    truth = np.tile([40 / fs, 121 / fs, np.nan], (m, 1))
    plotting.plot_rir_matrix(
        tmp_path / "rir.png",
        rirs,
        fs,
        detections=dets,
        used=used,
        used_label="echoes labelled",
        true_times=truth,
    )
    ax = keep_figure[-1].axes[0]
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    used_ln = lines["echoes labelled"]
    other = lines["other detections"]
    true_ln = next(ln for label, ln in lines.items() if label.startswith("true arrivals"))
    assert len({used_ln.get_marker(), other.get_marker(), true_ln.get_marker()}) == 3
    np.testing.assert_allclose(sorted(set(used_ln.get_ydata())), [5.0, 15.0])
    np.testing.assert_allclose(sorted(set(other.get_ydata())), [250 / fs * 1e3])
    np.testing.assert_allclose(sorted(set(true_ln.get_ydata())), [5.0, 121 / fs * 1e3])
    legend = [t.get_text() for t in keep_figure[-1].legends[0].get_texts()]
    assert {"echoes labelled", "other detections"} <= set(legend)


def test_true_arrival_times_direct_path_and_first_order_images():
    """Array mode: the true arrival times are the distances from each microphone to the source
    and to its six first-order images in the true shoebox, over the file's speed of sound."""
    size, src = np.array([5.0, 4.0, 3.0]), np.array([1.0, 2.0, 1.5])
    mics = np.array([[2.0, 2.0, 1.5], [4.0, 1.0, 1.0]])
    loaded = SimpleNamespace(
        n_rirs=2, c=340.0, source=src, room_size=size, wall_normals=None, wall_offsets=None
    )
    res = SimpleNamespace(mode="array", c=345.0, mics=mics)
    t = run_report.true_arrival_times(loaded, res)
    assert t.shape == (2, 7)
    np.testing.assert_allclose(t[0, 0], 1.0 / 340.0)
    # the image in the wall x = 0 is at (-1, 2, 1.5): 3 m from the first microphone
    assert np.any(np.isclose(t[0, 1:], 3.0 / 340.0))
    walk = SimpleNamespace(
        n_rirs=4,
        c=None,
        trajectory=np.array([[0.0, 0.0], [3.0, 4.0]]),
        keyframes=np.array([0, 3]),
        landmarks=np.array([[0.0, 0.0], [3.0, 0.0]]),
    )
    tw = run_report.true_arrival_times(walk, SimpleNamespace(mode="walk", c=300.0))
    np.testing.assert_allclose(tw[[0, 3]], [[0.0, 0.01], [5 / 300, 4 / 300]])
    assert np.isnan(tw[[1, 2]]).all()


def test_room_plot_of_a_run_that_did_not_converge_draws_the_walls_found(rng, tmp_path, keep_figure):
    """A labelling that found some image sources but did not converge (no room): the room plot
    draws those walls, named as found in a run that did not converge."""
    room = Room.shoebox([5.0, 4.0, 3.0])
    src = np.array([1.0, 2.0, 1.5])
    images = room.image_sources(src).positions[:4]  # 4 of the 6 walls found
    normals, offsets, _ = run_report.labelled_walls(src, np.vstack([images, np.full(3, np.nan)]))
    np.testing.assert_allclose(normals, room.normals[:4], atol=1e-12)
    np.testing.assert_allclose(offsets, room.offsets[:4], atol=1e-12)
    mics = rng.uniform(1, 3, (6, 3))
    fs = 8000.0
    dets = [SimpleNamespace(found=True, times=np.array([0.002, 0.004])) for _ in range(6)]
    res = SimpleNamespace(
        mode="array",
        converged=False,
        c=343.0,
        mics=mics,
        source=src,
        image_sources=None,
        wall_normals=None,
        wall_offsets=None,
        detections=dets,
        result=SimpleNamespace(
            reconstruction=None,
            labelling=SimpleNamespace(images=images, peaks=np.tile([0, -1], (6, 1))),
        ),
    )
    loaded = SimpleNamespace(
        fs=fs,
        rirs=rng.normal(0, 1e-3, (6, 200)),
        n_rirs=6,
        keyframes=None,
        c=343.0,
        source=src,
        room_size=np.array([5.0, 4.0, 3.0]),
        wall_normals=None,
        wall_offsets=None,
    )
    args = SimpleNamespace(out=tmp_path)
    written = run_report.run_plots(args, loaded, res)
    assert [p.name for p in written] == ["run_rir_matrix.png", "run_room.png"]
    fig = keep_figure[-1]
    walls = {ln.get_label() for ax in fig.axes for ln in ax.get_lines()}
    found = {w for w in walls if w.startswith("wall ")}
    assert found == {f"wall {k} (found; run not converged)" for k in range(4)}
    assert "not converged" in fig._suptitle.get_text()


def test_plaza_bench_keeps_the_median_trial_for_the_plot(monkeypatch):
    """The trial kept for the plot (and TUM files) is the one the table's median stands for,
    not the first (on Plaza1 the first gtsam example trial was the worst: 19.72 m)."""
    means = {0: 19.72, 1: 1.08, 2: 0.9}
    ds = SimpleNamespace(beacon_ids=np.array([1, 2]))

    def run(method, dataset, rng, n_poses=None):
        trial = run.trial
        run.trial += 1
        return SimpleNamespace(
            trial=trial,
            pose_time=np.array([0.0, 1.0]),
            range_scale=None,
            range_bias=None,
            seconds=1.0,
            converged=True,
            message="",
        )

    run.trial = 0
    monkeypatch.setattr(plaza_bench, "run_method", run)
    monkeypatch.setattr(
        plaza_bench,
        "evaluate",
        lambda res, dataset: SimpleNamespace(
            errors=np.full(2, means[res.trial]), beacon_errors=np.zeros(2)
        ),
    )
    kept = {}
    rows = plaza_bench.method_rows(ds, trials=3, seed=0, methods=("gtsam example",), keep=kept)
    assert [r["mean"] for r in rows] == pytest.approx([19.72, 1.08, 0.9])
    assert kept["gtsam example"].trial == 1
