"""What is wrong with RIRs before a room is estimated from them, named: the screen of silent and
clipped RIRs (:func:`screen_rirs`), and the check of the direct paths against the microphones
(:func:`check_direct_paths`) that names a delay before the emission, a wrong sampling rate or
microphones not in metres.

The check rests on eq. (2) of the paper with the range written as c t: at a known array, the
direct-path times t_i of one loudspeaker s obey ||s - m_i|| = c t_i - b with b = 0 when sample 0
is the emission. Fitted with c and b free (five unknowns; six microphones or more), three things
the pipeline would otherwise absorb show up on their own:

- b != 0, the same for every microphone: a delay common to every path (a recorder started before
  the loudspeaker played; pyroomacoustics delays every RIR by its fractional-delay filter's half
  length, ``pra.constants.get('frac_delay_length') // 2`` = 40 samples). With c free and b = 0
  the fit bends c and the loudspeaker to absorb it: 40 samples at 48 kHz (286 mm) gave c =
  257-347 m/s in the demo's shoebox and cut-corner room (8 microphones, reflection order 2, seeds
  868969, 404257, 682562; ``benchmarks/bench_run_input_sanity.py`` builds such files), and in
  the cut-corner room of seed 682562 the pipeline then labelled a consistent subset of the echoes
  (the direct path at 6 of 8 microphones) and converged with a wall 1.0 m off: without a known
  noise level its verdict took the 2.3 mm RMS residual of the walls' fit for noise. Named, with
  the option that estimates it (``unknown_emission``, ``rangeslam run --unknown-emission``).
- c / c_given a ratio of two common sampling rates: ``fs`` states another rate than the RIRs'
  (48 kHz RIRs labelled 16 kHz give c = 343 / 3 = 114.3 m/s). Named even where the pipeline's own
  estimate of c absorbed it and the walls came out right (labelled 44.1 kHz): the c reported,
  315 m/s, and every time in seconds are then wrong.
- c / c_given = 1000, 100 (or the inch's, the foot's): microphones in millimetres, centimetres.

A delay or a speed is only named when it is beyond its own noise (the two-sided
:data:`~rangeslam.verdict.thresholds.CHI2_LEVEL` quantile of Student's t with the fit's n - 5
degrees of freedom times its standard deviation): a compact array, which barely tells c from b,
or poorly timed direct paths name nothing.
"""

from __future__ import annotations

import enum
import itertools
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rangeslam.acoustics.echoes import CLIP_RUN, ClippedRirWarning, EchoDetection, clip_run
from rangeslam.datasets.rir_files import SilentRirWarning
from rangeslam.errors import InvalidInputError
from rangeslam.status import Status
from rangeslam.verdict.thresholds import CHI2_LEVEL

__all__ = [
    "COMMON_RATES",
    "DELAY_FLOOR",
    "FIT_RTOL",
    "MIN_DIRECT_PATHS",
    "DirectPathFit",
    "InputCause",
    "InputCheck",
    "RirScreen",
    "check_direct_paths",
    "check_rirs_input",
    "check_screens",
    "consistent_fit",
    "fit_direct_paths",
    "fits_one_source",
    "screen_rirs",
    "with_input_checks",
]

#: Sampling rates, Hz, that RIRs are commonly recorded or simulated at: a fitted c that is the
#: given c times ``fs / rate`` for one of them names ``fs``.
COMMON_RATES = (
    8000, 11025, 12000, 16000, 22050, 24000, 32000, 44100, 48000, 88200, 96000, 176400, 192000,
)  # fmt: skip
#: Units microphones are mistakenly given in, with the factor they scale metres by.
UNIT_FACTORS = (("millimetres", 1000.0), ("centimetres", 100.0), ("inches", 1 / 0.0254),
                ("feet", 1 / 0.3048))  # fmt: skip
#: A fitted c within this fraction of the given c is the air's (0 to 40 degrees C is 331-355 m/s,
#: within 3.4 % of 343); beyond it, a ratio of rates or units is looked for.
C_TOLERANCE = 0.05
#: How close (relative) c / c_given must come to a ratio of rates or a unit factor to be named:
#: about the air's own spread around 343 m/s (10 to 30 degrees C is 337-349 m/s, 1.7 %).
MATCH_RTOL = 0.02
#: Beyond this fraction from the given c, a c that no rate or unit explains is still named (the
#: limit of ``estimate_sound_speed``, which refuses such a c).
C_FAR = 0.1
#: Metres of path: a common delay shorter than this is not named. A delay moved the walls by 2-3
#: times its path while the run still converged (``rangeslam simulate room --seed 868969 --order
#: 2``, the RIRs delayed with ``shift_signals``: 0.5 sample at 48 kHz, 3.6 mm, put a wall 9.9 mm
#: off; 1 sample, 19.1 mm), so 1 mm keeps them within about 3 mm.
DELAY_FLOOR = 1e-3
#: Direct paths the check needs: five unknowns (s, c, b), one more to measure the noise.
MIN_DIRECT_PATHS = 6
#: RMS residual of a fit of the direct paths, as a fraction of the array's RMS radius, beyond which
#: it explains nothing (:func:`fits_one_source`). The dEchorate RIRs' direct paths fit to 0.24 %
#: (3.5 mm of a 1.46 m array; simulated ones to 1e-6). Uniform random times at 8 microphones
#: passed 2 % (the verdict's RELATIVE_RMS) in 4 of 400 draws and were named a cause; 0.5 % in none.
FIT_RTOL = 0.005
#: Direct paths the check may leave out as wrong picks (:func:`consistent_fit`).
MAX_LEFT_OUT = 2
#: Samples pyroomacoustics delays every RIR by (``frac_delay_length // 2`` with its default
#: fractional-delay filter of 81 taps), named when a delay comes within half a sample of it.
PYROOMACOUSTICS_DELAY = 40


# ---- the screen: silent and clipped RIRs --------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RirScreen:
    """The RIRs the pipeline sees, and which were left out: rirs (M, L) with masked rows zeroed;
    silent, clipped, masked (M,) bool; ``clipped_mode`` "mask" or "use"."""

    rirs: np.ndarray
    silent: np.ndarray
    clipped: np.ndarray
    masked: np.ndarray
    clipped_mode: str


# Why clipped RIRs are masked by default: a flat top of 4 samples on the direct path of one RIR
# of ten moved its range by 1 cm and the loudspeaker by 4 cm (from 0.01 mm), with the labelling
# and the reconstruction still converged (their residual tests do not see an error that size from
# a compact array); so it is left out rather than passed on as a converged answer.
def screen_rirs(x: np.ndarray, clipped: str) -> RirScreen:
    """Find silent and clipped RIRs in ``x`` (M, L), warn about each (stack level: the caller of
    the function calling this one), and zero the rows left out (a row of zeros: no detection, a
    masked row). ``clipped``: "mask" or "use"."""
    m = x.shape[0]
    if clipped not in ("mask", "use"):
        raise InvalidInputError(f"clipped must be 'mask' or 'use'; got {clipped!r}")
    silent = ~np.any(x != 0, axis=1)
    if silent.all():
        raise InvalidInputError(f"rirs are all silent: every sample of the {m} RIRs is 0")
    for i in np.flatnonzero(silent):
        warnings.warn(
            f"rirs[{i}] is silent (every sample is 0): no range from it, its row is masked",
            SilentRirWarning,
            stacklevel=3,
        )
    runs = [clip_run(r) for r in x]
    is_clipped = np.array([n >= CLIP_RUN for n, _ in runs], dtype=bool)
    masked = silent | (is_clipped if clipped == "mask" else False)
    if clipped == "mask":
        for i in np.flatnonzero(is_clipped):
            n, at = runs[i]
            warnings.warn(
                f"rirs[{i}] looks clipped: {n} consecutive samples from sample {at} are at its "
                f"largest magnitude {abs(x[i, at]):.6g}; its row is masked (clipped='use' keeps "
                "it, with less accurate echo times near those samples)",
                ClippedRirWarning,
                stacklevel=3,
            )
        if masked.all():
            raise InvalidInputError(
                f"rirs: every one of the {m} RIRs is silent or clipped; pass clipped='use' to "
                "use the clipped ones"
            )
        x = np.where(masked[:, None], 0.0, x)
    return RirScreen(x, silent, is_clipped, np.asarray(masked, dtype=bool), clipped)


# ---- the direct paths: ||s - m_i|| = c t_i - b ---------------------------------------------------


@dataclass(frozen=True, eq=False)
class DirectPathFit:
    """Least squares of ||s - m_i|| = c t_i - b over the n direct paths (:func:`fit_direct_paths`).

    Attributes:
        source: (3,) metres. c: m/s. delay_path: b, metres (0 when not fitted): the path a
            common delay adds, b / c seconds.
        c_std, delay_path_std: their standard deviations (m/s, metres; NaN for b when not fitted,
            inf when the fit does not determine them), from the residuals' own scale.
        residual_rms: metres. n: direct paths used. dof: n minus the unknowns.
    """

    source: np.ndarray
    c: float
    delay_path: float
    c_std: float
    delay_path_std: float
    residual_rms: float
    n: int
    dof: int


def _linear_start(mics: np.ndarray, t: np.ndarray, c0: float, free_delay: bool) -> np.ndarray:
    """(s, c, b) from the linear equations ||s - m||^2 = (c t - b)^2 expand to: 2 m.s - u + v t^2
    - 2 w t = ||m||^2 with u = ||s||^2 - b^2, v = c^2, w = c b (w = 0 with b fixed at 0); the
    microphones centred. c0 and b = 0 when v is not positive."""
    centre = mics.mean(axis=0)
    m = mics - centre
    cols = [2 * m, -np.ones((len(t), 1)), t[:, None] ** 2]
    if free_delay:
        cols.append(-2 * t[:, None])
    z = np.linalg.lstsq(np.hstack(cols), np.sum(m**2, axis=1), rcond=None)[0]
    if not (z[4] > 0 and np.isfinite(z).all()):
        return np.array([*centre, c0, 0.0])
    c = float(np.sqrt(z[4]))
    return np.array([*(z[:3] + centre), c, z[5] / c if free_delay else 0.0])


def fit_direct_paths(
    times: np.ndarray, mics: np.ndarray, *, c0: float, free_delay: bool = True
) -> DirectPathFit:
    """Gauss-Newton on r_i = ||s - m_i|| - c t_i + b over (s, c, b) (b fixed at 0 unless
    ``free_delay``), from the linear solution. ``times``: (n,) seconds from sample 0; ``mics``:
    (n, 3) metres, n at least 6 (5 without the delay); ``c0``: m/s, the start when the linear
    solution has none."""
    t = np.asarray(times, dtype=float)
    mics = np.asarray(mics, dtype=float)
    cols = [0, 1, 2, 3, 4] if free_delay else [0, 1, 2, 3]
    x = _linear_start(mics, t, c0, free_delay)

    def model(x):
        d = x[:3] - mics
        dist = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        jac = np.column_stack([d / dist[:, None], -t, np.ones_like(t)])[:, cols]
        return dist - x[3] * t + x[4], jac

    for _ in range(50):
        r, jac = model(x)
        step = np.linalg.lstsq(jac, -r, rcond=None)[0]
        x[cols] += step
        if not np.all(np.isfinite(x)) or np.abs(step).max() <= 1e-12 * max(1.0, abs(x[3])):
            break
    r, jac = model(x)
    dof = len(t) - len(cols)
    std = np.full(5, np.nan)
    try:
        cov = float(r @ r) / max(dof, 1) * np.linalg.inv(jac.T @ jac)
        std[cols] = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        std[cols] = np.inf
    return DirectPathFit(
        source=x[:3].copy(), c=float(x[3]), delay_path=float(x[4]), c_std=float(std[3]),
        delay_path_std=float(std[4]), residual_rms=float(np.sqrt(np.mean(r**2))), n=len(t),
        dof=dof,
    )  # fmt: skip


def fits_one_source(fit: DirectPathFit, mics: np.ndarray) -> bool:
    """The fit explains its direct paths: c positive and finite, and an RMS residual at most
    :data:`FIT_RTOL` of the array (the RMS distance of the
    microphones from their centroid; not the fitted loudspeaker's, which a fit of wrong times puts
    far away), in the fit's own units."""
    if not (np.isfinite(fit.c) and fit.c > 0 and np.isfinite(fit.delay_path)):
        return False
    scene = float(np.sqrt(np.mean(np.sum((mics - mics.mean(axis=0)) ** 2, axis=1))))
    return bool(fit.residual_rms <= FIT_RTOL * scene)


def consistent_fit(
    times: np.ndarray, mics: np.ndarray, *, c0: float
) -> tuple[DirectPathFit | None, np.ndarray]:
    """(fit with c and b free, (n,) bool: the direct paths it kept) of the most direct paths that
    :func:`fits_one_source`: all of them, else the best fit without one, without two (at most
    :data:`MAX_LEFT_OUT`, and at least MIN_DIRECT_PATHS + 1 kept so that two degrees of freedom
    measure the noise); (None, all False) when none fits. A wrong pick (a noise peak taken for the
    direct path) made the fit of 8 paths give c = 72 +- 78 m/s, 0.16 m RMS (shoebox, 16 kHz, noise
    5 % of the peak, seed 806744); without it, every path fitted to 0.1 mm."""
    n = len(times)
    for drop in range(max(0, min(MAX_LEFT_OUT, n - MIN_DIRECT_PATHS - 1)) + 1):
        best, kept = None, np.zeros(n, dtype=bool)
        for out in itertools.combinations(range(n), drop):
            keep = np.ones(n, dtype=bool)
            keep[list(out)] = False
            fit = fit_direct_paths(times[keep], mics[keep], c0=c0)
            if fits_one_source(fit, mics[keep]) and (
                best is None or fit.residual_rms < best.residual_rms
            ):
                best, kept = fit, keep
        if best is not None:
            return best, kept
    return None, np.zeros(n, dtype=bool)


# ---- the check ---------------------------------------------------------------------------------


class InputCause(enum.Enum):
    """What :func:`check_direct_paths` found wrong with the input."""

    #: A delay common to every direct path: sample 0 is not the emission.
    DELAY = "delay"
    #: The sampling rate stated is not the RIRs'.
    FS = "fs"
    #: The microphone positions are not in metres.
    UNITS = "units"
    #: c from the direct paths far from the c given, and no rate or unit explains it.
    SPEED = "speed"


@dataclass(frozen=True, eq=False)
class InputCheck:
    """Result of :func:`check_direct_paths`: what the direct paths say of the input.

    Attributes:
        causes: what was found wrong, most telling first (empty: nothing).
        status: CONVERGED when nothing was found; INCONSISTENT for a delay (the direct paths do
            not fit an emission at sample 0); OUT_OF_RANGE for fs, units or speed (c outside
            its physical range).
        message: one line naming the cause and what to do ("" when nothing was found).
        c: m/s, fitted from the direct paths (NaN when not checked). c_std: m/s.
        delay: seconds from sample 0 to the emission the direct paths share (NaN when not
            checked). delay_std: seconds.
        likely_fs: Hz, the common rate the RIRs look sampled at (FS), else None.
        unit: the unit the microphones look given in (UNITS), else None.
        n_used: direct paths fitted. note: why nothing was checked ("" when checked).
    """

    causes: tuple[InputCause, ...] = ()
    status: Status = Status.CONVERGED
    message: str = ""
    c: float = float("nan")
    c_std: float = float("nan")
    delay: float = float("nan")
    delay_std: float = float("nan")
    likely_fs: float | None = None
    unit: str | None = None
    n_used: int = 0
    note: str = ""

    @property
    def ok(self) -> bool:
        """True when nothing was found wrong."""
        return not self.causes


def _beyond_noise(value: float, std: float, dof: int) -> bool:
    """|value| beyond the two-sided CHI2_LEVEL quantile of Student's t (``dof``) times ``std``."""
    from scipy.stats import t as student

    limit = float(student.ppf(0.5 + CHI2_LEVEL / 2, max(dof, 1))) * std
    return bool(np.isfinite(limit) and abs(value) > limit)


def _direct_times(detections: Sequence[EchoDetection]) -> np.ndarray:
    """(M,) direct-path times, seconds from sample 0 (NaN where none)."""
    return np.array(
        [d.times[d.direct] if d.found and d.direct is not None else np.nan for d in detections],
        dtype=float,
    )


def check_direct_paths(
    detections: Sequence[EchoDetection],
    mics: np.ndarray,
    fs: float,
    *,
    c: float,
    emission_known: bool = True,
) -> InputCheck:
    """What the direct paths of one loudspeaker say of the input (the module docstring).

    Args:
        detections: M :class:`~rangeslam.acoustics.echoes.EchoDetection` of the RIRs as given.
        mics: (M, 3) microphone positions, metres. fs: the sampling rate stated, Hz.
        c: the speed of sound given, m/s.
        emission_known: sample 0 is taken for the emission (a common delay is then a cause);
            False when the delay is estimated anyway (``unknown_emission``): fs and units only.

    Returns:
        An :class:`InputCheck`; nothing found, with the reason in ``note``, when fewer than
        :data:`MIN_DIRECT_PATHS` microphones have a direct path or no subset of them fits
        (:func:`consistent_fit`).
    """
    t = _direct_times(detections)
    ok = np.isfinite(t)
    n = int(ok.sum())
    if n < MIN_DIRECT_PATHS:
        note = f"input not checked: {n} direct paths, {MIN_DIRECT_PATHS} needed"
        return InputCheck(n_used=n, note=note)
    free, keep = consistent_fit(t[ok], np.asarray(mics, dtype=float)[ok], c0=c)
    if free is None:
        note = (
            f"input not checked: no {max(MIN_DIRECT_PATHS + 1, n - MAX_LEFT_OUT)} of the {n} "
            "direct paths fit one loudspeaker"
        )
        return InputCheck(n_used=n, note=note)
    t, pts, n = t[ok][keep], np.asarray(mics, dtype=float)[ok][keep], int(keep.sum())
    delayed = _beyond_noise(free.delay_path, free.delay_path_std, free.dof) and (
        abs(free.delay_path) > DELAY_FLOOR * abs(free.c) / c  # the floor in the fit's units
    )
    speed = free
    if emission_known and not delayed:  # the model asserted, b = 0, unless it fits worse
        fixed = fit_direct_paths(t, pts, c0=c, free_delay=False)
        speed = fixed if fits_one_source(fixed, pts) else free
    delay = free.delay_path / free.c
    delay_std = float(np.hypot(free.delay_path_std, delay * free.c_std) / abs(free.c))
    causes, parts = [], []
    cause, text, likely, unit, explained = _speed_cause(speed, fs, c, all_paths=bool(keep.all()))
    if cause is not None:
        causes.append(cause)
        parts.append(text)
    if delayed and emission_known and explained:  # a delay with c that nothing explains: junk
        causes.append(InputCause.DELAY)
        parts.append(_delay_text(delay * fs, likely or fs, c))
    if not causes:
        return InputCheck(c=speed.c, c_std=speed.c_std, delay=delay, delay_std=delay_std, n_used=n)
    status = Status.INCONSISTENT if causes[0] is InputCause.DELAY else Status.OUT_OF_RANGE
    return InputCheck(
        causes=tuple(causes), status=status, message="; ".join(parts), c=speed.c,
        c_std=speed.c_std, delay=delay, delay_std=delay_std, likely_fs=likely, unit=unit,
        n_used=n,
    )  # fmt: skip


def _delay_text(samples: float, rate: float, c: float) -> str:
    """The sentence naming a common delay of ``samples``, in seconds and metres at ``rate`` Hz
    (the RIRs' rate: the stated fs, or the likely one when fs looks wrong) and ``c`` m/s."""
    delay = samples / rate
    pra = (
        "; pyroomacoustics adds pra.constants.get('frac_delay_length') // 2 = "
        f"{PYROOMACOUSTICS_DELAY} to every RIR"
        if abs(samples - PYROOMACOUSTICS_DELAY) < 0.5
        else ""
    )
    how = "late" if samples > 0 else "early (the RIRs start after the emission)"
    return (
        f"sample 0 is not the emission: every direct path is {abs(samples):.2f} samples {how} "
        f"({abs(delay) * 1e3:.4g} ms, {abs(delay) * c * 1e3:.1f} mm at {rate:g} Hz and {c:g} m/s"
        f"{pra}); run with --unknown-emission (unknown_emission=True), which estimates it, or "
        "take it out of the RIRs"
    )


def _speed_cause(fit: DirectPathFit, fs: float, c: float, *, all_paths: bool):
    """(cause or None, its sentence, likely fs or None, unit or None, explained) from the fitted
    c: ``explained`` when c is the air's (within C_TOLERANCE of ``c``) or a rate's or a unit's.
    SPEED, a c far off that nothing explains, only from ``all_paths`` (none left out: a fit of
    7 wrong times of 8 can fit a loudspeaker with any c)."""
    q = fit.c / c
    if not np.isfinite(q) or abs(q - 1) <= C_TOLERANCE:
        return None, "", None, None, bool(np.isfinite(q))
    if not _beyond_noise(fit.c - c, fit.c_std, fit.dof):
        return None, "", None, None, False
    head = (
        f"the direct paths give c = {fit.c:.4g} +- {fit.c_std:.2g} m/s, {q:.4g} x the {c:g} m/s "
        "given"
    )
    rates = [r for r in COMMON_RATES if r != fs and abs(q * r / fs - 1) <= MATCH_RTOL]
    units = [(u, k) for u, k in UNIT_FACTORS if abs(q / k - 1) <= MATCH_RTOL]
    if rates:
        rate = float(min(rates, key=lambda r: abs(q * r / fs - 1)))
        return InputCause.FS, (
            f"fs = {fs:g} Hz looks wrong: {head} ({fs:g} / {rate:g}), as RIRs sampled at "
            f"{rate:g} Hz labelled {fs:g} Hz would; give the RIRs' own rate (nothing is resampled)"
        ), rate, None, True  # fmt: skip
    if units:
        unit = min(units, key=lambda uk: abs(q / uk[1] - 1))[0]
        return InputCause.UNITS, (
            f"the microphone positions look like {unit}, not metres: {head}; give them in metres"
        ), None, unit, True  # fmt: skip
    if abs(q - 1) > C_FAR and all_paths:
        return InputCause.SPEED, (
            f"{head}: check fs ({fs:g} Hz), the microphones' units (metres) and c"
        ), None, None, False  # fmt: skip
    return None, "", None, None, False


def check_rirs_input(
    rirs: np.ndarray,
    fs: float,
    mics: np.ndarray,
    *,
    c: float,
    detect_options: dict[str, Any] | None = None,
    emission_known: bool = True,
) -> InputCheck:
    """:func:`check_direct_paths` on the detections of ``rirs`` (M, L) (``detect_echoes_many``
    with ``detect_options``, its warnings left to the pipeline that follows; ``max_time``, a time
    from the emission, not applied when the emission is unknown)."""
    from rangeslam.acoustics.echoes import detect_echoes_many

    opts = dict(detect_options or {})
    if not emission_known:
        opts.pop("max_time", None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        dets = detect_echoes_many(rirs, fs, **opts)
    return check_direct_paths(dets, mics, fs, c=c, emission_known=emission_known)


def with_input_checks(result: Any, checks: Sequence[InputCheck] | None) -> Any:
    """``result`` (a ``RunResult``) with ``input_checks``, one per loudspeaker; when one found
    something, its status and its message leading the result's (``loudspeaker j:`` before it
    with several). None: ``result`` as it is."""
    if checks is None:
        return result
    checks = tuple(checks)
    bad = [(j, k) for j, k in enumerate(checks) if not k.ok]
    if not bad:
        return replace(result, input_checks=checks)
    many = len(checks) > 1
    lead = [f"loudspeaker {j}: {k.message}" if many else k.message for j, k in bad]
    return replace(
        result,
        status=bad[0][1].status,
        message="; ".join([*lead, result.message]),
        input_checks=checks,
    )


def check_screens(
    screens: Sequence[RirScreen],
    fs: float,
    mics: np.ndarray,
    *,
    c: float,
    detect_options: dict[str, Any] | None = None,
    emission_known: bool = True,
) -> tuple[InputCheck, ...]:
    """:func:`check_rirs_input` on each loudspeaker's screened RIRs, the clipped ones left out
    too (used or not, their direct peak is mistimed)."""
    return tuple(
        check_rirs_input(
            np.where((s.silent | s.clipped)[:, None], 0.0, s.rirs), fs, mics, c=c,
            detect_options=detect_options, emission_known=emission_known,
        )
        for s in screens
    )  # fmt: skip
