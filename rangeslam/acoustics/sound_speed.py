"""The speed of sound from the direct paths heard by a known microphone array.

With the emission at t = 0 (sample 0 of every RIR) and the microphones known, the direct-path
times t_i fix the loudspeaker s and the speed c together: ||s - m_i|| = c t_i (eq. 2 of the paper
with the range written as c t), four unknowns, so five or more microphones over-determine them.
:func:`estimate_sound_speed` fits (s, c) by least squares (SR-LS multilateration at the given c
to start), and reports c with its standard deviation sigma^2 (J^T J)^-1 from the residuals' own
scale (sigma estimated with M - 4 degrees of freedom).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_points, check_positive, frozen
from rangeslam.acoustics.echoes import EchoDetection
from rangeslam.localization.multilateration import multilaterate
from rangeslam.status import HasStatus, Status

__all__ = ["MIN_MICS_FOR_C", "SoundSpeedEstimate", "estimate_sound_speed"]

#: Microphones with a direct path needed: four unknowns (s, c), two more to test the fit.
MIN_MICS_FOR_C = 6


@dataclass(frozen=True, eq=False)
class SoundSpeedEstimate(HasStatus):
    """Result of :func:`estimate_sound_speed`.

    Attributes:
        c: m/s, the estimate (the starting value when not converged).
        c_std: m/s, its standard deviation (inf when not converged).
        source: (3,) the loudspeaker fitted with it, metres.
        residual_rms: metres, RMS of ||s - m_i|| - c t_i over the microphones used.
        n_used: microphones with a direct path.
        status: CONVERGED; NOT_IDENTIFIABLE (too few direct paths, a singular fit);
            OUT_OF_RANGE (c more than ``max_change`` from the start). message: what happened.
    """

    c: float
    c_std: float
    source: np.ndarray
    residual_rms: float
    n_used: int
    status: Status
    message: str


def _direct_times(detections: Sequence[EchoDetection]) -> tuple[np.ndarray, np.ndarray]:
    """(M,) direct-path times, seconds (NaN where none), and (M,) bool: found."""
    t = np.array(
        [d.times[d.direct] if d.found and d.direct is not None else np.nan for d in detections],
        dtype=float,
    )
    return t, np.isfinite(t)


def _fit(mics: np.ndarray, t: np.ndarray, s0: np.ndarray, c0: float):
    """Gauss-Newton on r_i = ||s - m_i|| - c t_i over (s, c); (s, c, residuals, J)."""
    x = np.append(s0, c0)
    for _ in range(20):
        d = x[:3] - mics
        dist = np.linalg.norm(d, axis=1)
        r = dist - x[3] * t
        jac = np.column_stack([d / dist[:, None], -t])
        step = np.linalg.lstsq(jac, -r, rcond=None)[0]
        x = x + step
        if np.abs(step).max() < 1e-12 * max(1.0, abs(x[3])):
            break
    d = x[:3] - mics
    dist = np.linalg.norm(d, axis=1)
    return x[:3], float(x[3]), dist - x[3] * t, np.column_stack([d / dist[:, None], -t])


def estimate_sound_speed(
    detections: Sequence[EchoDetection],
    mics: ArrayLike,
    *,
    c0: float,
    max_change: float = 0.1,
) -> SoundSpeedEstimate:
    """The speed of sound and the loudspeaker from the M detections' direct paths.

    Args:
        detections: M :class:`~rangeslam.acoustics.echoes.EchoDetection`, t = 0 the emission.
        mics: (M, 3) metres. c0: m/s, the starting value.
        max_change: largest relative change from ``c0`` accepted (default 10 %).

    Returns:
        A :class:`SoundSpeedEstimate`; not converged, with ``c`` = ``c0``, when fewer than
        :data:`MIN_MICS_FOR_C` microphones have a direct path or the fit is singular or far off.
    """
    pts = as_points(mics, "mics", dim=3)
    c0 = check_positive(c0, "c0")
    t, ok = _direct_times(detections)
    n = int(ok.sum())

    def fail(status: Status, message: str) -> SoundSpeedEstimate:
        nan3 = frozen(np.full(3, np.nan))
        return SoundSpeedEstimate(c0, np.inf, nan3, np.nan, n, status, message)

    if n < MIN_MICS_FOR_C:
        return fail(
            Status.NOT_IDENTIFIABLE,
            f"c not estimated: {n} microphones with a direct path, {MIN_MICS_FOR_C} needed",
        )
    start = multilaterate(pts[ok], c0 * t[ok])
    s, c, r, jac = _fit(pts[ok], t[ok], np.asarray(start.position, dtype=float), c0)
    sigma2 = float(r @ r) / (n - 4)
    try:
        cov = sigma2 * np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        return fail(Status.NOT_IDENTIFIABLE, "c not estimated: the direct paths do not fix it")
    c_std = float(np.sqrt(max(cov[3, 3], 0.0)))
    rms = float(np.sqrt(np.mean(r**2)))
    if not (np.isfinite(c) and np.isfinite(c_std)) or abs(c - c0) > max_change * c0:
        return fail(
            Status.OUT_OF_RANGE,
            f"c not estimated: the fit gave {c:.4g} m/s, more than {max_change:.0%} from {c0:g}",
        )
    msg = (
        f"c = {c:.3f} +- {c_std:.2g} m/s from the direct paths of {n} microphones (RMS "
        f"residual {rms:.2g} m; started at {c0:g})"
    )
    return SoundSpeedEstimate(c, c_std, frozen(s), rms, n, Status.CONVERGED, msg)
