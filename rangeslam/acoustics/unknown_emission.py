"""The room from RIRs whose sample 0 is not the emission: one unknown delay per loudspeaker.

A recording started ``tau`` seconds before the loudspeaker played (a free-running recorder, an
unknown output latency) has every arrival ``tau`` late: each range is the distance plus
b = c tau, the same for the direct path and every echo of that loudspeaker (the paper's "future
work"; :mod:`rangeslam.localization.emission`). Here tau is estimated and taken out before the
usual pipeline, in two passes per loudspeaker:

1. Direct paths: the detector's direct peak at every microphone, located with its offset as a
   pseudorange (:func:`rangeslam.localization.multilaterate_with_offset`, robust when there are
   at least 6 microphones; needs 5). The RIRs are advanced by that tau (band-limited, any
   fraction of a sample; :func:`rangeslam.acoustics.deconvolution.shift_signals`), so the
   echoes are where the labelling expects them.
2. The pipeline runs on the advanced RIRs (``run``: :func:`rangeslam.acoustics.pipeline.run_rirs`
   or ``run_loudspeakers``); every loudspeaker's labelled ranges (direct path and first-order
   echoes) then give the remaining offset jointly with the source and its images
   (:func:`rangeslam.localization.reconstruct_room_unknown_emission`, the joint ML of the offset
   and the room, with the offset's standard deviation), less the pipeline's timing bias: how
   much later it times the direct paths than pass 1's detector did on the same advanced RIRs. A
   direct template (``MEASURED_RIR_OPTIONS``) is cut at whole samples, so every matched-filtered
   arrival is up to half a sample off; left in, that common bias was read as an emission offset
   and moved tau 0.14-0.46 sample off the truth on 7 of 12 shoebox seeds (900100-900111), up to
   38 reported stds, still converged. When the remaining offset is more than a tenth of a
   sample and more than 3 of its standard deviations (the bias's included), the RIRs are
   advanced by the corrected tau and the pipeline runs again. Otherwise the direct paths' tau stands: echoes are timed less well than direct paths
   (merged arrivals): one loudspeaker's unweighted fit over all of them came 1 mm off where the
   direct paths alone were 0.02 mm off (shoebox, 8 microphones, seed 494335).

Silent and clipped RIRs are found on the RIRs as given, before any advance (a band-limited
shift smooths the flat run that marks a clipped one), left out of the offset fit, masked as
``run_rirs`` masks them (or used, ``clipped="use"``), and flagged in the result.

The speed of sound is not estimated with tau: ||s - m_i|| = c (t_i - tau) barely tells c from
tau with a compact array (both stretch every range), so c is taken as given.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

import numpy as np

from rangeslam._validation import as_flag, frozen
from rangeslam.acoustics.deconvolution import shift_signals
from rangeslam.acoustics.echoes import ClippedRirWarning, detect_echoes_many
from rangeslam.acoustics.rir_notes import rir_notes
from rangeslam.datasets.rir_files import SilentRirWarning
from rangeslam.errors import DegenerateGeometryError, InvalidInputError
from rangeslam.localization.emission import (
    multilaterate_with_offset,
    reconstruct_room_unknown_emission,
)
from rangeslam.status import HasStatus, Status

log = logging.getLogger(__name__)

__all__ = [
    "EmissionOffset",
    "check_unknown_emission",
    "direct_path_offset",
    "loudspeakers_unknown_emission",
    "rirs_unknown_emission",
    "with_unknown_emission",
]

#: Samples: a remaining offset above this (and above 3 standard deviations) after the first pass
#: is taken out by a second pass.
RERUN_SAMPLES = 0.1

#: The note of ``run_rirs`` for an answer that is not finite (kept when the message is rebuilt).
NOT_FINITE = "the answer is not finite: not converged"
_FLAGS = ("silent", "clipped", "masked")


def check_unknown_emission(unknown_emission: object, mode: str, estimate_c: object) -> bool:
    """``unknown_emission`` as a bool; refused for a walk and with ``estimate_c``."""
    if as_flag(unknown_emission, "unknown_emission") and (mode != "array" or estimate_c):
        raise InvalidInputError(
            "unknown_emission is for a known array (mics) with c as given; got "
            + ("step_bounds (a walk)" if mode != "array" else "estimate_c=True as well")
        )
    return bool(unknown_emission)


@dataclass(frozen=True)
class EmissionOffset(HasStatus):
    """Seconds from sample 0 of one loudspeaker's RIRs to its emission.

    Attributes:
        time: seconds (NaN when not found). std: its standard deviation, seconds (the range
            residuals' RMS through the fit's dilution of precision; NaN when not found).
        status: the pseudorange fit's (NOT_IDENTIFIABLE when fewer than 5 microphones have a
            direct path). message: what happened.
        direct_times: (M,) seconds from sample 0, the direct peak the fit used at each
            microphone (NaN where none), or None.
    """

    time: float
    std: float
    status: Status
    message: str
    direct_times: np.ndarray | None = None


def rirs_unknown_emission(screen, fs: float, mics, options, *, c: float, rng):
    """``run_rirs`` (array mode) on screened RIRs (the pipeline's ``RirScreen`` of (M, L) RIRs)
    whose emission time is unknown (:func:`with_unknown_emission`); ``options`` a
    ``RirRunOptions`` of the array mode."""
    from rangeslam.acoustics.pipeline import run_rirs  # pipeline imports this module

    def run(sets, **kwargs):
        return run_rirs(sets[0], **kwargs)

    return _unknown_emission_run(run, [screen], fs, mics, options, c=c, rng=rng)


def loudspeakers_unknown_emission(screens, fs: float, mics, options, *, c: float, rng):
    """``run_loudspeakers`` on J screened RIR sets (``RirScreen``) whose emission times are
    unknown, one each (:func:`with_unknown_emission`); ``options`` a ``RirRunOptions``."""
    from rangeslam.acoustics.pipeline import run_loudspeakers  # pipeline imports this module

    return _unknown_emission_run(run_loudspeakers, screens, fs, mics, options, c=c, rng=rng)


def _unknown_emission_run(run, screens, fs: float, mics, options, *, c: float, rng):
    """:func:`with_unknown_emission` of ``run`` (J sets, then the pipeline's keywords), given
    ``options``' array-mode tuning and the screens' ``clipped_mode``."""
    again = partial(
        run, fs=fs, mics=mics, c=c, rng=rng, clipped=screens[0].clipped_mode,
        direct_template=options.direct_template, detect_options=options.detect_options,
        label_options=options.label_options, reconstruct_options=options.reconstruct_options,
        check_input=False,  # the caller checked the RIRs as given; these are advanced
    )  # fmt: skip
    return with_unknown_emission(
        again, screens, fs, mics, c=c, detect_options=options.detect_options, rng=rng,
        template=options.direct_template is not None,
    )  # fmt: skip


def direct_path_offset(
    rirs: np.ndarray,
    fs: float,
    mics: np.ndarray,
    *,
    c: float,
    detect_options: dict[str, Any] | None = None,
    rng: np.random.Generator | None = None,
) -> EmissionOffset:
    """The emission time of ``rirs`` (M, L) from the direct paths at the M known ``mics``
    (pseudorange multilateration, robust with 6 or more). ``detect_options`` as
    ``detect_echoes_many`` (its ``max_time``, a time from the emission, is not applied here)."""
    opts = {k: v for k, v in (detect_options or {}).items() if k != "max_time"}
    with warnings.catch_warnings():  # the run that follows warns about the same RIRs
        warnings.simplefilter("ignore", UserWarning)
        dets = detect_echoes_many(rirs, fs, **opts)
    seen = np.array([d.direct is not None for d in dets])
    nan = float("nan")
    if seen.sum() < 5:
        why = (
            f"{int(seen.sum())} of {len(dets)} RIRs have a direct path; an unknown emission needs 5"
        )
        return EmissionOffset(nan, nan, Status.NOT_IDENTIFIABLE, why)
    times = np.array([d.times[d.direct] if d.direct is not None else np.nan for d in dets])
    try:
        fit = multilaterate_with_offset(
            mics, c * np.nan_to_num(times), mask=seen, robust=bool(seen.sum() >= 6), rng=rng
        )
    except (InvalidInputError, DegenerateGeometryError) as exc:
        return EmissionOffset(nan, nan, Status.NOT_IDENTIFIABLE, str(exc))
    used = fit.inliers & np.isfinite(fit.residuals)
    dof = max(int(used.sum()) - mics.shape[1] - 1, 1)
    sigma = np.sqrt(np.sum(fit.residuals[used] ** 2) / dof)
    return EmissionOffset(
        fit.offset / c, sigma * fit.dop[-1] / c, fit.status, fit.message, frozen(times)
    )


#: The fewest microphones whose direct path both timings hold for the timing bias to be measured.
MIN_BIAS_MICS = 3


def _timing_bias(lab: Any, direct: np.ndarray | None, tau: float, c: float):
    """(bias, std) seconds: how much later the pipeline times a direct path than
    :func:`direct_path_offset`'s detector on the same advanced RIRs (the median over the
    microphones both timed; std: the differences' standard deviation over the square root of their
    number), or the reason it was not measured (a string). A direct template
    (``MEASURED_RIR_OPTIONS``) is cut at whole samples around its peak, so matched-filtered
    arrivals all come up to half a sample off (0.3 sample at seed 900100, every microphone within
    0.01 of it); a bias common to the direct path and the echoes that the echoes' offset would
    otherwise take for the emission's."""
    if direct is None:
        return "no direct-path times"
    both = lab.mask[:, 0] & np.isfinite(direct)
    if both.sum() < MIN_BIAS_MICS:
        return f"{int(both.sum())} microphones with both timings of the direct path"
    diff = lab.ranges[both, 0] / c - (direct[both] - tau)
    return float(np.median(diff)), float(np.std(diff) / np.sqrt(len(diff)))


def _echo_offsets(res: Any, mics: np.ndarray, c: float, rng, offsets: list, template: bool):
    """Each loudspeaker's remaining offset from its labelled ranges, as seconds
    (``reconstruct_room_unknown_emission``, the labelling's tolerance as in ``room_from_rirs``)
    less the pipeline's timing bias with a ``template`` (:func:`_timing_bias`; else 0), its std
    and the bias's combined:
    (offset, std, bias) when that fit converged, else the reason it did not (a string)."""
    labs = getattr(res.result, "labellings", None) or (res.result.labelling,)
    out: list = []
    for lab, o in zip(labs, offsets, strict=True):
        if not lab.has_room:
            out.append("no echo labelled")
            continue
        bias = _timing_bias(lab, o.direct_times, o.time, c) if template else (0.0, 0.0)
        if isinstance(bias, str):
            out.append(f"the pipeline's timing bias not measured: {bias}")
            continue
        ranges = np.where(lab.mask, np.nan_to_num(lab.ranges), 0.0)
        try:
            fit = reconstruct_room_unknown_emission(
                mics, ranges, mask=lab.mask, c=c, inlier_threshold=2 * lab.tolerance, rng=rng
            )
        except (InvalidInputError, DegenerateGeometryError) as exc:
            out.append(str(exc))
            continue
        if not fit.converged:
            out.append(fit.message)
            continue
        std = float(np.hypot(fit.offset_std / c, bias[1]))
        out.append((fit.offset / c - bias[0], std, bias[0]))
    return out


def with_unknown_emission(
    run: Callable[[list[np.ndarray]], Any],
    screens: Sequence[Any],
    fs: float,
    mics: np.ndarray,
    *,
    c: float,
    detect_options: dict[str, Any] | None = None,
    rng: np.random.Generator | None = None,
    template: bool = False,
):
    """``run`` (J advanced RIR sets -> RunResult) on J screened sets whose emission times are
    unknown: the module docstring's passes. ``screens``: the pipeline's ``RirScreen`` of each set
    (``rirs`` (M, L_j) with the masked rows zeroed; ``silent``, ``clipped``, ``masked`` (M,);
    ``clipped_mode``), found on the RIRs as given: the advance smooths the flat run that marks a
    clipped RIR, so it is screened before. Silent and clipped rows (used ones too: their direct
    peak is mistimed) are left out of the offset fit. ``template``: ``run`` matched-filters with
    a direct template, whose timing bias the echoes' check takes out (:func:`_timing_bias`;
    without one the pipeline times the direct paths with pass 1's detector: no bias but the
    shift's 0.01 sample, and taking out its noisy estimate moved the check across its threshold
    at seed 900104, 0.096 against 0.1 sample). Returns ``run``'s RunResult with the
    screens' flags (J * M), ``emission_offsets`` (J,) seconds from sample 0 to each emission and
    ``emission_offset_stds`` (J,) seconds; not converged, with the reason in ``message``, when an
    offset could not be estimated."""
    _warn_used_clipped(screens)
    offsets = [
        direct_path_offset(
            np.where((s.silent | s.clipped)[:, None], 0.0, s.rirs), fs, mics, c=c,
            detect_options=detect_options, rng=rng,
        )
        for s in screens
    ]  # fmt: skip
    sets = [s.rirs for s in screens]
    taus = np.array([o.time for o in offsets])
    stds = np.array([o.std for o in offsets])
    res = _run_screened(run, _advanced(sets, taus, fs))
    echoes = _echo_offsets(res, mics, c, rng, offsets, template)
    # the echoes disagree with the direct paths beyond their own noise: their offset is taken
    moved = [
        isinstance(e, tuple)
        and np.isfinite(t)
        and abs(e[0]) * fs > RERUN_SAMPLES
        and abs(e[0]) > 3 * e[1]
        for e, t in zip(echoes, taus, strict=True)
    ]
    if any(moved):
        for j in np.flatnonzero(moved):
            taus[j] += echoes[j][0]
            stds[j] = echoes[j][1]
        log.info("unknown emission: the echoes moved the offsets to %s s; running again", taus)
        res = _run_screened(run, _advanced(sets, taus, fs))
    res = _with_screens(res, screens)
    return _emission_verdict(res, taus, stds, offsets, echoes, moved)


def _warn_used_clipped(screens: Sequence[Any]) -> None:
    """A ClippedRirWarning for each clipped RIR kept (``clipped="use"``): the screen warns only
    about those it masks, and the detector no longer sees them clipped once advanced."""
    for j, s in enumerate(screens if screens[0].clipped_mode == "use" else ()):
        who = f" (loudspeaker {j})" if len(screens) > 1 else ""
        for i in np.flatnonzero(s.clipped):
            warnings.warn(
                f"rirs[{i}]{who} looks clipped: used (clipped='use'), with less accurate echo "
                "times near its peak, and left out of the emission-time fit",
                ClippedRirWarning,
                stacklevel=6,  # the caller of run_rirs / run_loudspeakers
            )


def _run_screened(run: Callable[[list[np.ndarray]], Any], sets: list[np.ndarray]):
    """``run`` on advanced sets whose masked rows are zeros, without the warnings the screen of
    the RIRs as given has already raised (a masked row now silent, a used clipped one again)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SilentRirWarning)
        warnings.simplefilter("ignore", ClippedRirWarning)
        return run(sets)


def _with_screens(res, screens: Sequence[Any]):
    """``res`` with the flags of the RIRs as given (``screens``, J * M rows) and its message's
    notes on them (the run on the advanced RIRs saw the masked rows as silent ones)."""
    flags = {k: np.concatenate([getattr(s, k) for s in screens]) for k in _FLAGS}
    # run_rirs's verdict turned a converged pipeline with an answer not finite into SOLVER_FAILED
    failed = Status(res.result.status) is Status.CONVERGED and res.status is Status.SOLVER_FAILED
    kept = [NOT_FINITE] if failed else []
    notes = rir_notes(
        flags["silent"], flags["clipped"], flags["masked"], np.asarray(res.no_echoes),
        screens[0].clipped_mode,
    )  # fmt: skip
    message = "; ".join([res.result.message, *kept, *notes])
    return replace(res, message=message, **{k: frozen(v) for k, v in flags.items()})


def _advanced(rir_sets, taus: np.ndarray, fs: float) -> list[np.ndarray]:
    """Each set advanced by its emission time (as it is where that was not found)."""
    return [
        shift_signals(x, -t * fs) if np.isfinite(t) else np.asarray(x, dtype=float)
        for x, t in zip(rir_sets, taus, strict=True)
    ]


def _emission_verdict(
    res, taus: np.ndarray, stds: np.ndarray, offsets: list, echoes: list, moved: list
):
    """``res`` with the offsets, its message led by them (and what the echoes said of them: the
    first pass's remaining offset, which ``moved`` loudspeakers took in a second pass), and not
    converged when a loudspeaker's direct-path offset did not converge."""
    many = len(taus) > 1
    parts = []
    status = res.status
    for j, (t, s, o) in enumerate(zip(taus, stds, offsets, strict=True)):
        who = f" (loudspeaker {j})" if many else ""
        if not o.converged:
            parts.append(f"emission time{who} not found from the direct paths: {o.message}")
            status = o.status if status is Status.CONVERGED else status
            continue
        text = f"emission {t * 1e3:.4f} +- {s * 1e3:.2g} ms after sample 0{who}"
        if j < len(echoes):
            e = echoes[j]
            if not isinstance(e, tuple):
                text += f" (the echoes' offset not estimated: {e})"
            elif moved[j]:  # the echoes' offset is in ``t``: what is left of it is not measured
                text += (
                    f", moved by the echoes' offset {e[0] * 1e3:+.2g} +- {e[1] * 1e3:.2g} ms from "
                    f"the direct paths' {(t - e[0]) * 1e3:.4f} ms (second pass)"
                )
            else:
                text += f", the echoes' offset {e[0] * 1e3:+.2g} +- {e[1] * 1e3:.2g} ms from it"
            if isinstance(e, tuple) and e[2]:
                text += f" (the pipeline's timing bias {e[2] * 1e3:+.2g} ms taken out)"
        parts.append(text)
    return replace(
        res,
        status=status,
        message="; ".join([*parts, res.message]),
        emission_offsets=frozen(taus),
        emission_offset_stds=frozen(stds),
    )
