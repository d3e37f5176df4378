"""Real data: the dEchorate subset (Di Carlo et al., EURASIP JASMP 2021) in ../shared/data.

Thresholds are measured against the dataset's calibrated geometry, which the authors calibrated
from these same echoes (a self-consistent reference at the centimetre level).
"""

import shutil

import numpy as np
import pytest

from rangeslam import DataFormatError, align, calibrate, reconstruct_room
from rangeslam.app.experiments import wall_errors
from rangeslam.datasets import load_dechorate
from rangeslam.sim.echo_picks import simulate_loudspeakers
from rangeslam.status import Status


@pytest.fixture
def data(dechorate_dir):
    return load_dechorate(dechorate_dir)


def test_loader_shapes_and_units(data):
    """30 microphones, 2 loudspeakers, 7 echo columns; ranges are toa * c, in metres."""
    assert data.mics.shape == (30, 3) and data.sources.shape == (2, 3)
    assert data.toa.shape == (2, 30, 7)
    np.testing.assert_allclose(data.ranges(0), data.toa[0] * 345.844)
    assert data.pick_resolution == pytest.approx(345.844 / 48000)
    assert data.room.n_walls == 6 and data.room.contains(data.mics).all()
    # the direct path is the shortest arrival for every microphone and loudspeaker
    assert np.all(data.toa[:, :, :1] < data.toa[:, :, 1:])


def test_calibrated_geometry_explains_the_direct_paths(data):
    """Loudspeaker 0's direct-path ranges agree with the calibrated positions to about a centimetre
    (median |error| < 1 cm); loudspeaker 1's are off by more (its calibrated height, see README)."""
    for j, limit in ((0, 0.01), (1, 0.02)):
        pred = np.linalg.norm(data.mics - data.sources[j], axis=1)
        assert np.median(np.abs(data.ranges(j)[:, 0] - pred)) < limit


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_both_loudspeakers_reconstruct_the_room(data, seed):
    """Measured echoes of both loudspeakers, walls estimated jointly, wrong picks handled by the
    method: loudspeaker 0 within 3 cm of its calibrated position, at least 4 of the 6 walls within
    5 cm and all 6 within 15 cm, both as plane offset at the wall's centroid and as the literal
    offset in the dataset's frame (measured: 5 walls within 5 cm either way, worst 6.2 cm and
    11.3 cm). Three seeds of the random subset search, as the result must not hinge on one."""
    res = reconstruct_room(data.mics, [data.ranges(0), data.ranges(1)], rng=seed)
    assert res.converged, res.message
    assert np.linalg.norm(res.sources[0] - data.sources[0]) <= 0.03
    off, _ = wall_errors(data.room, res.wall_normals, res.wall_offsets)
    assert np.sum(off <= 0.05) >= 4, off
    assert off.max() <= 0.15, off
    # The same in the literal sense, |o_est - o_true| with the dataset's corner as origin.
    literal = np.abs(res.wall_offsets - data.room.offsets)
    assert np.sum(literal <= 0.05) >= 4 and literal.max() <= 0.15, literal
    assert res.n_outliers > 0  # the wrong picks were found, not fitted


def test_fixed_threshold_of_three_samples(data):
    """With an inlier threshold of three samples (3 c / fs = 2.2 cm) the joint result meets the same
    thresholds."""
    res = reconstruct_room(
        data.mics,
        [data.ranges(0), data.ranges(1)],
        inlier_threshold=3 * data.pick_resolution,
        rng=0,
    )
    assert res.converged, res.message
    assert np.linalg.norm(res.sources[0] - data.sources[0]) <= 0.03
    off, _ = wall_errors(data.room, res.wall_normals, res.wall_offsets)
    assert np.sum(off <= 0.05) >= 4 and off.max() <= 0.15, off


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_single_loudspeakers_locate_themselves(data, seed):
    """Alone, each loudspeaker is located (0: within 3 cm; 1: within 8 cm, its calibrated height being
    about 5 cm off its own ranges). Loudspeaker 1's north echoes are all mis-picked, so alone it
    cannot verify the north wall (wall 3); loudspeaker 0's echoes off wall 0 left out by the fit
    place that wall 17 cm away with as many ranges within the threshold (17 of 30 against the
    answer's 18). Each result either converges or names one of those walls, as a rival or as the
    better place (the judge, rangeslam.localization.room_judge); never another failure. Measured
    over seeds 0-5: loudspeaker 0 converged 3 times, wall 0 named 3 times; loudspeaker 1
    converged 4 times, wall 3 named twice."""
    for j, limit, wall in ((0, 0.03, "wall 0:"), (1, 0.08, "wall 3:")):
        res = reconstruct_room(data.mics, data.ranges(j), rng=seed)
        assert np.linalg.norm(res.sources[0] - data.sources[j]) <= limit
        if not res.converged:
            assert res.status in (Status.OUTLIERS, Status.NOT_IDENTIFIABLE), res.message
            assert res.message.startswith(wall), res.message


@pytest.mark.slow
def test_zero_knowledge_calibration_of_the_30_microphones(data, rng):
    """Issue 3: the 30 microphones and the 14 virtual sources of loudspeakers 0 and 1 (direct path
    and six echoes each), all unknown to the solver. The measured picks include whole arrays
    hearing a wrong echo (up to 59 cm off), so the robust mode is used, with the 1 cm noise level
    the calibrated positions themselves carry. Issue 17: converged means right (median
    microphone error <= 3 cm after rigid alignment, none worse than 10 cm, under a quarter of the
    ranges dropped); an answer no second start reached is NO_AGREEMENT, and one that drops half
    of a microphone's ranges OUTLIERS (two of four starts once reached one 37 cm off). Measured
    with 4 runs: 4-6 in 10 starts reach the right minimum (1.1-3.5 cm), the wrong ones 6-80 cm;
    before the agreement rule, 5 of 15 draws converged 10-38 cm off. Issue 42: the judge may
    find a rival minimum within the cost level (NOT_IDENTIFIABLE, the rival named)."""
    ranges = np.hstack([data.ranges(0), data.ranges(1)])
    for _ in range(3):
        out = calibrate(ranges, noise_std=0.01, robust=True, max_attempts=4, max_iterations=3,
                        rng=rng)  # fmt: skip
        errors = align(out.receivers, data.mics, reflection=True).errors
        if not out.converged:
            not_right = (Status.NO_AGREEMENT, Status.OUTLIERS, Status.NOT_IDENTIFIABLE)
            assert out.status in not_right, out.message
            continue
        assert np.median(errors) <= 0.03 and errors.max() <= 0.10, out.message
        assert 0 < out.n_outliers < 0.25 * ranges.size


@pytest.mark.slow
def test_calibrate_defaults_on_a_held_out_simulated_pair_of_loudspeakers(data):
    """Held out: two new loudspeakers in the dEchorate room, their picks drawn from the error
    kinds of the real ones (rangeslam.sim.echo_picks: array-correlated phantoms, biases, gross
    errors), calibrate with defaults: right (median <= 3 cm, none over 10 cm) or not converged.
    A frozen scene that once failed (scene seed 16): CONVERGED with the microphones 25 cm off,
    ranked first by a Cauchy scale (27 cm) taken from the unrefined SDP fit, while another start
    fitted its kept ranges to 2 cm."""
    picks = simulate_loudspeakers(data.mics, data.mic_array, data.room_size, 2, 16)
    out = calibrate(picks.ranges, dim=3, rng=16)
    errors = align(out.receivers, data.mics, reflection=True).errors
    assert not out.converged or (np.median(errors) <= 0.03 and errors.max() <= 0.10), out.message


def _copy(src, dst):
    shutil.copytree(src, dst)
    return dst


def test_loader_refuses_broken_files(dechorate_dir, tmp_path):
    """Missing files, a wrong header, short rows, bad numbers, duplicate and missing rows: each gives
    an error naming the file and the row."""
    with pytest.raises(FileNotFoundError, match=r"positions\.json"):
        load_dechorate(tmp_path)
    d = _copy(dechorate_dir, tmp_path / "a")
    csv = d / "echo_toa.csv"
    lines = csv.read_text().splitlines()

    def write(new_lines):
        csv.write_text("\n".join(new_lines) + "\n")

    write([lines[0].replace("toa_direct_s", "toa_d"), *lines[1:]])
    with pytest.raises(DataFormatError, match="header"):
        load_dechorate(d)
    write([lines[0], lines[1].rsplit(",", 1)[0], *lines[2:]])
    with pytest.raises(DataFormatError, match="row 2: expected 9 fields"):
        load_dechorate(d)
    write([lines[0], lines[1].replace("3.910888388e-03", "abc"), *lines[2:]])
    with pytest.raises(DataFormatError, match="row 2"):
        load_dechorate(d)
    write([lines[0], lines[1].replace("3.910888388e-03", "-1"), *lines[2:]])
    with pytest.raises(DataFormatError, match="row 2: times of arrival must be positive"):
        load_dechorate(d)
    write([*lines, lines[1]])
    with pytest.raises(DataFormatError, match="duplicate row for mic 0, src 0"):
        load_dechorate(d)
    write(lines[:-1])
    with pytest.raises(DataFormatError, match="no row for mic 29, src 1"):
        load_dechorate(d)
    write([lines[0], "99,0" + lines[1][3:], *lines[2:]])
    with pytest.raises(DataFormatError, match="out of range"):
        load_dechorate(d)
    write(lines)
    (d / "positions.json").write_text("{not json")
    with pytest.raises(DataFormatError, match="not valid JSON"):
        load_dechorate(d)
