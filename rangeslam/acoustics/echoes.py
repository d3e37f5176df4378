"""Echo detection in room impulse responses: arrival times (direct path first) and amplitudes.

Model: the RIR is a sum of band-limited pulses ``a_i p(t - t_i)`` plus noise and a slowly varying
offset. Without an excitation ``p`` is the band-limited impulse, a sinc tapered by a Hann window
over +-40 samples (the 81-tap fractional-delay filter pyroomacoustics builds its RIRs from). With
one, the input is a recording of the excitation and is matched-filtered first (correlated with
the excitation and divided by its energy): ``p`` is then the excitation's normalised
autocorrelation, symmetric with peak 1 at lag 0, so the times stay absolute (lag 0 is the start
of the excitation) and an isolated echo keeps its RIR amplitude.

:func:`detect_echoes`:

1. Baseline: a running median over +-10 ms (at least +-16 pulse widths) of the signal smoothed by
   [1, 2, 1] / 4 is subtracted. That removes DC and slow drifts such as the undershoot of the
   10 Hz high-pass pyroomacoustics applies (up to ~1.5% of the direct path), which otherwise
   turn up as rows of "echoes"; the smoothing cancels the alternating tails of nearby pulses,
   which would bias the median.
2. Noise floor: 1.4826 x the median absolute deviation (MAD) of the signal, over the span searched
   or over ``noise_window``. Echoes are sparse, so the median ignores them.
3. Threshold ``max(noise_factor * noise, relative_threshold * peak)``, ``peak`` the largest |sample|
   in the span searched, unless ``threshold`` is given.
4. Candidates: local maxima of |signal| above the threshold, ``min_separation`` apart
   (``scipy.signal.find_peaks``).
5. Strongest first, each candidate is refined (below) on the residual, the signal minus the pulses
   kept so far. It is kept if its refined amplitude is still above the threshold, it is
   ``min_separation`` from every kept echo, and it exceeds what a slightly wrong pulse of a kept
   echo d pulse widths away can leave there: (2 x the residual at that echo's peak + 0.5 x its
   amplitude / pi) / d. Its pulse is then subtracted. Subtracting removes the tails of strong
   arrivals, which otherwise pass for weak echoes beside them, and lets a weak echo next to a
   strong one be timed without the strong one's tail; the side-lobe test catches what two
   arrivals closer than a sample (one peak, not quite the model pulse) or a pulse whose tails
   differ from the model leave behind. A last pass refines every kept echo again with all the
   others subtracted. Without the subtraction, pyroomacoustics RIRs gave 6-11 spurious peaks per
   RIR and a wrong direct path in a third of them at 16 kHz; with it, < 0.01 and none.
6. Sub-sample refinement, the maximum-likelihood delay of the known pulse in white noise: the
   band-limited (tapered-sinc) interpolation of the samples around the peak, divided by the norm
   of the sampled pulse at that delay, is evaluated on a 1/32-sample grid over +-1 sample and its
   largest magnitude located by a parabola through the three best grid points; the amplitude is
   the least-squares fit of the pulse there (signed). On isolated pyroomacoustics pulses the time
   is exact to 5e-4 sample and the amplitude to 0.2%; a parabola through the three largest
   samples is off by up to 0.23 sample (a sinc is no parabola), and the peak of the interpolation
   without the norm by up to 0.01 sample.

Measured on pyroomacoustics shoebox RIRs (``rangeslam.sim.rir.shoebox_rirs``, reflection order 3,
absorption 0.1-0.3, random rooms 3-10 x 3-8 x 2.4-4 m, 3 x 50 rooms x 4 microphones; the test is
tests/test_echoes.py): of the direct paths and first-order echoes with no other arrival (image
source up to order 3) within 1 sample, 98.3-98.6% (16 kHz) and 99.6-99.7% (48 kHz) are detected
within 1 sample, with median / 95th-percentile errors of 0.0015 / 0.14 sample (16 kHz) and
3e-4 / 0.01 sample (48 kHz); of those with no other arrival within 2 samples, 99.9% and 100%
(95th percentile 0.03 and 0.005 sample). What is missed or off are arrivals 1-2 samples from
another one, which merge into one peak. Detections more than a sample from every arrival: < 0.01
per RIR. White noise down to 30 dB below the direct path changes none of this much.

Times are in seconds from sample 0 (from the emission for ``shoebox_rirs``), amplitudes in the
units of the RIR.
"""

from __future__ import annotations

import inspect
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.ndimage import median_filter
from scipy.signal import fftconvolve, find_peaks, hilbert

from rangeslam._robust import MAD_TO_STD
from rangeslam._validation import (
    as_flag,
    as_float_array,
    as_pair,
    as_scalar,
    frozen,
    shape_str,
)
from rangeslam.errors import InvalidInputError

__all__ = [
    "SPEED_OF_SOUND",
    "ClippedRirWarning",
    "EchoDetection",
    "detect_echoes",
    "detect_echoes_many",
]

#: m/s: pyroomacoustics' default (``pyroomacoustics.constants.get("c")``), used by rangeslam.sim.rir.
SPEED_OF_SOUND = 343.0

# Half-length (samples) of the Hann-tapered sinc used to interpolate and as the band-limited pulse.
_HALF = 40
# Grid steps per sample of the peak search, and how far (samples) from the integer peak it looks.
_GRID = 32
_REACH = 1
# Side-lobe test. A pulse that is not quite the model (two arrivals closer than a sample, a
# coloured transducer, a different taper) leaves a residual whose side lobes, d pulse widths away,
# reach about (residual at its peak) / d, plus up to a fraction of the pulse's own tails,
# |amplitude| / (pi d). Candidates no bigger than _GUARD times the first plus _TAILS times the
# second are taken for such side lobes.
_GUARD = 2.0
_TAILS = 0.5
# Half-length of the running median taken as the baseline: seconds, and at least this many pulse
# widths.
_BASELINE_TIME = 0.01
#: Highest sampling rate accepted, Hz (10 MHz, far above audio and ultrasonic ranging): the
#: baseline's running median spans _BASELINE_TIME * fs samples, which at absurd rates (fs = 1e10
#: from a unit slip) exhausted memory instead of failing.
MAX_FS = 1e7
_BASELINE_WIDTHS = 16
# Envelope half-width at half maximum of the band-limited impulse (|sinc(t / 2)|), samples: the
# unit of pulse width, which scales the default separation, the baseline and the side-lobe test.
_IMPULSE_HALFWIDTH = 1.2067
# Consecutive samples at the largest magnitude that make a RIR "clipped".
CLIP_RUN = 3
# The autocorrelation of an excitation is kept out to where it falls below this (relative) level.
_PULSE_TAIL = 1e-4
_MAX_PULSE_HALF = 2048


class ClippedRirWarning(UserWarning):
    """A RIR (or recording) has several consecutive samples at its largest magnitude."""


@dataclass(frozen=True, eq=False)
class EchoDetection:
    """Echoes detected in one RIR.

    Attributes:
        times: (K,) arrival times in seconds from sample 0, ascending.
        amplitudes: (K,) signed peak values of the band-limited signal at ``times`` (after the
            matched filter, if an excitation was given: then an isolated echo's amplitude is its
            amplitude in the RIR).
        direct: index into ``times`` of the direct path: the earliest detection whose |amplitude|
            is at least ``direct_fraction`` (default 0.1) times the largest. Usually 0; weaker
            detections before it (a noise spike, the onset of a recording that does not start at
            rest, the pre-echoes of a distorting loudspeaker) stay in ``times``. None when
            nothing was detected.
        noise_level: robust estimate of the noise standard deviation (MAD x 1.4826), RIR units.
        threshold: the detection threshold used, RIR units.
        fs: sampling rate, Hz.
        clipped: True when the input had several consecutive samples at its largest |value|.
    """

    times: np.ndarray
    amplitudes: np.ndarray
    direct: int | None
    noise_level: float
    threshold: float
    fs: float
    clipped: bool = False

    def __len__(self) -> int:
        return len(self.times)

    @property
    def found(self) -> bool:
        """False for an empty detection (a silent RIR, or nothing above the threshold)."""
        return len(self.times) > 0

    @property
    def samples(self) -> np.ndarray:
        """(K,) arrival times in (fractional) samples."""
        return self.times * self.fs

    def distances(self, c: float = SPEED_OF_SOUND) -> np.ndarray:
        """(K,) path lengths in metres, ``times * c`` (c in m/s)."""
        return self.times * float(c)


def detect_echoes(
    rir: ArrayLike,
    fs: float,
    *,
    excitation: ArrayLike | None = None,
    max_echoes: int | None = None,
    min_separation: float | None = None,
    threshold: float | None = None,
    noise_factor: float = 6.0,
    relative_threshold: float = 0.01,
    max_time: float | None = None,
    noise_window: tuple[float, float] | None = None,
    direct_fraction: float = 0.1,
    baseline: bool = True,
) -> EchoDetection:
    """Detect the echoes (arrivals) in one RIR (L,), or in a recording of ``excitation``.

    Args:
        rir: (L,) RIR samples; sample n is time n / fs. With ``excitation``, the recorded signal.
        fs: sampling rate, Hz.
        excitation: (E,) the emitted signal (a sweep, a click...): the recording is correlated with
            it, so echo times are measured from the start of the excitation. None: the RIR itself.
        max_echoes: keep at most this many: the direct path and the strongest others (None: all).
        min_separation: seconds; echoes closer than this are one echo (the stronger). Default:
            2 pulse widths: 2 samples without an excitation, more with a band-limited one (the
            width is the half-width of the envelope of its autocorrelation, relative to a sinc's).
        threshold: absolute detection threshold in RIR units; default
            ``max(noise_factor * noise_level, relative_threshold * peak)``.
        noise_factor: threshold in noise standard deviations (6: about 2e-9 false alarms per
            sample in Gaussian noise).
        relative_threshold: threshold as a fraction of the largest |sample| (usually the direct
            path) in the span searched.
        max_time: seconds; only echoes up to this time (None: the whole RIR).
        noise_window: (start, stop) seconds of a noise-only stretch (e.g. before the direct path
            or the far tail) to estimate the noise floor from; None: the whole span searched.
        direct_fraction: the direct path is the earliest echo with |amplitude| >= this fraction of
            the largest (which the direct path itself may not be: coincident reflections can add
            up to more); 0 makes it the first peak above the threshold.
        baseline: subtract a running median (+-10 ms) first, so that DC and slow drifts are not
            taken for echoes.

    Returns:
        An :class:`EchoDetection`. A silent RIR (all zeros) or one with nothing above the
        threshold gives an empty detection (``found`` False, ``direct`` None), never made-up
        echoes. A clipped RIR (3 or more consecutive samples at its largest |value|) gives a
        :class:`ClippedRirWarning` and ``clipped`` True, and is processed anyway: echo times
        near the clipped samples are less accurate.
    """
    x = _as_rir(rir, "rir")
    fs = _as_fs(fs)
    params = _Params.make(
        fs,
        excitation=excitation,
        max_echoes=max_echoes,
        min_separation=min_separation,
        threshold=threshold,
        noise_factor=noise_factor,
        relative_threshold=relative_threshold,
        max_time=max_time,
        noise_window=noise_window,
        direct_fraction=direct_fraction,
        baseline=baseline,
        length=len(x),
    )
    return _detect(x, params, "rir", stacklevel=3)


def detect_echoes_many(
    rirs: ArrayLike | Sequence[ArrayLike],
    fs: float,
    **kwargs: Any,
) -> list[EchoDetection]:
    """Detect the echoes in each of M RIRs of the same length: :func:`detect_echoes` per RIR.

    Args:
        rirs: (M, L) array, one RIR per row, or a list of M 1-D arrays of the same length L.
        fs: sampling rate, Hz.
        **kwargs: the keyword arguments of :func:`detect_echoes`, applied to every RIR (one
            excitation, the same thresholds...).

    Returns:
        M :class:`EchoDetection`, in the order of ``rirs``. Errors and warnings name the RIR as
        ``rirs[m]``.
    """
    unknown = sorted(set(kwargs) - _OPTIONS)
    if unknown:
        raise TypeError(f"detect_echoes_many() got an unexpected keyword argument {unknown[0]!r}")
    if isinstance(rirs, np.ndarray):
        if rirs.ndim != 2:
            raise InvalidInputError(
                f"rirs must have shape (M, L) (one RIR per row); got {shape_str(rirs.shape)}"
                + (" (use detect_echoes for one RIR)" if rirs.ndim == 1 else "")
            )
        rows = list(rirs)
    elif isinstance(rirs, Sequence) and not isinstance(rirs, str | bytes):
        rows = list(rirs)
        if rows and all(np.ndim(r) == 0 for r in rows):
            raise InvalidInputError(
                f"rirs must be M RIRs, (M, L); got a flat sequence of {len(rows)} numbers "
                "(use detect_echoes for one RIR)"
            )
    else:
        raise InvalidInputError(
            f"rirs must be an (M, L) array or a list of 1-D arrays; got {type(rirs).__name__}"
        )
    if not rows:
        raise InvalidInputError("rirs must hold at least one RIR; got none")
    xs = [_as_rir(r, f"rirs[{m}]") for m, r in enumerate(rows)]
    for m, x in enumerate(xs):
        if len(x) != len(xs[0]):
            raise InvalidInputError(
                f"rirs must all have the same length; rirs[{m}] has {len(x)} samples, "
                f"rirs[0] has {len(xs[0])}"
            )
    fs = _as_fs(fs)
    params = _Params.make(fs, length=len(xs[0]), **{**_DEFAULTS, **kwargs})
    out = []
    for m, x in enumerate(xs):
        out.append(_detect(x, params, f"rirs[{m}]", stacklevel=3))
    return out


# Keyword arguments of detect_echoes (and so of detect_echoes_many), with their defaults: the one
# place they are set (_Params.make takes every option explicitly).
_DEFAULTS = {
    name: p.default
    for name, p in inspect.signature(detect_echoes).parameters.items()
    if name not in ("rir", "fs")
}
_OPTIONS = frozenset(_DEFAULTS)


# ---- input checks -----------------------------------------------------------------------------


def _as_rir(value: ArrayLike, name: str) -> np.ndarray:
    x = as_float_array(value, name)
    if x.ndim != 1:
        raise InvalidInputError(f"{name} must have shape (L,) (one RIR); got {shape_str(x.shape)}")
    if len(x) < 3:
        raise InvalidInputError(f"{name} must hold at least 3 samples; got {len(x)}")
    bad = np.flatnonzero(~np.isfinite(x))
    if len(bad):
        raise InvalidInputError(f"{name} must be finite; sample {int(bad[0])} is {x[bad[0]]}")
    return x


def _as_fs(fs: object) -> float:
    return as_scalar(
        fs, "fs", low=0.0, low_open=True, high=MAX_FS,
        expected=f"a positive number of Hz, at most {MAX_FS:g}",
    )  # fmt: skip


def _as_real(value: object, name: str, *, low: float, high: float = math.inf) -> float:
    span = f">= {low:g}" if high == math.inf else f"in [{low:g}, {high:g}]"
    return as_scalar(
        value, name, low=low, high=None if high == math.inf else high,
        expected=f"a finite number {span}",
    )  # fmt: skip


@dataclass(frozen=True)
class _Params:
    """Checked settings shared by every RIR of a call, with the pulse model."""

    fs: float
    pulse: np.ndarray  # the pulse's samples at lags -q..q (q = len // 2), peak 1 at lag 0
    excitation: np.ndarray | None
    max_echoes: int | None
    separation: float  # samples
    width: float  # resolution of the pulse relative to the band-limited impulse's (>= 1)
    threshold: float | None
    noise_factor: float
    relative_threshold: float
    max_sample: float  # last time searched, in samples
    noise_span: tuple[int, int] | None
    direct_fraction: float
    baseline: bool

    @classmethod
    def make(
        cls,
        fs: float,
        *,
        length: int,
        excitation: ArrayLike | None,
        max_echoes: int | None,
        min_separation: float | None,
        threshold: float | None,
        noise_factor: float,
        relative_threshold: float,
        max_time: float | None,
        noise_window: tuple[float, float] | None,
        direct_fraction: float,
        baseline: bool,
    ) -> _Params:
        exc, pulse, width = _pulse_model(excitation)
        sep = 2.0 * width
        if max_echoes is not None and (
            isinstance(max_echoes, bool)
            or not isinstance(max_echoes, int | np.integer)
            or max_echoes < 1
        ):
            raise InvalidInputError(
                f"max_echoes must be an integer >= 1 or None; got {max_echoes!r}"
            )
        if min_separation is not None:
            sep = _as_real(min_separation, "min_separation", low=0.0) * fs
        if threshold is not None:
            threshold = _as_real(threshold, "threshold", low=0.0)
        noise_factor = _as_real(noise_factor, "noise_factor", low=0.0)
        relative_threshold = _as_real(relative_threshold, "relative_threshold", low=0.0, high=1.0)
        if relative_threshold == 1.0:
            raise InvalidInputError("relative_threshold must be below 1 (1 rejects every echo)")
        direct_fraction = _as_real(direct_fraction, "direct_fraction", low=0.0, high=1.0)
        max_sample = math.inf
        if max_time is not None:
            max_sample = _as_real(max_time, "max_time", low=0.0) * fs
        span = None if noise_window is None else _noise_span(noise_window, fs, length)
        return cls(
            fs=fs,
            pulse=pulse,
            excitation=exc,
            max_echoes=None if max_echoes is None else int(max_echoes),
            separation=sep,
            width=width,
            threshold=threshold,
            noise_factor=noise_factor,
            relative_threshold=relative_threshold,
            max_sample=max_sample,
            noise_span=span,
            direct_fraction=direct_fraction,
            baseline=as_flag(baseline, "baseline"),
        )


def _pulse_model(excitation: ArrayLike | None) -> tuple[np.ndarray | None, np.ndarray, float]:
    """The checked excitation (E,) (None: none), the pulse it gives (its normalised
    autocorrelation; the band-limited impulse's single sample without one) and the pulse's width
    relative to the band-limited impulse's (>= 1)."""
    if excitation is None:
        return None, np.ones(1), 1.0
    exc = as_float_array(excitation, "excitation")
    if exc.ndim != 1 or len(exc) == 0:
        raise InvalidInputError(
            f"excitation must have shape (E,) with E >= 1; got {shape_str(exc.shape)}"
        )
    bad = np.flatnonzero(~np.isfinite(exc))
    if len(bad):
        raise InvalidInputError(f"excitation must be finite; sample {int(bad[0])} is {exc[bad[0]]}")
    energy = float(exc @ exc)
    if energy == 0.0:
        raise InvalidInputError("excitation must not be all zeros")
    pulse = _autocorrelation(exc / math.sqrt(energy))
    return exc, pulse, max(1.0, _envelope_halfwidth(pulse) / _IMPULSE_HALFWIDTH)


def _noise_span(noise_window, fs: float, length: int) -> tuple[int, int]:
    """The samples [n0, n1) of ``noise_window`` (start, stop) seconds, at least 8 of ``length``."""
    what = "(start, stop) seconds with 0 <= start < stop"
    t0, t1 = as_pair(noise_window, "noise_window", expected=what)
    end = length / fs  # clipped first: t * fs of a huge t would overflow ceil and floor
    n0, n1 = math.ceil(min(max(t0, 0.0), end) * fs), math.floor(min(t1, end) * fs) + 1
    n1 = min(length, n1)
    if not 0 <= t0 < t1 or n1 - n0 < 8:
        raise InvalidInputError(
            f"noise_window must be {what}, covering at least 8 of the {length} samples; got "
            f"{noise_window!r} ({max(n1 - n0, 0)} samples)"
        )
    return n0, n1


def _envelope_halfwidth(pulse: np.ndarray) -> float:
    """Half-width at half maximum (samples) of the envelope |analytic signal| of a pulse peaking
    at its middle sample."""
    q = len(pulse) // 2
    env = np.abs(hilbert(np.concatenate([np.zeros(q), pulse, np.zeros(q)])))[2 * q :]
    env /= env[0]
    below = np.flatnonzero(env < 0.5)
    if not len(below):
        return float(q)
    k = int(below[0])
    return k - 1 + (env[k - 1] - 0.5) / (env[k - 1] - env[k])


def _autocorrelation(e: np.ndarray) -> np.ndarray:
    """Autocorrelation of a unit-energy signal at lags -q..q, cut where it has died out."""
    r = fftconvolve(e, e[::-1])
    mid = len(e) - 1
    r[mid] = 1.0
    big = np.flatnonzero(np.abs(r) > _PULSE_TAIL)
    q = min(max(mid - int(big[0]), int(big[-1]) - mid), _MAX_PULSE_HALF)
    return r[mid - q : mid + q + 1].copy()


# ---- detection --------------------------------------------------------------------------------


def _kernel(t: np.ndarray) -> np.ndarray:
    """The Hann-tapered sinc (band-limited interpolator and pulse), zero beyond +-_HALF samples."""
    return np.where(np.abs(t) < _HALF, np.sinc(t) * np.cos(np.pi * t / (2 * _HALF)) ** 2, 0.0)


# Window of samples (offsets from the integer peak) seen by the interpolator, and the kernel
# evaluated from each of them to every point of the search grid.
_TAPS = np.arange(-_HALF - _REACH, _HALF + _REACH + 1)
_GRID_U = np.linspace(-_REACH, _REACH, 2 * _REACH * _GRID + 1)
_GRID_K = _kernel(_GRID_U[:, None] - _TAPS[None, :])
_GRID_NORM = np.sqrt(np.sum(_GRID_K**2, axis=1))


def _refine(y: np.ndarray, m: int, pulse: np.ndarray) -> tuple[float, float]:
    """Sub-sample arrival near integer index m of padded y: (time in samples, signed amplitude).

    The time maximises |correlation with the pulse| / ||pulse||, the maximum-likelihood delay of
    a known pulse in white noise. Raw RIR: the pulse is the tapered sinc, so the correlation is
    the band-limited interpolation of y and the norm (which dips by ~2% between samples) is
    divided out. With an excitation, y already is the correlation of the recording with it (whose
    norm does not depend on the delay), so the time is the peak of y's interpolation. The
    amplitude is the least-squares fit of the pulse at that time.
    """
    w = y[m + _TAPS[0] : m + _TAPS[-1] + 1]
    f = np.abs(_GRID_K @ w)
    if len(pulse) == 1:
        f /= _GRID_NORM
    i = int(np.argmax(f))
    u = _GRID_U[i]
    if 0 < i < len(f) - 1:
        f0, f1, f2 = f[i - 1], f[i], f[i + 1]
        den = f0 - 2 * f1 + f2
        if den < 0:
            u += 0.5 * (f0 - f2) / den / _GRID
    tau = m + u
    start, vals = _pulse_at(pulse, tau)
    return tau, float(y[start : start + len(vals)] @ vals / (vals @ vals))


def _smooth(y: np.ndarray) -> np.ndarray:
    """(y[n-1] + 2 y[n] + y[n+1]) / 4 for the inner samples: a zero at the Nyquist frequency
    removes the alternating tails of band-limited pulses, which bias a running median."""
    return 0.25 * (y[:-2] + 2 * y[1:-1] + y[2:])


def _peak_magnitude(y: np.ndarray, m: int, reach: int = 1) -> float:
    """Largest |band-limited interpolation| of padded y within +-1 sample of index m, or its
    largest |sample| within +-reach."""
    near = float(np.abs(y[m - reach : m + reach + 1]).max())
    return max(near, float(np.abs(_GRID_K @ y[m + _TAPS[0] : m + _TAPS[-1] + 1]).max()))


def _pulse_at(pulse: np.ndarray, tau: float) -> tuple[int, np.ndarray]:
    """The pulse delayed by tau samples, sampled: (first index, values)."""
    q = len(pulse) // 2
    m = math.floor(tau)
    start = m - q - _HALF
    n = np.arange(start, m + q + _HALF + 2)
    if len(pulse) == 1:
        return start, _kernel(n - tau)
    kern = _kernel(np.arange(-_HALF, _HALF + 2) - (tau - m))
    # sum_k pulse[k] kern(n - tau - k) for n - m in [-q - HALF, q + HALF + 1]
    return start, np.convolve(pulse, kern)[: len(n)]


def clip_run(x: np.ndarray) -> tuple[int, int]:
    """Longest run of consecutive samples at the largest |x|: (length, first index)."""
    mag = np.abs(x)
    top = mag.max()
    if top == 0:
        return 0, 0
    at = np.concatenate([[0], (mag == top).astype(np.int8), [0]])
    edges = np.flatnonzero(np.diff(at))
    starts, stops = edges[::2], edges[1::2]
    k = int(np.argmax(stops - starts))
    return int(stops[k] - starts[k]), int(starts[k])


def _detect(x: np.ndarray, p: _Params, name: str, *, stacklevel: int) -> EchoDetection:
    """Detect the echoes in one checked RIR x (L,); ``name`` is its name in messages."""
    run, at = clip_run(x)
    clipped = run >= CLIP_RUN
    if clipped:
        warnings.warn(
            f"{name} looks clipped: {run} consecutive samples from sample {at} are at its largest "
            f"magnitude {abs(x[at]):.6g}; echo times near them are unreliable",
            ClippedRirWarning,
            stacklevel=stacklevel,
        )
    length = len(x)
    y = _filtered(x, p)
    last = length - 1 if p.max_sample >= length else math.floor(p.max_sample) + _REACH
    span = y[: last + 1]
    peak = float(np.abs(span).max())
    noisy = span if p.noise_span is None else y[p.noise_span[0] : p.noise_span[1]]
    noise = MAD_TO_STD * float(np.median(np.abs(noisy - np.median(noisy))))
    if p.threshold is not None:
        thr = p.threshold
    else:
        thr = max(p.noise_factor * noise, p.relative_threshold * peak)
    found = EchoDetection(
        times=frozen(np.zeros(0)),
        amplitudes=frozen(np.zeros(0)),
        direct=None,
        noise_level=noise,
        threshold=thr,
        fs=p.fs,
        clipped=clipped,
    )
    if peak == 0.0 or peak <= thr:
        return found
    # zero padding so that windows around any sample (and pulses) fit
    pad = len(p.pulse) // 2 + _HALF + _REACH + 4
    r = np.concatenate([np.zeros(pad), y, np.zeros(pad)])
    kept = _greedy_echoes(r, pad, np.abs(span), length, p, thr)
    _refit_echoes(r, kept, p.pulse)
    kept = [e for e in kept if e[0] - pad <= p.max_sample and abs(e[1]) > thr]
    if not kept:
        return found
    times, amps, direct = _direct_and_strongest(kept, pad, p)
    return replace(found, times=frozen(times), amplitudes=frozen(amps), direct=direct)


def _filtered(x: np.ndarray, p: _Params) -> np.ndarray:
    """(L,) the RIR correlated with the excitation (lags >= 0, excitation-energy units; x itself
    without one), its slowly varying baseline removed when ``p.baseline``."""
    length = len(x)
    if p.excitation is None:
        y = x
    else:
        # lag n >= 0 of the correlation with the excitation, in excitation-energy units
        e = p.excitation
        y = fftconvolve(x, e[::-1])[len(e) - 1 :] / float(e @ e)
        y = y[:length]
    if p.baseline:
        # a slowly varying offset (DC, a high-pass filter's undershoot) is no echo
        half = max(math.ceil(_BASELINE_WIDTHS * p.width), math.ceil(_BASELINE_TIME * p.fs))
        y = y - median_filter(
            _smooth(np.concatenate([y[:1], y, y[-1:]])), size=2 * half + 1, mode="mirror"
        )
    return y


def _greedy_echoes(r, pad: int, mag, length: int, p: _Params, thr: float) -> list[list[float]]:
    """Strongest candidate first, each echo fitted (:func:`_refine`) and its pulse subtracted
    from the zero-padded signal ``r`` (in place), unless too close to a stronger echo or no bigger
    than a stronger one's misfit and side lobes (module docstring, step 5). Returns
    [[time in padded samples, amplitude]]."""
    cand, _ = find_peaks(
        np.concatenate([[0.0], mag, [0.0]]),
        height=np.nextafter(thr, np.inf),
        distance=max(1, math.floor(p.separation)),
    )
    cand = cand - 1
    cand = cand[np.argsort(-mag[cand], kind="stable")]
    # how far from an echo's peak its misfit is looked for: its main lobe, within the separation
    reach = max(1, min(math.ceil(p.separation), math.ceil(2 * p.width)))
    kept: list[list[float]] = []  # [time in padded samples, amplitude]
    misfit: list[float] = []  # |residual| left at each kept echo's peak
    for c in cand:
        lo = pad + max(c - _REACH, 0)
        m = lo + int(np.argmax(np.abs(r[lo : pad + min(c + _REACH, length - 1) + 1])))
        tau, amp = _refine(r, m, p.pulse)
        if abs(amp) <= thr or tau - pad > p.max_sample or tau < pad - 0.5:
            continue
        if kept:
            dist = np.abs(tau - np.array([e[0] for e in kept]))
            widths = np.maximum(dist / p.width, 1.0)
            # too close to a stronger echo, or no bigger than what a slightly wrong pulse of one
            # would leave here (module docstring, step 5)
            if np.any(dist < p.separation) or np.any(
                abs(amp)
                <= (_GUARD * np.array(misfit) + _TAILS * np.abs([e[1] for e in kept]) / np.pi)
                / widths
            ):
                continue
        _add_pulse(r, p.pulse, tau, -amp)
        kept.append([tau, amp])
        misfit.append(_peak_magnitude(r, round(tau), reach))
    return kept


def _refit_echoes(r, kept: list[list[float]], pulse: np.ndarray) -> None:
    """One more pass: each echo of ``kept`` refined again (in place) with every other pulse
    subtracted from ``r``; a refit that moves more than _REACH samples is not taken."""
    for e in kept:
        _add_pulse(r, pulse, e[0], e[1])
        tau, amp = _refine(r, round(e[0]), pulse)
        if abs(tau - e[0]) <= _REACH:
            e[0], e[1] = tau, amp
        else:
            tau, amp = e
        _add_pulse(r, pulse, tau, -amp)


def _direct_and_strongest(kept, pad: int, p: _Params) -> tuple[np.ndarray, np.ndarray, int]:
    """Times (s, ascending) and amplitudes of the echoes, the index of the direct path (the
    earliest with ``direct_fraction`` of the largest amplitude), at most ``max_echoes`` kept
    (the direct path and the strongest others)."""
    times = np.array([e[0] - pad for e in kept]) / p.fs
    amps = np.array([e[1] for e in kept])
    order = np.argsort(times, kind="stable")
    times, amps = times[order], amps[order]
    big = np.abs(amps) >= p.direct_fraction * np.abs(amps).max()
    direct = int(np.argmax(big))
    if p.max_echoes is not None and len(times) > p.max_echoes:
        others = np.delete(np.arange(len(times)), direct)
        strongest = others[np.argsort(-np.abs(amps[others]), kind="stable")[: p.max_echoes - 1]]
        keep = np.sort(np.concatenate([[direct], strongest]))
        direct = int(np.searchsorted(keep, direct))
        times, amps = times[keep], amps[keep]
    return times, amps, direct


def _add_pulse(r: np.ndarray, pulse: np.ndarray, tau: float, amp: float) -> None:
    """r += amp * pulse(. - tau), in place (r zero-padded wide enough)."""
    start, vals = _pulse_at(pulse, tau)
    r[start : start + len(vals)] += amp * vals
