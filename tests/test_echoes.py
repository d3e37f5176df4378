"""Echo detection in RIRs: synthetic pulse trains, pyroomacoustics rooms, matched filtering, bad input."""

import dataclasses

import numpy as np
import pytest
from scipy.signal import chirp, fftconvolve
from scipy.signal.windows import tukey

from rangeslam import InvalidInputError, Room
from rangeslam.acoustics.echoes import (
    SPEED_OF_SOUND,
    ClippedRirWarning,
    EchoDetection,
    detect_echoes,
    detect_echoes_many,
)
from rangeslam.sim.rir import shoebox_rirs

C = 343.0  # pyroomacoustics' default speed of sound


def pulse(n, tau, half=32):
    """A band-limited pulse at tau samples: a sinc under a Blackman window of +-half samples
    (not the detector's own Hann-tapered model pulse)."""
    t = n - tau
    w = 0.42 + 0.5 * np.cos(np.pi * t / half) + 0.08 * np.cos(2 * np.pi * t / half)
    return np.where(np.abs(t) < half, np.sinc(t) * w, 0.0)


def pulse_train(rng, length, count, min_gap, amp_range=(0.2, 1.0)):
    """Times (samples, ascending, at least min_gap apart) and signed amplitudes of count pulses."""
    while True:
        times = np.sort(rng.uniform(60, length - 60, count))
        if np.min(np.diff(times)) >= min_gap:
            break
    amps = rng.uniform(*amp_range, count) * rng.choice([-1.0, 1.0], count)
    n = np.arange(length)
    x = np.sum([a * pulse(n, t) for a, t in zip(amps, times, strict=True)], axis=0)
    return x, times, amps


def sweep(fs, f0, f1, duration):
    t = np.arange(round(duration * fs)) / fs
    return chirp(t, f0, duration, f1) * tukey(len(t), 0.1)


def random_room(rng, n_mics=4):
    size = np.array([rng.uniform(3, 10), rng.uniform(3, 8), rng.uniform(2.4, 4)])
    src = rng.uniform(0.2, size - 0.2)
    mics = rng.uniform(0.2, size - 0.2, (n_mics, 3))
    return size, src, mics, rng.uniform(0.1, 0.3)


def arrival_samples(size, src, mic, fs, order=3):
    """Arrival times (samples) of the direct path and every valid image source up to ``order``
    (each distinct image once), and their reflection orders (0 for the direct path)."""
    images = Room.shoebox(size).image_sources(src, order=order)
    _, first = np.unique(np.round(images.positions, 9), axis=0, return_index=True)
    keep = np.sort(first[images.valid[first]])
    pos = np.vstack([src[None], images.positions[keep]])
    orders = np.concatenate([[0], images.orders[keep]])
    return np.linalg.norm(pos - mic, axis=1) / C * fs, orders


def isolated_first_order(times, orders, isolation):
    """Indices of the direct path and first-order echoes with no other arrival within
    ``isolation`` samples (echoes that coincide with another arrival cannot be told apart)."""
    out = []
    for j in np.flatnonzero(orders <= 1):
        if np.min(np.abs(np.delete(times, j) - times[j])) > isolation:
            out.append(j)
    return out


# ---- synthetic pulse trains ---------------------------------------------------------------------


def test_noise_free_pulses_are_recovered_exactly(rng):
    x, times, amps = pulse_train(rng, 2000, 6, min_gap=80)
    det = detect_echoes(x, 16000.0)
    assert len(det) == 6 and det.found
    assert np.max(np.abs(det.samples - times)) < 0.01  # samples
    assert np.max(np.abs(det.amplitudes - amps)) < 0.01
    assert np.all(np.diff(det.times) > 0)
    assert det.direct == 0
    assert det.times[0] == pytest.approx(times[0] / 16000.0, abs=1e-6)


def test_noisy_pulses_are_all_found_within_a_tenth_of_a_sample(rng):
    sigma = 0.01
    x, times, amps = pulse_train(rng, 3000, 12, min_gap=10, amp_range=(0.3, 1.0))
    x = x + rng.normal(0.0, sigma, x.shape)
    det = detect_echoes(x, 48000.0)
    assert len(det) == 12
    # timing std is about sigma / (|a| * 1.8) < 0.02 sample here
    assert np.max(np.abs(det.samples - times)) < 0.1
    assert np.max(np.abs(det.amplitudes - amps)) < 0.06
    # the pulses' tails cover a quarter of the samples and raise the MAD a little
    assert det.noise_level == pytest.approx(sigma, rel=0.25)
    assert det.threshold == pytest.approx(6 * det.noise_level)


def test_noise_only_gives_no_echoes(rng):
    sigma = rng.uniform(0.1, 10)
    det = detect_echoes(rng.normal(0.0, sigma, 8000), 16000.0)
    assert not det.found and len(det) == 0 and det.direct is None
    assert det.times.shape == (0,) and det.amplitudes.shape == (0,)
    assert det.noise_level == pytest.approx(sigma, rel=0.1)


def test_a_silent_rir_gives_an_empty_detection():
    det = detect_echoes(np.zeros(500), 16000.0)
    assert not det.found and det.direct is None and not det.clipped
    assert det.threshold == 0.0 and det.noise_level == 0.0


def test_a_stuck_channel_warns_and_gives_no_echoes():
    """A constant (a channel stuck at one value) has no echo, and all its samples are at its
    largest magnitude: it is reported as clipped."""
    with pytest.warns(ClippedRirWarning, match="500 consecutive samples from sample 0"):
        det = detect_echoes(np.full(500, 0.3), 16000.0)
    assert not det.found and det.clipped


def test_a_dc_offset_and_slow_drift_are_no_echoes(rng):
    x, times, _ = pulse_train(rng, 4000, 5, min_gap=60, amp_range=(0.5, 1.0))
    drift = 0.05 + 0.03 * np.sin(2 * np.pi * np.arange(4000) / 4000)
    det = detect_echoes(x + drift, 16000.0)
    assert len(det) == 5
    assert np.max(np.abs(det.samples - times)) < 0.01


def test_echoes_are_kept_by_strength_and_time(rng):
    x, times, amps = pulse_train(rng, 3000, 8, min_gap=60)
    det = detect_echoes(x, 16000.0, max_echoes=4)
    keep = np.sort(np.concatenate([[0], 1 + np.argsort(-np.abs(amps[1:]))[:3]]))
    assert len(det) == 4 and det.direct == 0
    np.testing.assert_allclose(det.samples, times[keep], atol=0.01)

    cut = (times[3] + times[4]) / 2 / 16000.0
    det = detect_echoes(x, 16000.0, max_time=cut)
    np.testing.assert_allclose(det.samples, times[:4], atol=0.01)


def test_direct_fraction_skips_weak_early_peaks():
    n = np.arange(2000)
    x = 0.05 * pulse(n, 300.3) + pulse(n, 700.6) + 0.4 * pulse(n, 1200.2)
    det = detect_echoes(x, 16000.0)
    assert len(det) == 3 and det.direct == 1
    assert det.samples[1] == pytest.approx(700.6, abs=0.01)
    assert detect_echoes(x, 16000.0, direct_fraction=0.0).direct == 0
    assert detect_echoes(x, 16000.0, direct_fraction=0.5).direct == 1
    assert detect_echoes(x, 16000.0, direct_fraction=1.0).direct == 1


def test_noise_window_and_explicit_threshold(rng):
    n = np.arange(4000)
    x = pulse(n, 2000.4) + 0.2 * pulse(n, 2600.7) + rng.normal(0, 1e-3, 4000)
    det = detect_echoes(x, 16000.0, noise_window=(0.0, 0.1))  # samples 0..1600: noise only
    assert det.noise_level == pytest.approx(1e-3, rel=0.15)
    assert len(det) == 2
    det = detect_echoes(x, 16000.0, threshold=0.5)
    assert det.threshold == 0.5 and len(det) == 1


def test_the_result_is_frozen(rng):
    x, _, _ = pulse_train(rng, 1000, 3, min_gap=60)
    det = detect_echoes(x, 8000.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        det.direct = 1  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        det.times[0] = 0.0
    np.testing.assert_allclose(det.distances(), det.times * SPEED_OF_SOUND)
    assert isinstance(det, EchoDetection)


# ---- pyroomacoustics rooms -------------------------------------------------------------------


@pytest.mark.parametrize("fs", [16000, 48000])
def test_direct_path_and_first_order_echoes_in_shoebox_rooms(rng, fs):
    """Of the direct paths and first-order echoes that no other arrival (image sources up to
    order 3, all that are simulated) comes within a sample of, >= 95% are detected within one
    sample (measured: 98.3-98.6% at 16 kHz, 99.6-99.7% at 48 kHz, see rangeslam.acoustics.echoes); nearly
    every detection is a real arrival; the direct path is found and nothing comes before it."""
    present = hit = detections = real = 0
    for _ in range(10):
        size, src, mics, absorption = random_room(rng)
        rirs = shoebox_rirs(size, src, mics, fs=fs, absorption=absorption, max_order=3)
        for det, mic in zip(detect_echoes_many(rirs, fs), mics, strict=True):
            truth, orders = arrival_samples(size, src, mic, fs)
            got = det.samples
            assert got[0] > truth[0] - 1.0
            if np.min(np.abs(truth[1:] - truth[0])) > 2.0:  # else it may merge with an echo
                assert abs(got[det.direct] - truth[0]) < 1.0
            for j in isolated_first_order(truth, orders, isolation=1.0):
                present += 1
                hit += np.min(np.abs(got - truth[j])) <= 1.0
            detections += len(got)
            real += np.sum(np.min(np.abs(got[:, None] - truth[None, :]), axis=1) <= 1.0)
    assert present > 150
    assert hit / present >= 0.95
    assert real / detections >= 0.97


def test_matched_filter_recovers_the_rir_times(rng):
    """A pyroomacoustics RIR recorded through a 50 ms sweep (50 Hz - 7.2 kHz) with a little noise:
    the matched filter finds the direct path and first-order echoes where the RIR itself does.
    Its pulse is wider than the RIR's, so "isolated" means 3 samples from any other arrival."""
    fs = 16000
    excitation = sweep(fs, 50.0, 7200.0, 0.05)
    present = agree = 0
    for _ in range(3):
        size, src, mics, absorption = random_room(rng)
        rirs = shoebox_rirs(size, src, mics, fs=fs, absorption=absorption, max_order=3)
        for h, mic in zip(rirs, mics, strict=True):
            recording = fftconvolve(h, excitation)
            recording += rng.normal(0, 1e-4 * np.abs(recording).max(), recording.shape)
            filtered = detect_echoes(recording, fs, excitation=excitation)
            direct = detect_echoes(h, fs)
            truth, orders = arrival_samples(size, src, mic, fs)
            if np.min(np.abs(truth[1:] - truth[0])) > 3.0:
                assert filtered.samples[filtered.direct] == pytest.approx(truth[0], abs=0.25)
            for j in isolated_first_order(truth, orders, isolation=3.0):
                present += 1
                a = filtered.samples[np.argmin(np.abs(filtered.samples - truth[j]))]
                b = direct.samples[np.argmin(np.abs(direct.samples - truth[j]))]
                agree += abs(a - truth[j]) <= 1.0 and abs(a - b) <= 0.25
    assert agree / present >= 0.95


def test_matched_filter_on_a_synthetic_recording_is_exact(rng):
    """Pulses convolved with a sweep: the matched filter gives their times (from the start of the
    sweep) and amplitudes back."""
    fs = 48000
    excitation = sweep(fs, 100.0, 20000.0, 0.02)
    x, times, amps = pulse_train(rng, 4000, 5, min_gap=200, amp_range=(0.3, 1.0))
    recording = fftconvolve(x, excitation)
    det = detect_echoes(recording, fs, excitation=excitation)
    assert len(det) == 5
    assert np.max(np.abs(det.samples - times)) < 0.02
    assert np.max(np.abs(det.amplitudes - amps)) < 0.02


def test_many_matches_one_by_one(rng):
    size, src, mics, absorption = random_room(rng, n_mics=3)
    rirs = shoebox_rirs(size, src, mics, fs=16000, absorption=absorption, max_order=2)
    many = detect_echoes_many(list(rirs), 16000, max_echoes=7)
    for h, det in zip(rirs, many, strict=True):
        one = detect_echoes(h, 16000, max_echoes=7)
        np.testing.assert_array_equal(det.times, one.times)
        assert len(det) == 7


# ---- bad input -----------------------------------------------------------------------------------


def test_a_clipped_rir_warns_and_is_still_processed(rng):
    """Hard clipping at +-1 of a direct path 8 times bigger: its 4 largest samples, of either
    sign, are at the clip level."""
    n = np.arange(2000)
    x = 8 * pulse(n, 500.3) + 0.5 * pulse(n, 900.8) + 0.3 * pulse(n, 1400.5)
    clipped = np.clip(x, -1.0, 1.0)
    with pytest.warns(
        ClippedRirWarning, match="rir looks clipped: 4 consecutive samples from sample 499"
    ):
        det = detect_echoes(clipped, 16000.0)
    assert det.clipped
    assert det.samples[det.direct] == pytest.approx(500.3, abs=1.5)  # clipped: off by ~1
    for t in (900.8, 1400.5):
        assert np.min(np.abs(det.samples - t)) < 0.01
    with pytest.warns(ClippedRirWarning, match=r"rirs\[1\] looks clipped"):
        dets = detect_echoes_many([x, clipped], 16000.0)
    assert [d.clipped for d in dets] == [False, True]


@pytest.mark.parametrize(
    ("rir", "kwargs", "match"),
    [
        (np.zeros((2, 100)), {}, r"rir must have shape \(L,\) \(one RIR\); got \(2, 100\)"),
        (np.zeros(2), {}, "rir must hold at least 3 samples"),
        ([1.0, "a", 2.0], {}, "rir must be an array of real numbers"),
        (np.r_[np.zeros(7), np.nan, np.zeros(5)], {}, "rir must be finite; sample 7 is nan"),
        (np.r_[np.zeros(3), -np.inf], {}, "rir must be finite; sample 3 is -inf"),
        (np.zeros(100), {"fs": 0}, "fs must be a positive number"),
        (np.zeros(100), {"fs": -16000}, "fs must be a positive number"),
        (np.zeros(100), {"fs": np.nan}, "fs must be a positive number"),
        (np.zeros(100), {"fs": True}, "fs must be a positive number"),
        (np.zeros(100), {"fs": "16k"}, "fs must be a positive number"),
        (np.zeros(100), {"excitation": np.zeros(10)}, "excitation must not be all zeros"),
        (np.zeros(100), {"excitation": np.ones((2, 5))}, r"excitation must have shape \(E,\)"),
        (np.zeros(100), {"excitation": [1.0, np.nan]}, "excitation must be finite; sample 1"),
        (np.zeros(100), {"max_echoes": 0}, "max_echoes must be an integer >= 1"),
        (np.zeros(100), {"max_echoes": 2.5}, "max_echoes must be an integer >= 1"),
        (np.zeros(100), {"min_separation": -1e-3}, "min_separation must be a finite number >= 0"),
        (np.zeros(100), {"threshold": np.inf}, "threshold must be a finite number >= 0"),
        (np.zeros(100), {"noise_factor": -1}, "noise_factor must be a finite number >= 0"),
        (np.zeros(100), {"relative_threshold": 1.5}, r"relative_threshold must be .* in \[0, 1\]"),
        (np.zeros(100), {"relative_threshold": 1.0}, "relative_threshold must be below 1"),
        (np.zeros(100), {"direct_fraction": 2}, r"direct_fraction must be .* in \[0, 1\]"),
        (np.zeros(100), {"max_time": -0.1}, "max_time must be a finite number >= 0"),
        (np.zeros(100), {"noise_window": (0.01, 0.0)}, "noise_window must be"),
        (np.zeros(100), {"noise_window": (0.0, 1e-4)}, r"at least 8 of the 100 samples"),
        (np.zeros(100), {"noise_window": 0.5}, r"noise_window must be \(start, stop\)"),
    ],
)
def test_bad_input(rir, kwargs, match):
    kwargs = {"fs": 16000.0, **kwargs}
    fs = kwargs.pop("fs")
    with pytest.raises(InvalidInputError, match=match):
        detect_echoes(rir, fs, **kwargs)


@pytest.mark.parametrize(
    ("rirs", "match"),
    [
        (np.zeros(100), r"rirs must have shape \(M, L\) .* got \(100,\) \(use detect_echoes"),
        (np.zeros((2, 3, 4)), r"rirs must have shape \(M, L\)"),
        ([0.0, 1.0, 2.0], "got a flat sequence of 3 numbers"),
        ([], "rirs must hold at least one RIR"),
        (np.zeros((0, 10)), "rirs must hold at least one RIR"),
        ([np.zeros(10), np.zeros(10), np.zeros(9)], r"rirs\[2\] has 9 samples, rirs\[0\] has 10"),
        ([np.zeros(10), np.r_[np.zeros(4), np.nan, np.zeros(5)]], r"rirs\[1\] .* sample 4 is nan"),
        ([np.zeros(10), np.zeros((2, 5))], r"rirs\[1\] must have shape \(L,\)"),
        ("abc", "rirs must be an"),
    ],
)
def test_bad_input_many(rirs, match):
    with pytest.raises(InvalidInputError, match=match):
        detect_echoes_many(rirs, 16000.0)


def test_many_refuses_unknown_options():
    with pytest.raises(TypeError, match="unexpected keyword argument 'treshold'"):
        detect_echoes_many(np.zeros((2, 10)), 16000.0, treshold=0.1)
