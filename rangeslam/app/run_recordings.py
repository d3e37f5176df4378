"""``rangeslam run`` on recordings of an excitation, and with an unknown emission time.

Recordings (an npz ``recordings`` array, or any RIRS files given with ``--excitation``) are
deconvolved into RIRs (:func:`rangeslam.acoustics.deconvolution.deconvolve`) before anything else,
so the rest of ``run`` sees RIRs. ``--unknown-emission`` is passed to the pipeline
(``run_rirs(unknown_emission=True)``); the estimated delays are reported here.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path
from typing import Any

__all__ = ["deconvolve_loaded", "emission_lines", "emission_plot_rirs"]


def deconvolve_loaded(args: argparse.Namespace, loaded, source) -> Any:
    """``loaded`` (one loudspeaker's files, read from ``source``: a path or a list of WAVs) as
    RIRs: deconvolved with the excitation of ``--excitation`` or of the npz when it holds
    recordings; unchanged when it holds RIRs and no ``--excitation`` is given. Refuses, naming
    the flag or the file: recordings without an excitation, an npz of RIRs with ``--excitation``,
    an excitation at another sampling rate or not shorter than the recordings."""
    from rangeslam.acoustics.deconvolution import deconvolve
    from rangeslam.errors import InvalidInputError

    flag = getattr(args, "excitation", None)
    where = source if isinstance(source, Path) else Path(source[0])
    if flag is None and not loaded.recorded:
        return loaded
    if flag is not None and not loaded.recorded and where.suffix.lower() == ".npz":
        raise InvalidInputError(
            f"--excitation {flag}: {where} holds 'rirs' (impulse responses already); recordings "
            "of the excitation go in a 'recordings' array"
        )
    if flag is not None:
        excitation, name = _flag_excitation(flag, loaded.fs), f"--excitation {flag}"
    elif loaded.excitation is not None:
        excitation, name = loaded.excitation, f"{where}: excitation"
    else:
        raise InvalidInputError(
            f"{where} holds recordings but no excitation: give --excitation FILE (.wav, .npy, "
            ".csv) or an 'excitation' array in the npz"
        )
    n, length = len(excitation), loaded.rirs.shape[1]
    if n > length - 2:
        raise InvalidInputError(
            f"{name}: {n} samples ({n / loaded.fs:.3f} s), not shorter than the recordings of "
            f"{where} ({length} samples, {length / loaded.fs:.3f} s): a recording must go on "
            "after the excitation for as long as the RIR"
        )
    return dataclasses.replace(
        loaded, rirs=deconvolve(loaded.rirs, excitation), recorded=False, excitation=excitation
    )


def _flag_excitation(path: Path, fs: float):
    """(E,) the excitation of ``--excitation``, a WAV's rate checked against ``fs``."""
    from rangeslam.datasets.rir_files import load_excitation
    from rangeslam.errors import InvalidInputError, RangeSlamError

    try:
        rate, x = load_excitation(path)
    except RangeSlamError as exc:
        raise InvalidInputError(f"--excitation {exc}") from exc
    if rate is not None and rate != fs:
        raise InvalidInputError(
            f"--excitation {path}: sampled at {rate:g} Hz, the recordings at {fs:g} Hz "
            "(nothing is resampled)"
        )
    return x


def emission_plot_rirs(rirs, fs: float, offset: float):
    """(M, L) ``rirs`` advanced by ``offset`` seconds (the estimated emission), as the pipeline
    saw them, for the RIR plot; as given when the offset is not finite."""
    from rangeslam.acoustics.deconvolution import shift_signals

    return shift_signals(rirs, -offset * fs) if math.isfinite(offset) else rirs


def emission_lines(res, truth: list, lines: list[str], record: dict) -> None:
    """The estimated emission times (``--unknown-emission``), each with its standard deviation
    and its error against the file's ``emission_delay`` (``truth``, one per loudspeaker, None
    where not stated), appended to ``lines`` and ``record``."""
    if res.emission_offsets is None:
        return
    taus, stds = res.emission_offsets, res.emission_offset_stds
    lines += ["", "emission time (from sample 0 of the RIRs, estimated):", ""]
    lines += ["| loudspeaker | emission [ms] | std [ms] | error [ms] |", "|---|---|---|---|"]
    errors = []
    for j, (t, s) in enumerate(zip(taus, stds, strict=True)):
        true = truth[j] if j < len(truth) else None
        err = None if true is None else float(t - true)
        errors.append(err)
        cells = (
            ("-", "-", "-")  # not found (the message says why)
            if not math.isfinite(t)
            else (f"{t * 1e3:.5f}", f"{s * 1e3:.2g}", "-" if err is None else f"{err * 1e3:+.2g}")
        )
        lines.append(f"| {j} | " + " | ".join(cells) + " |")
    record["emission_offsets_s"] = [float(t) for t in taus]
    record["emission_offset_stds_s"] = [float(s) for s in stds]
    if any(e is not None for e in errors):
        record["emission_offset_errors_s"] = errors
