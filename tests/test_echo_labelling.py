"""Echo labelling (label_echoes, room_from_rirs): simulated rooms, masks, failure modes, dEchorate."""

import numpy as np
import pytest

from rangeslam import DegenerateGeometryError, InvalidInputError, Room
from rangeslam.acoustics.echoes import EchoDetection, detect_echoes_many
from rangeslam.acoustics.labelling import EchoLabelling, label_echoes, room_from_rirs
from rangeslam.datasets.dechorate import load_dechorate_rirs
from rangeslam.sim.rir import shoebox_rirs
from rangeslam.status import Status

C = 343.0  # pyroomacoustics' speed of sound


def random_setup(rng, compact):
    """A random shoebox, source and 8-12 microphones (in a 0.5 m cube, or spread in the room)."""
    size = np.array([rng.uniform(3, 10), rng.uniform(3, 8), rng.uniform(2.4, 4)])
    src = rng.uniform(0.3, size - 0.3)
    m = int(rng.integers(8, 13))
    if compact:
        mics = rng.uniform(0.6, size - 0.6) + rng.uniform(-0.25, 0.25, (m, 3))
    else:
        mics = rng.uniform(0.3, size - 0.3, (m, 3))
    return size, src, mics, rng.uniform(0.1, 0.3)


def present_peaks(det, size, src, mics, fs):
    """(M, 7) index of the detected peak of the direct path (column 0) and of each first-order echo
    (column 1 + wall, Room.shoebox order) where it is present: detected within one sample, with no
    other arrival (image source up to order 3) within one sample; -1 elsewhere."""
    ims = Room.shoebox(size).image_sources(src, 3)
    _, first = np.unique(np.round(ims.positions, 9), axis=0, return_index=True)
    keep = np.sort(first[ims.valid[first]])
    every = np.vstack([src[None], ims.positions[keep]])
    t1 = np.linalg.norm(np.vstack([src[None], ims.positions[:6]])[None] - mics[:, None], axis=2)
    ta = np.linalg.norm(every[None] - mics[:, None], axis=2)
    t1, ta = t1 / C * fs, ta / C * fs
    out = np.full((len(mics), 7), -1)
    for m, d in enumerate(det):
        if not d.found:
            continue
        for k in range(7):
            if np.sort(np.abs(ta[m] - t1[m, k]))[1] <= 1:
                continue  # merged with another arrival: not one image source's echo
            i = int(np.argmin(np.abs(d.samples - t1[m, k])))
            if abs(d.samples[i] - t1[m, k]) <= 1:
                out[m, k] = i
    return out


def score(lab, truth):
    """(present, correctly labelled) direct paths and first-order echoes. Each echo column is the
    image source whose present peaks it holds most often; an echo is labelled correctly when its
    image source's column holds its peak."""
    cols = [0]
    for j in range(1, lab.peaks.shape[1]):
        votes = [np.sum((lab.peaks[:, j] == truth[:, k]) & (truth[:, k] >= 0)) for k in range(7)]
        votes[0] = 0
        cols.append(int(np.argmax(votes)) if max(votes) > 0 else -1)
    correct = 0
    for k in range(7):
        if k in cols:
            j = cols.index(k)
            correct += int(np.sum((lab.peaks[:, j] == truth[:, k]) & (truth[:, k] >= 0)))
    return int((truth >= 0).sum()), correct


def wall_errors(rec, size):
    """(6,) distance, metres, from the centre of each true wall of the shoebox (the room's centre
    projected onto it) to the estimated wall with the nearest normal; inf if none is within 25
    degrees."""
    room = Room.shoebox(size)
    centre = np.asarray(size) / 2
    out = []
    for n_true, o_true in zip(room.normals, room.offsets, strict=True):
        p = centre + (o_true - n_true @ centre) * n_true
        cos = rec.wall_normals @ n_true
        j = int(np.argmax(cos))
        ok = cos[j] > np.cos(np.radians(25))
        out.append(abs(rec.wall_normals[j] @ p - rec.wall_offsets[j]) if ok else np.inf)
    return np.array(out)


def geometric_detections(mics, points, fs, extra=None):
    """EchoDetections with arrivals exactly at the distances from ``points`` (P, 3) (direct path
    first) to each microphone, plus ``extra[m]`` (distances) for microphone m."""
    dets = []
    for m, mic in enumerate(mics):
        r = np.linalg.norm(points - mic, axis=1)
        direct = r[0]
        if extra is not None:
            r = np.concatenate([r, extra[m]])
        r = np.unique(r)  # sorted; coincident image sources arrive as one peak
        i = int(np.searchsorted(r, direct))
        amps = np.where(np.arange(len(r)) == i, 1.0, 0.3)
        dets.append(detection(r / C, amps, i, fs))
    return dets


def detection(times, amps, direct, fs):
    return EchoDetection(
        times=times, amplitudes=amps, direct=direct, noise_level=0.0, threshold=0.01, fs=fs
    )


# ---- simulated rooms ------------------------------------------------------------------------------


# Measured with this test's setup over 30 rooms per case (seeds 1 and 7; reflection order 3, about
# 50 detected peaks per microphone): 16 kHz compact 97.0% and 98.5%, spread 98.6% and 98.7%;
# 48 kHz compact 99.8% and 99.9%, spread 99.75% and 99.65%. This test passed for seeds 1-30.
# Misses come in whole columns (a first-order image too few microphones hear cleanly), so a few
# rooms pooled over both rates keep the 95% bound away from the noise of one bad room.
@pytest.mark.slow
def test_labels_direct_paths_and_first_order_echoes_in_simulated_rooms(rng):
    present = correct = 0
    for fs, compact in [(16000, True), (16000, False), (48000, True), (48000, False)] * 2:
        size, src, mics, absorption = random_setup(rng, compact)
        rirs = shoebox_rirs(size, src, mics, fs=fs, absorption=absorption, max_order=3)
        det = detect_echoes_many(rirs, fs)
        lab = label_echoes(det, mics, c=C, rng=rng)
        assert isinstance(lab, EchoLabelling)
        assert lab.ranges.shape == lab.mask.shape == lab.peaks.shape
        assert lab.ranges.shape[0] == len(mics)
        assert np.linalg.norm(lab.source - src) < 0.01
        p, ok = score(lab, present_peaks(det, size, src, mics, fs))
        present += p
        correct += ok
    assert correct / present >= 0.95, f"{correct} of {present} labelled correctly"


def test_bookkeeping_of_ranges_masks_and_peaks(rng):
    size, src, mics, absorption = random_setup(rng, compact=True)
    rirs = shoebox_rirs(size, src, mics, fs=48000, absorption=absorption, max_order=3)
    det = detect_echoes_many(rirs, 48000)
    lab = label_echoes(det, mics, c=C, rng=rng)
    assert lab.converged, lab.message
    assert not lab.ranges.flags.writeable and not lab.mask.flags.writeable
    # masked entries are NaN (never 0) with peak -1; observed ones are the picked peak's range
    assert np.all(np.isnan(lab.ranges[~lab.mask])) and np.all(lab.peaks[~lab.mask] == -1)
    for m, k in zip(*np.nonzero(lab.mask), strict=True):
        assert lab.ranges[m, k] == pytest.approx(det[m].times[lab.peaks[m, k]] * C)
        assert abs(lab.residuals[m, k]) <= lab.tolerance
    # one peak, one point; every peak is assigned, higher-order or unassigned
    for m in range(len(mics)):
        used = lab.peaks[m][lab.peaks[m] >= 0]
        assert len(set(used.tolist())) == len(used)
    assert np.array_equal(
        lab.mask.sum(axis=1) + lab.n_higher_order + lab.n_unassigned, [len(d) for d in det]
    )
    assert np.array_equal(lab.support, lab.mask.sum(axis=0))
    # columns nearest the source first; each image lies beyond every microphone's direct path
    dist = np.linalg.norm(lab.images - lab.source, axis=1)
    assert np.all(np.diff(dist) > 0)
    d_src = np.linalg.norm(mics - lab.source, axis=1)
    assert np.all(np.linalg.norm(lab.images[:, None] - mics[None], axis=2) > d_src - lab.tolerance)


# End to end at 48 kHz (16 kHz labels fewer echoes, see above). Over 20 rooms per layout the walls
# (centre of each true wall to the estimated plane) came out within: compact array median 0.02 mm,
# 95th percentile 2.4 mm, worst 10 mm (far walls seen from a 0.5 m array: the image's direction
# is what the array resolves worst); spread array median 0.01 mm, 95th percentile 0.5 mm, worst
# 2.7 mm; the source within 0.1 mm. The bounds are three times the worst, and far below what one
# wrong echo column gives (a wall tilted or shifted by decimetres to metres).
@pytest.mark.parametrize(("compact", "bound"), [(True, 0.03), (False, 0.01)])
def test_room_from_simulated_rirs_recovers_the_walls(rng, compact, bound):
    size, src, mics, absorption = random_setup(rng, compact)
    rirs = shoebox_rirs(size, src, mics, fs=48000, absorption=absorption, max_order=3)
    res = room_from_rirs(rirs, 48000, mics, c=C, rng=rng)
    assert res.converged, res.message
    rec = res.reconstruction
    assert rec.room is not None and len(rec.wall_offsets) == 6
    assert np.max(wall_errors(rec, size)) < bound
    assert np.linalg.norm(rec.sources[0] - src) < 0.005
    assert np.array_equal(rec.observed[0], res.labelling.mask)


def wrong_walls(rec, size, *, degrees=5.0, metres=0.10):
    """Estimated walls more than ``degrees`` from every true normal of the shoebox, or more than
    ``metres`` from the centre of the true wall with the nearest normal."""
    room = Room.shoebox(size)
    centre = np.asarray(size) / 2
    bad = []
    for n, o in zip(rec.wall_normals, rec.wall_offsets, strict=True):
        j = int(np.argmax(room.normals @ n))
        p = centre + (room.offsets[j] - room.normals[j] @ centre) * room.normals[j]
        angle = np.degrees(np.arccos(min(float(room.normals[j] @ n), 1.0)))
        bad.append(angle > degrees or abs(n @ p - o) > metres)
    return np.array(bad)


# Issue: at 16 kHz with a compact array a first-order image that few microphones hear cleanly is
# missed, and a higher-order image (or a chance alignment) takes its column: before the swap test
# (_ambiguous) and max_normal_std, 49 of 200 rooms (this setup, setup seeds 1-10) came out
# converged with such a wrong wall. Now none does, and 65% converge (130 of 200; per 20 rooms
# 12-16). Other layouts, 100 rooms each: 16 kHz spread 7 -> 1 wrong, converged 100% -> 94%;
# 48 kHz compact 1 -> 0, 100% -> 99%; 48 kHz spread 0 -> 0, 100% -> 100%.
# 8 of 20 leaves a margin: at 65% fewer than 8 occur with probability 0.6%. Passed for seeds 1-5.
@pytest.mark.slow
def test_no_wrong_wall_is_presented_as_converged(rng):
    n_rooms, converged = 20, 0
    for _ in range(n_rooms):
        size, src, mics, absorption = random_setup(rng, compact=True)
        rirs = shoebox_rirs(size, src, mics, fs=16000, absorption=absorption, max_order=3)
        res = room_from_rirs(rirs, 16000, mics, c=C, rng=rng)
        if res.converged:
            converged += 1
            bad = wrong_walls(res.reconstruction, size)
            assert not bad.any(), f"wrong walls {np.flatnonzero(bad)} converged: {res.message}"
        else:
            assert res.message
    assert converged >= 8, f"only {converged} of {n_rooms} rooms converged"


def test_an_ambiguous_column_is_left_out_and_said_so(rng):
    """Every arrival up to order 3 but the floor's: second-order images through the floor take
    its column (and a free one); they are left out, no wall found is wrong, and it is said."""
    size = np.array([5.0, 4.0, 3.0])
    src = np.array([1.6, 1.3, 1.2])
    mics = np.array([3.0, 2.4, 1.5]) + rng.uniform(-0.3, 0.3, (10, 3))
    ims = Room.shoebox(size).image_sources(src, 3)
    # every arrival up to order 3 but the floor's (image 4, and the images coinciding with it)
    keep = ims.valid & (np.linalg.norm(ims.positions - ims.positions[4], axis=1) > 1e-9)
    dets = geometric_detections(mics, np.vstack([src[None], ims.positions[keep]]), 48000)
    lab = label_echoes(dets, mics, c=C, rng=rng)
    assert lab.status in (Status.NOT_IDENTIFIABLE, Status.OUTLIERS), lab.message
    floor = np.array([0.0, 0.0, -1.0])
    normals = (lab.images - lab.source) / np.linalg.norm(lab.images - lab.source, axis=1)[:, None]
    # every column is a true wall other than the floor; nothing floor-like is presented
    for n in normals:
        assert np.max(Room.shoebox(size).normals @ n) > np.cos(np.radians(1))
        assert n @ floor < np.cos(np.radians(1))
    assert "left out the image" in lab.message


# ---- missing echoes, silent RIRs, too few echoes ----------------------------------------------------


def test_missing_echoes_are_masked_and_spurious_peaks_left_out(rng):
    size = np.array([6.0, 5.0, 3.0])
    src = np.array([2.1, 1.7, 1.4])
    mics = np.array([2.5, 3.0, 1.5]) + rng.uniform(-0.4, 0.4, (10, 3))
    ims = Room.shoebox(size).image_sources(src, 2)
    points = np.vstack([src[None], ims.positions])  # direct, first and second order
    extra = [rng.uniform(1.0, 12.0, 5) for _ in mics]  # spurious peaks
    dets = geometric_detections(mics, points, 48000, extra)
    # wall 2's echo missed at microphones 1 and 4: remove those peaks
    for m in (1, 4):
        d = dets[m]
        keep = np.abs(d.times * C - np.linalg.norm(points[1 + 2] - mics[m])) > 1e-9
        dets[m] = detection(d.times[keep], d.amplitudes[keep], d.direct, d.fs)
    lab = label_echoes(dets, mics, c=C, rng=rng)
    assert lab.converged, lab.message
    wall = [int(np.argmin(np.linalg.norm(ims.positions[:6] - x, axis=1))) for x in lab.images]
    assert sorted(wall) == list(range(6))
    np.testing.assert_allclose(lab.images, ims.positions[wall], atol=1e-6)
    missing = np.zeros_like(lab.mask)
    missing[[1, 4], 1 + wall.index(2)] = True
    assert np.array_equal(lab.mask, ~missing)
    assert np.all(np.isnan(lab.ranges[missing])) and np.all(lab.peaks[missing] == -1)
    np.testing.assert_allclose(lab.residuals[lab.mask], 0.0, atol=1e-6)
    # the spurious peaks are nobody's
    assert lab.n_unassigned.sum() >= 0.9 * 5 * len(mics)


def test_a_silent_rir_gives_a_masked_row(rng):
    size, src, mics, absorption = random_setup(rng, compact=False)
    rirs = shoebox_rirs(size, src, mics, fs=48000, absorption=absorption, max_order=3)
    rirs[3] = 0.0
    res = room_from_rirs(rirs, 48000, mics, c=C, rng=rng)
    assert not res.detections[3].found
    lab = res.labelling
    assert not lab.mask[3].any() and np.all(np.isnan(lab.ranges[3])) and np.all(lab.peaks[3] == -1)
    assert lab.mask[np.arange(len(mics)) != 3, 0].all()
    assert res.converged, res.message
    assert not res.reconstruction.observed[0, 3].any()


def test_too_few_echoes_is_reported_not_converged(rng):
    size, src, mics, _ = random_setup(rng, compact=True)
    # direct paths only: the source is found, no image source
    dets = geometric_detections(mics, src[None], 16000)
    lab = label_echoes(dets, mics, c=C, rng=rng)
    assert lab.status is Status.NOT_IDENTIFIABLE and "0 of the 6" in lab.message
    assert lab.ranges.shape == (len(mics), 1) and lab.mask[:, 0].all()
    np.testing.assert_allclose(lab.source, src, atol=1e-6)
    assert not label_echoes(dets, mics, c=C, n_images=None, rng=rng).converged
    # a room without reflections: no reconstruction, and a message saying why
    rirs = shoebox_rirs(size, src, mics, fs=16000, max_order=0)
    res = room_from_rirs(rirs, 16000, mics, c=C, rng=rng)
    assert res.status is Status.NOT_IDENTIFIABLE and res.reconstruction is None
    assert "did not converge" in res.message
    # only 3 microphones heard anything: not even the source
    few = dets[:3] + [detection(np.zeros(0), np.zeros(0), None, 16000)] * (len(mics) - 3)
    lab = label_echoes(few, mics, c=C, rng=rng)
    assert lab.status is Status.NOT_IDENTIFIABLE
    assert np.all(np.isnan(lab.source)) and not lab.mask.any()
    assert "direct path" in lab.message


def test_n_images_none_labels_the_walls_there_are(rng):
    size = np.array([5.0, 4.0, 3.0])
    src = np.array([1.5, 1.2, 1.1])
    mics = np.array([3.0, 2.5, 1.4]) + rng.uniform(-0.3, 0.3, (9, 3))
    ims = Room.shoebox(size).image_sources(src, 1).positions
    points = np.vstack([src[None], ims[[0, 2, 4]]])  # three walls only (x0, y0, floor)
    dets = geometric_detections(mics, points, 48000)
    lab = label_echoes(dets, mics, c=C, n_images=None, rng=rng)
    assert lab.converged and lab.n_images == 3, lab.message
    order = np.argsort(np.linalg.norm(ims[[0, 2, 4]] - src, axis=1))
    np.testing.assert_allclose(lab.images, ims[[0, 2, 4]][order], atol=1e-6)
    lab = label_echoes(dets, mics, c=C, rng=rng)  # six asked for
    assert lab.status is Status.NOT_IDENTIFIABLE and "3 of the 6" in lab.message
    assert lab.n_images == 3
    # walls less certain than max_normal_std: kept as columns, the result not converged
    assert lab.normal_std.shape == (3,) and np.all(lab.normal_std > 0)
    vague = label_echoes(dets, mics, c=C, n_images=None, max_normal_std=1e-9, rng=rng)
    assert vague.status is Status.NOT_IDENTIFIABLE and vague.n_images == 3
    assert vague.message.count("doubtful") == 3 and "max_normal_std" in vague.message


# ---- input checks -----------------------------------------------------------------------------------


def test_bad_input_is_refused_with_a_message_naming_the_argument(rng):
    _, src, mics, _ = random_setup(rng, compact=True)
    dets = geometric_detections(mics, src[None], 16000)
    with pytest.raises(InvalidInputError, match="detections"):
        label_echoes(dets[:-1], mics, c=C)
    with pytest.raises(InvalidInputError, match=r"detections\[2\]"):
        label_echoes([*dets[:2], "peak", *dets[3:]], mics, c=C)
    with pytest.raises(InvalidInputError, match="mics"):
        label_echoes(dets, mics[:, :2], c=C)
    with pytest.raises(InvalidInputError, match="at least 4"):
        label_echoes(dets[:3], mics[:3], c=C)
    flat = mics.copy()
    flat[:, 2] = 1.0
    with pytest.raises(DegenerateGeometryError, match="coplanar"):
        label_echoes(dets, flat, c=C)
    for kwargs, name in [
        ({"c": -1.0}, "c"),
        ({"c": C, "n_images": 0}, "n_images"),
        ({"c": C, "min_mics": 3}, "min_mics"),
        ({"c": C, "tolerance": 0.0}, "tolerance"),
        ({"c": C, "max_range": -2.0}, "max_range"),
        ({"c": C, "n_triples": 1.5}, "n_triples"),
        ({"c": C, "max_normal_std": 0.0}, "max_normal_std"),
    ]:
        with pytest.raises(InvalidInputError, match=name):
            label_echoes(dets, mics, **kwargs)
    rirs = np.zeros((len(mics), 100))
    with pytest.raises(InvalidInputError, match="direct_template"):
        room_from_rirs(rirs + 1e-3, 16000, mics, c=C, direct_template=(0.001, -1.0))
    with pytest.raises(InvalidInputError, match="excitation"):
        room_from_rirs(
            rirs + 1e-3,
            16000,
            mics,
            c=C,
            direct_template=(0.0, 0.001),
            detect_options={"excitation": np.ones(5)},
        )


# ---- dEchorate: measured RIRs -------------------------------------------------------------------


REFLECTIVE = {"west x0": 0, "east xL": 1, "south y0": 2, "north yW": 3, "ceiling zH": 5}


def dechorate_room(path):
    """room_from_rirs on the 12 measured RIRs and mics_v3 only. The loudspeaker makes each arrival
    a long ringing pulse, so the RIRs are matched-filtered with the strongest direct sound (10
    samples before its peak to 40 after); the echoes are timed to 1-2 cm, with offsets of a few
    centimetres from the calibrated geometry, hence a 4 cm tolerance."""
    d = load_dechorate_rirs(path)
    res = room_from_rirs(
        d.rirs,
        d.fs,
        d.mics,
        c=d.c,
        rng=0,
        direct_template=(10 / d.fs, 40 / d.fs),
        detect_options={"max_time": 0.03, "noise_factor": 3.0, "direct_fraction": 0.5},
        label_options={"tolerance": 0.04, "n_images": None},
    )
    return d, res


def test_load_dechorate_rirs(dechorate_dir):
    d = load_dechorate_rirs(dechorate_dir)
    assert d.rirs.shape == (12, 19556) and d.fs == 48000 and d.mics.shape == (12, 3)
    np.testing.assert_allclose(d.room_size, [5.705, 5.965, 2.355])
    assert d.room_code == "011111" and d.c == pytest.approx(345.844)
    assert load_dechorate_rirs(dechorate_dir / "rirs_src0_12mics.npz").fs == d.fs
    with pytest.raises(InvalidInputError, match="path"):
        load_dechorate_rirs(dechorate_dir / "missing")


# Measured (the same for rng 0-3): loudspeaker 1.8 cm from src_v3, ceiling 1.1 cm, floor (not
# reflective in this room) 3.5 cm. The four lateral walls are NOT recovered. At this detection
# threshold (5-13 peaks per microphone) their echoes are mostly not detected: they are weak next to
# the clutter of the measured RIRs (reflections off other objects, loudspeaker ringing). With a
# lower one (noise_factor 1, about 30 peaks per microphone) the west echo is there at 8
# microphones, consistent to about 1 cm (and 5 cm late, as the README says), the east one at only
# 5; but chance alignments of the denser peaks then outnumber them (12 microphones in 6 pairs 4 cm
# apart are about 6 independent positions, so 6 agreeing microphones check little) and the
# labelling still finds only the ceiling (and, with min_mics=8, the floor). The planes this configuration matches to west and south are other
# reflections (57 cm and 34 cm off, the west one tilted 21 degrees); none is near east or north.
# So only the ceiling meets the 10 cm, and the four walls found do not bound a room.
def test_dechorate_loudspeaker_and_ceiling(dechorate_dir):
    d, res = dechorate_room(dechorate_dir)
    rec = res.reconstruction
    assert rec is not None, res.message
    assert np.linalg.norm(rec.sources[0] - d.source) < 0.05
    err = wall_errors(rec, d.room_size)
    assert err[5] < 0.03  # ceiling
    assert sum(err[k] < 0.10 for k in REFLECTIVE.values()) >= 1
    # the 12 microphones lie in a 0.54 m slab (z 0.95-1.49 m): wall 2's image fits as well on
    # the other side of their plane (4.67 noise variances), and the walls found do not close a
    # room; both are said
    assert res.status is Status.NOT_IDENTIFIABLE and "the other side" in res.message
    assert "do not bound a room" in res.message


# Why the lateral walls are out of reach (measured, scratch analysis, geometry and echo_toa.csv used
# only to look): after matched filtering with the direct sound the ceiling echo peaks at 0.38-0.59
# of the direct path and within 1.4 cm of the geometry at every microphone, while the west, east,
# south and north echoes reach only 0.04-0.41 (median about 0.2) over a clutter whose median is
# 0.07-0.14, their maxima within 8 cm of the expected time often on the window edge. Even with
# the shoebox prior (vertical walls, 2 parameters) and the floor/ceiling image family masked out,
# the 12-microphone steered envelope at the true walls ranks 1473 (west), 14723 (east), 25630
# (south) and 10600 (north) among 205200 (angle, distance) hypotheses, in every band tried
# (0.3-1.5, 0.3-3, 1-4, 2-8, 4-16 kHz, with and without the matched filter). The strongest
# lateral reflector is 35 cm beyond the calibrated south wall (where 9 of the 12 annotated south
# echoes lie too, 48-62 cm late in range), and the "west" column found is a 21-degree tilted plane
# at 10 (= 5 pairs of) microphones within 3 cm. Nothing in these RIRs singles out the four walls.
@pytest.mark.xfail(
    strict=True,
    reason="issue 7 asks for 4 of the 5 reflective dEchorate walls within 10 cm; only the ceiling "
    "is recovered from these RIRs (see test_dechorate_loudspeaker_and_ceiling)",
)
def test_dechorate_four_of_five_reflective_walls(dechorate_dir):
    d, res = dechorate_room(dechorate_dir)
    err = wall_errors(res.reconstruction, d.room_size)
    assert sum(err[k] < 0.10 for k in REFLECTIVE.values()) >= 4
