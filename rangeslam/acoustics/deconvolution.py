"""From recordings of a known excitation to room impulse responses, and back (for simulation).

A loudspeaker playing an excitation e (E,) into a room whose response at microphone m is h_m is
recorded as y_m = h_m * e + noise. :func:`deconvolve` recovers h_m by regularised spectral division
(a Wiener-style inverse filter, as in Farina's swept-sine method, "Simultaneous measurement of
impulse response and distortion with a swept-sine technique", AES 108th Convention, 2000):

    H_m(f) = Y_m(f) conj(E(f)) / (|E(f)|^2 + lambda max_f |E(f)|^2)

on an FFT long enough for the linear (not circular) convolution. The filter |E|^2 / (|E|^2 +
lambda max |E|^2) that relates the result to h_m is real and non-negative: zero phase, so every
arrival stays at its time and only loses the frequencies the excitation did not play (below
lambda of its peak power). Only the first L - E + 1 samples are returned: later parts of h_m
were recorded with part of the excitation cut off by the end of the recording.

The result is a RIR like any other (sample 0 at the start of the excitation), so everything
downstream (echo detection, labelling, the clipped and silent checks, the plots) is unchanged.
It is band-limited to what the excitation played: an excitation that stops well below fs / 2
(a sweep to 0.45 fs, or a real loudspeaker) leaves every arrival ringing, and the detector takes
the side lobes for echoes (see :func:`exponential_sweep`); such RIRs want the measured-RIR
preset (``rangeslam run --measured``: a matched filter with the direct sound).
:func:`rangeslam.acoustics.echoes.detect_echoes` can instead take the excitation itself (a matched
filter); with a sweep its pulse is the sweep's autocorrelation, wider than a deconvolved arrival
because a sweep's power falls with frequency. Measured on a simulated two-loudspeaker shoebox
session (seed 763382, 12 microphones, 48 kHz): from sweep recordings the matched filter lost one
loudspeaker's direct paths (not converged), deconvolved every wall came within 0.15 mm; from MLS
recordings both gave every wall within 0.21 mm.

:func:`exponential_sweep` and :func:`mls` make the two usual excitations; :func:`record` convolves
RIRs with one (what :func:`deconvolve` undoes), for ``rangeslam simulate room --recordings``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike
from scipy.fft import irfft, next_fast_len, rfft
from scipy.signal import fftconvolve, max_len_seq

from rangeslam._validation import as_float_array, as_scalar, frozen, shape_str
from rangeslam.errors import InvalidInputError

__all__ = [
    "EXCITATIONS",
    "REGULARIZATION",
    "deconvolve",
    "excitation_signal",
    "exponential_sweep",
    "mls",
    "record",
    "shift_signals",
]

#: lambda of :func:`deconvolve`: frequencies played below this fraction of the excitation's peak
#: power are attenuated rather than amplified (noise there would dominate the RIR).
REGULARIZATION = 1e-6
#: The excitations :func:`excitation_signal` makes.
EXCITATIONS = ("sweep", "mls")


def exponential_sweep(
    fs: float, *, duration: float = 0.5, f_low: float = 20.0, f_high: float | None = None
) -> np.ndarray:
    """An exponential (logarithmic) sine sweep from ``f_low`` to ``f_high`` (default fs / 2) Hz
    over ``duration`` seconds (Farina 2000), with 5 ms raised-cosine fades at both ends.

    Why up to fs / 2: the deconvolved RIR lacks what the sweep did not play, and a band cut at
    0.45 fs leaves every arrival with side lobes the echo detector takes for echoes (3 pulses
    deconvolved came out as 11 detections at 48 kHz, 4 to 17 samples from the true ones; up to
    0.49 fs, 4; up to fs / 2, the 3 within 0.003 sample; tests/test_run_recordings.py).
    """
    fs = as_scalar(fs, "fs", low=0.0, low_open=True, expected="a positive number of Hz")
    duration = as_scalar(duration, "duration", low=0.0, low_open=True, expected="seconds > 0")
    f_low = as_scalar(f_low, "f_low", expected="a finite number of Hz")
    f_high = fs / 2 if f_high is None else as_scalar(f_high, "f_high", expected="Hz, or None")
    if not 0 < f_low < f_high <= fs / 2:
        raise InvalidInputError(
            f"the sweep needs 0 < f_low < f_high <= fs / 2 = {fs / 2:g} Hz; got f_low {f_low:g}, "
            f"f_high {f_high:g}"
        )
    if round(duration * fs) < 2:
        raise InvalidInputError(
            f"duration must give at least 2 samples at fs = {fs:g} Hz; got {duration:g} s"
        )
    t = np.arange(round(duration * fs)) / fs
    rate = math.log(f_high / f_low)
    x = np.sin(2 * np.pi * f_low * duration / rate * (np.exp(t * rate / duration) - 1.0))
    fade = min(round(0.005 * fs), len(x) // 2)
    ramp = 0.5 - 0.5 * np.cos(np.pi * np.arange(fade) / max(fade, 1))
    x[:fade] *= ramp
    x[len(x) - fade :] *= ramp[::-1]
    return x


def mls(nbits: int = 14) -> np.ndarray:
    """A maximum-length sequence of 2^nbits - 1 samples of +-1 (``scipy.signal.max_len_seq``)."""
    if isinstance(nbits, bool) or not isinstance(nbits, int | np.integer) or not 4 <= nbits <= 24:
        raise InvalidInputError(f"nbits must be an integer from 4 to 24; got {nbits!r}")
    return 2.0 * max_len_seq(int(nbits))[0] - 1.0


def excitation_signal(kind: str, fs: float) -> np.ndarray:
    """The excitation ``kind`` ("sweep": a 0.5 s exponential sweep from 20 Hz to fs / 2; "mls":
    a maximum-length sequence of about 0.34 s) at ``fs`` Hz."""
    if kind not in EXCITATIONS:
        raise InvalidInputError(f"excitation must be one of {', '.join(EXCITATIONS)}; got {kind!r}")
    fs = as_scalar(fs, "fs", low=0.0, low_open=True, expected="a positive number of Hz")
    if kind == "sweep":
        return exponential_sweep(fs)
    return mls(max(4, min(24, round(math.log2(0.34 * fs + 1)))))


def record(rirs: ArrayLike, excitation: ArrayLike) -> np.ndarray:
    """(M, L + E - 1) what microphones with RIRs (M, L) record of ``excitation`` (E,): the full
    linear convolution, sample 0 at the start of the excitation."""
    h = as_float_array(rirs, "rirs")
    e = _as_excitation(excitation)
    if h.ndim != 2:
        raise InvalidInputError(f"rirs must have shape (M, L); got {shape_str(h.shape)}")
    return fftconvolve(h, e[None, :])


def deconvolve(
    recordings: ArrayLike, excitation: ArrayLike, *, regularization: float = REGULARIZATION
) -> np.ndarray:
    """(M, L - E + 1) RIRs from M recordings (M, L) of ``excitation`` (E,), E < L - 1.

    Sample n of the result is time n / fs after the start of the excitation in the recording
    (module docstring: regularised spectral division, zero phase). ``regularization``: lambda,
    the fraction of the excitation's peak power below which frequencies are attenuated.

    Raises:
        InvalidInputError naming the argument: recordings not (M, L) or not finite, an excitation
        not (E,), not finite, all zeros or not shorter than the recordings by at least 2 samples
        (the RIRs would have fewer than 3).
    """
    y = as_float_array(recordings, "recordings")
    if y.ndim != 2 or y.shape[0] < 1:
        raise InvalidInputError(
            f"recordings must have shape (M, L), one recording per row; got {shape_str(y.shape)}"
        )
    bad = np.argwhere(~np.isfinite(y))
    if len(bad):
        m, n = (int(i) for i in bad[0])
        raise InvalidInputError(
            f"recordings must be finite; recordings[{m}] sample {n} is {y[m, n]}"
        )
    e = _as_excitation(excitation)
    lam = as_scalar(regularization, "regularization", low=0.0, low_open=True, expected="> 0")
    length = y.shape[1] - len(e) + 1
    if length < 3:
        raise InvalidInputError(
            f"excitation ({len(e)} samples) must be shorter than the recordings ({y.shape[1]} "
            "samples) by at least 2: what follows the excitation's end is the RIR"
        )
    n = next_fast_len(y.shape[1] + len(e) - 1, real=True)
    spec = rfft(e, n)
    power = np.abs(spec) ** 2
    inverse = np.conj(spec) / (power + lam * power.max())
    return frozen(irfft(rfft(y, n, axis=1) * inverse[None, :], n, axis=1)[:, :length])


def shift_signals(x: ArrayLike, delay: float) -> np.ndarray:
    """(M, L) the rows of ``x`` (M, L) delayed by ``delay`` samples (negative: advanced; any
    fraction), band-limited (a linear phase on a zero-padded FFT); what moves past either end is
    cut, the other end is filled with zeros."""
    arr = as_float_array(x, "x")
    if arr.ndim != 2:
        raise InvalidInputError(f"x must have shape (M, L); got {shape_str(arr.shape)}")
    d = as_scalar(delay, "delay", expected="a finite number of samples")
    length = arr.shape[1]
    if abs(d) >= length:
        return np.zeros_like(arr)
    pad = math.ceil(abs(d)) + 64
    n = next_fast_len(length + 2 * pad, real=True)
    buf = np.zeros((arr.shape[0], n))
    buf[:, pad : pad + length] = arr
    k = np.arange(n // 2 + 1)
    out = irfft(rfft(buf, axis=1) * np.exp(-2j * np.pi * k * d / n)[None, :], n, axis=1)
    out = out[:, pad : pad + length]
    whole = math.floor(d) if d >= 0 else math.ceil(d)  # samples certainly moved past an end
    if whole > 0:
        out[:, :whole] = 0.0
    elif whole < 0:
        out[:, length + whole :] = 0.0
    return out


def _as_excitation(excitation: ArrayLike) -> np.ndarray:
    """(E,) finite, not all zeros."""
    e = as_float_array(excitation, "excitation")
    if e.ndim != 1 or len(e) < 1:
        raise InvalidInputError(
            f"excitation must have shape (E,) with E >= 1; got {shape_str(e.shape)}"
        )
    bad = np.flatnonzero(~np.isfinite(e))
    if len(bad):
        raise InvalidInputError(f"excitation must be finite; sample {int(bad[0])} is {e[bad[0]]}")
    if not np.any(e):
        raise InvalidInputError("excitation must not be all zeros")
    return e
