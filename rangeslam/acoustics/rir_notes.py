"""The sentences a run's message gives about the RIRs it left out or found nothing in, shared by
:func:`rangeslam.acoustics.pipeline.run_rirs` and the unknown-emission runs
(:mod:`rangeslam.acoustics.unknown_emission`), which screen the RIRs before advancing them."""

from __future__ import annotations

import numpy as np

__all__ = ["rir_notes"]


def rir_notes(
    silent: np.ndarray,
    clipped: np.ndarray,
    masked: np.ndarray,
    no_echoes: np.ndarray,
    clipped_mode: str,
) -> list[str]:
    """One sentence per kind of RIR (silent, clipped, without an echo and not masked) that has
    any, naming the rows: ``"2 of 8 RIRs clipped (masked): rirs[0], rirs[1]"``. All (M,) bool;
    ``clipped_mode`` "mask" or "use"."""
    m = len(silent)
    notes = []
    for flags, what in (
        (silent, "silent (masked)"),
        (clipped, "clipped (masked)" if clipped_mode == "mask" else "clipped (used)"),
        (no_echoes & ~masked, "without any echo detected (masked)"),
    ):
        if flags.any():
            rows = ", ".join(f"rirs[{i}]" for i in np.flatnonzero(flags))
            notes.append(f"{int(flags.sum())} of {m} RIRs {what}: {rows}")
    return notes
