"""Real data: the xtdoa measurements (El Badawy, Larsson, Pollefeys, Dokmanic, "Localizing
unsynchronized sensors with unknown sources", arXiv 2102.03565; MIT licence) in ../shared/data.

12 microphones with measured positions, 65 events, times of arrival with both the microphones'
clock offsets and the emission times unknown. The thresholds are the issue's (16): the authors'
published medians beaten, under the floor of the measured positions (a few centimetres).
"""

import numpy as np
import pytest
from scipy.io import savemat

from rangeslam import DataFormatError, InvalidInputError
from rangeslam.app.xtdoa_bench import (
    PUBLISHED_MEDIAN_CM,
    fit_from_reference,
    reference_sources,
    subset_rows,
    summary_rows,
)
from rangeslam.datasets import xtdoa
from rangeslam.errors import DataNotFoundError


@pytest.fixture(scope="module")
def data():
    """The xtdoa data, as the loader finds it ($RANGESLAM_DATA/xtdoa, else ../shared/data/xtdoa);
    skip, naming the paths tried, when it is absent."""
    try:
        return xtdoa()
    except DataNotFoundError as exc:
        pytest.skip(str(exc))


def test_loader_shapes(data):
    """Points as rows, 12 x 65 arrivals, a boolean mask with the 23 all-clean events."""
    assert data.receivers.shape == (12, 3)
    assert data.arrivals.shape == (12, 65) and data.arrivals.dtype == np.float64
    assert data.clean.dtype == bool and data.clean.shape == (12, 65)
    assert len(data.clean_columns) == 23
    assert not data.arrivals.flags.writeable


def _write(path, **fields):
    savemat(path / "real_data_M12_K65.mat", fields)
    return path


def test_loader_bad_input(tmp_path):
    """A missing path, a missing variable, wrong shapes and a non-binary mask are refused."""
    with pytest.raises(InvalidInputError, match="xtdoa directory"):
        xtdoa(tmp_path / "nowhere")
    t, w, x = np.ones((4, 5)), np.ones((4, 5)), np.zeros((3, 4))
    with pytest.raises(DataFormatError, match="variable 'W' missing"):
        xtdoa(_write(tmp_path, T=t, X_r=x))
    with pytest.raises(DataFormatError, match=r"W must be \(4, 5\)"):
        xtdoa(_write(tmp_path, T=t, W=np.ones((4, 6)), X_r=x))
    with pytest.raises(DataFormatError, match=r"X_r must be \(3, 4\)"):
        xtdoa(_write(tmp_path, T=t, W=w, X_r=x.T))
    with pytest.raises(DataFormatError, match="W must hold only 0 and 1"):
        xtdoa(_write(tmp_path, T=t, W=2 * w, X_r=x))
    (tmp_path / "real_data_M12_K65.mat").write_text("not a MATLAB file")
    with pytest.raises(DataFormatError, match="not a readable MATLAB file"):
        xtdoa(tmp_path)
    ok = xtdoa(_write(tmp_path, T=t, W=w, X_r=x))
    assert ok.receivers.shape == (4, 3)


@pytest.mark.slow
def test_authors_protocol_reduced(data):
    """10 random subsets of K = 8 and of K = 11 clean events (the authors' protocol, each event
    its own offset, microphone offsets unknown). The global search reaches the least-squares fit
    started from the truth (microphone error within 1 mm of it) in at least 9 of 10 subsets of
    each size, its median mean-microphone error (similarity alignment) is within 1 mm of that
    fit's median, and both are under the authors' published medians (13.7 cm at K = 8, 9.6 cm at
    K = 11). The issue's 11 cm and 9 cm are for the 200-subset medians; a 10-subset median
    depends on the draw (the fit from the truth ranges over 7-9.3 cm at K = 11), so
    benchmarks/bench_xtdoa.py checks those."""
    rows = subset_rows(data, [8, 11], 10, seed=2026)
    sources = reference_sources(data)
    summary = {s["K"]: s for s in summary_rows(rows)}
    for k in (8, 11):
        mine = [r for r in rows if r["K"] == k]
        floor = np.array([fit_from_reference(data, _columns(r), sources) for r in mine])
        same = np.abs([r["similarity_error_m"] for r in mine] - floor) < 1e-3
        assert same.sum() >= 9, (k, same)
        median_cm = summary[k]["median_similarity_cm"]
        assert abs(median_cm - 100 * np.median(floor)) <= 0.1, (k, median_cm)
        assert median_cm <= PUBLISHED_MEDIAN_CM[k], (k, median_cm)


def _columns(row: dict) -> np.ndarray:
    return np.array([int(c) for c in row["columns"].split()])


@pytest.mark.slow
def test_robust_run_without_the_mask(data):
    """All 65 events, the authors' mask W not given (issue 16): the robust run drops every event W
    marks wrong at all 12 microphones, keeps at most 10% of W's outlier arrivals, and puts the
    microphones within 10 cm (median over the microphones, similarity alignment as published) of
    the measured positions. A converged verdict must be right; the search may also end without
    two subsets agreeing (NO_AGREEMENT), but not with a wrong answer called converged."""
    from rangeslam.geometry.alignment import align
    from rangeslam.mdu.emission import calibrate_unknown_emission

    seed = 2026
    res = calibrate_unknown_emission(
        data.arrivals, np.arange(data.arrivals.shape[1]), receiver_offsets=True, robust=True,
        rng=seed,
    )  # fmt: skip
    kept = np.asarray(res.inliers)
    whole_bad = ~data.clean.any(axis=0)
    assert not kept[:, whole_bad].any()
    assert np.sum(kept & ~data.clean) <= 0.1 * np.sum(~data.clean)
    errors = align(res.receivers, data.receivers, reflection=True, scale=True).errors
    assert np.median(errors) <= 0.10, (res.status, np.median(errors))
    assert res.status.name in ("CONVERGED", "NO_AGREEMENT"), res.message
