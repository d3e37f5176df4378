"""Room impulse responses simulated with pyroomacoustics (image source method), at the boundary
of the package: points as rows (N, 3) here, as columns there; time zero at the emission here,
while pyroomacoustics' fractional-delay filters add a fixed delay of half their length.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ._validation import as_points
from .errors import InvalidInputError

__all__ = ["shoebox_rirs"]


def shoebox_rirs(
    room_size: ArrayLike,
    source: ArrayLike,
    receivers: ArrayLike,
    *,
    fs: int = 16000,
    absorption: float = 0.2,
    max_order: int = 3,
    duration: float | None = None,
) -> np.ndarray:
    """RIRs (M, L) from one source to M receivers in a shoebox [0, Lx] x [0, Ly] x [0, Lz].

    Args:
        room_size: (3,) metres. source: (3,) metres. receivers: (M, 3) metres, inside the room.
        fs: sampling rate, Hz. absorption: energy absorption of every wall, in (0, 1].
        max_order: image sources up to this reflection order.
        duration: seconds kept (default: long enough for every simulated arrival).

    Sample n is time n / fs after the emission (pyroomacoustics' filter delay removed).
    """
    import pyroomacoustics as pra

    size = np.asarray(room_size, dtype=float)
    if size.shape != (3,) or not np.all(np.isfinite(size)) or np.any(size <= 0):
        raise InvalidInputError(f"room_size must be 3 positive lengths; got {room_size!r}")
    src = as_points(np.atleast_2d(source), "source", dim=3)[0]
    rec = as_points(receivers, "receivers", dim=3)
    for name, pts in (("source", src[None]), ("receivers", rec)):
        outside = np.any((pts <= 0) | (pts >= size), axis=1)
        if outside.any():
            raise InvalidInputError(
                f"{name} must lie inside the room; row {int(np.argmax(outside))} does not"
            )
    if not 0 < absorption <= 1:
        raise InvalidInputError(f"absorption must be in (0, 1]; got {absorption!r}")
    if not (np.isfinite(fs) and fs > 0 and float(fs).is_integer()):
        raise InvalidInputError(f"fs must be a positive whole number of Hz; got {fs!r}")
    if not (isinstance(max_order, int | np.integer) and max_order >= 0):
        raise InvalidInputError(f"max_order must be an integer >= 0; got {max_order!r}")
    room = pra.ShoeBox(
        size, fs=int(fs), materials=pra.Material(absorption), max_order=int(max_order)
    )
    room.add_source(src)
    room.add_microphone_array(rec.T)
    room.compute_rir()
    delay = pra.constants.get("frac_delay_length") // 2
    rirs = [np.asarray(room.rir[m][0])[delay:] for m in range(len(rec))]
    length = max(len(r) for r in rirs) if duration is None else round(duration * fs)
    out = np.zeros((len(rec), length))
    for m, r in enumerate(rirs):
        n = min(len(r), length)
        out[m, :n] = r[:n]
    return out
