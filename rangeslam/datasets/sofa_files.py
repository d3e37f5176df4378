"""Room impulse responses from SOFA files (AES69), read with ``sofar`` (pyfar's SOFA reader).

A SOFA file of impulse responses (``GLOBAL_DataType`` ``FIR``: conventions ``GeneralFIR``,
``SingleRoomSRIR``, ``SingleRoomMIMOSRIR``, ...) holds ``Data_IR`` of shape (M, R, N): M
measurements, R receivers, N samples, with the geometry in the listener's frame:

- a receiver's position in the room is ``ListenerPosition`` + rot @ ``ReceiverPosition`` (the
  rotation from ``ListenerView`` and ``ListenerUp``: view is x, up is z; AES69-2022, sec. 4.4);
- the source's is ``SourcePosition`` + ``EmitterPosition`` (one emitter), the same in every
  measurement (several sources are several files, as for .npz);
- positions are ``cartesian`` or ``spherical`` (azimuth, elevation in degrees, radius), in metres;
- ``Data_Delay`` (whole samples, >= 0) is the time before each RIR's sample 0: the RIR is
  preceded by that many zeros, so sample 0 is the emission, as :func:`load_rirs` promises;
- a ``shoebox`` room (``GLOBAL_RoomType``) with ``RoomCornerA`` at the origin gives the true room
  size ``RoomCornerB`` (for evaluation only).

Each of the M x R responses is one microphone (row m * R + r).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from rangeslam._validation import frozen
from rangeslam.errors import DataFormatError

__all__ = ["load_sofa", "sofa_positions"]

log = logging.getLogger(__name__)


def _array(sofa, name: str, p: Path) -> np.ndarray:
    try:
        arr = np.asarray(getattr(sofa, name), dtype=np.float64)
    except (AttributeError, TypeError, ValueError) as exc:
        raise DataFormatError(f"{p}: {name} is missing or not numeric ({exc})") from exc
    if not np.all(np.isfinite(arr)):
        raise DataFormatError(f"{p}: {name} holds values that are not finite")
    return arr


def sofa_positions(values: np.ndarray, kind: str, units: str, name: str, p: Path) -> np.ndarray:
    """(..., 3) cartesian positions [m] of SOFA ``values`` (..., 3) of type ``kind``
    ('cartesian', or 'spherical': azimuth, elevation [deg], radius [m])."""
    kind = str(kind).strip().lower()
    if "metre" not in str(units).lower() and "meter" not in str(units).lower():
        raise DataFormatError(f"{p}: {name} must be in metres; its units are {units!r}")
    if kind == "cartesian":
        return values
    if kind == "spherical":
        az, el, r = np.deg2rad(values[..., 0]), np.deg2rad(values[..., 1]), values[..., 2]
        return np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az),
                         r * np.sin(el)], axis=-1)  # fmt: skip
    raise DataFormatError(f"{p}: {name}_Type must be 'cartesian' or 'spherical'; got {kind!r}")


def _per_measurement(arr: np.ndarray, m: int, name: str, p: Path) -> np.ndarray:
    """(M, 3) from a SOFA (I, 3) or (M, 3) array."""
    arr = arr.reshape(-1, 3) if arr.ndim < 2 else arr
    if arr.shape not in ((1, 3), (m, 3)):
        raise DataFormatError(f"{p}: {name} must have shape (1, 3) or ({m}, 3); got {arr.shape}")
    return np.broadcast_to(arr, (m, 3))


def _frames(sofa, m: int, p: Path) -> np.ndarray:
    """(M, 3, 3) rotations of the listener's frame (columns: view, left, up) into the room."""
    view = getattr(sofa, "ListenerView", None)
    if view is None:
        return np.broadcast_to(np.eye(3), (m, 3, 3))
    kind = getattr(sofa, "ListenerView_Type", "cartesian")
    x = sofa_positions(_per_measurement(_array(sofa, "ListenerView", p), m, "ListenerView", p),
                       kind, "metre", "ListenerView", p)  # fmt: skip
    up = getattr(sofa, "ListenerUp", None)
    z = np.broadcast_to([0.0, 0.0, 1.0], (m, 3)) if up is None else sofa_positions(
        _per_measurement(_array(sofa, "ListenerUp", p), m, "ListenerUp", p), kind, "metre",
        "ListenerUp", p)  # fmt: skip
    x = x / np.linalg.norm(x, axis=1, keepdims=True)
    z = z - np.sum(z * x, axis=1, keepdims=True) * x
    norm = np.linalg.norm(z, axis=1, keepdims=True)
    if not np.all(np.isfinite(x)) or np.any(norm < 1e-9):
        raise DataFormatError(f"{p}: ListenerView and ListenerUp must be non-zero, not parallel")
    z = z / norm
    return np.stack([x, np.cross(z, x), z], axis=-1)


def positions_of(sofa, values: np.ndarray, name: str, p: Path) -> np.ndarray:
    """:func:`sofa_positions` of ``values`` of the SOFA variable ``name``, read with the type
    and units the file gives it (``{name}_Type``, ``{name}_Units``; SOFA's defaults
    'cartesian' and 'metre' when absent)."""
    kind = getattr(sofa, f"{name}_Type", "cartesian")
    return sofa_positions(values, kind, getattr(sofa, f"{name}_Units", "metre"), name, p)


def per_measurement_positions(sofa, name: str, m: int, p: Path) -> np.ndarray:
    """(M, 3) the SOFA variable ``name`` given once or per measurement, as positions."""
    return positions_of(sofa, _per_measurement(_array(sofa, name, p), m, name, p), name, p)


def _microphones(sofa, m: int, r: int, p: Path) -> np.ndarray:
    """(M * R, 3) receiver positions in the room, row m * R + r."""
    listener = per_measurement_positions(sofa, "ListenerPosition", m, p)
    rec = _array(sofa, "ReceiverPosition", p)
    rec = rec.reshape(rec.shape + (1,) * (3 - rec.ndim))  # (R, 3, I or M)
    if rec.shape[:2] != (r, 3) or rec.shape[2] not in (1, m):
        raise DataFormatError(
            f"{p}: ReceiverPosition must have shape ({r}, 3, 1) or ({r}, 3, {m}); got {rec.shape}"
        )
    rec = np.broadcast_to(np.moveaxis(rec, 2, 0), (m, r, 3))  # (M, R, 3)
    rec = positions_of(sofa, rec, "ReceiverPosition", p)
    rot = _frames(sofa, m, p)
    return (listener[:, None, :] + np.einsum("mij,mrj->mri", rot, rec)).reshape(m * r, 3)


def _source(sofa, m: int, p: Path) -> np.ndarray:
    """(3,) the source position, one for every measurement."""
    src = per_measurement_positions(sofa, "SourcePosition", m, p)
    emitter = getattr(sofa, "EmitterPosition", None)
    if emitter is not None:
        e = _array(sofa, "EmitterPosition", p)
        e = e.reshape(e.shape + (1,) * (3 - e.ndim))
        if e.shape[0] != 1:
            raise DataFormatError(f"{p}: one emitter per file; EmitterPosition has {e.shape[0]}")
        e = positions_of(sofa, np.moveaxis(e[0], 1, 0), "EmitterPosition", p)
        src = src + np.broadcast_to(e, (m, 3))  # emitters are in the source's frame; a zero
        # offset (sofar's default) or a translation without source view is what this reads
    if np.ptp(src, axis=0).max() > 0:
        raise DataFormatError(
            f"{p}: the source moves between measurements; one source per file (several "
            "sources: one file each)"
        )
    return src[0].copy()


def _delayed(ir: np.ndarray, sofa, p: Path) -> np.ndarray:
    """(M, R, N') the responses preceded by their ``Data_Delay`` in zeros (whole samples)."""
    m, r, n = ir.shape
    delay = _array(sofa, "Data_Delay", p) if getattr(sofa, "Data_Delay", None) is not None else 0
    try:
        delay = np.broadcast_to(np.asarray(delay).reshape(-1, r) if np.size(delay) > 1 else
                                delay, (m, r))  # fmt: skip
    except ValueError as exc:
        raise DataFormatError(f"{p}: Data_Delay must be (1, {r}) or ({m}, {r}) samples") from exc
    if np.any(delay < 0) or np.any(delay != np.round(delay)):
        raise DataFormatError(
            f"{p}: Data_Delay must be whole samples >= 0; got {delay.ravel()[:4]}"
        )
    if not np.any(delay):
        return ir
    d = delay.astype(int)
    out = np.zeros((m, r, n + int(d.max())))
    for i in range(m):
        for j in range(r):
            out[i, j, d[i, j] : d[i, j] + n] = ir[i, j]
    return out


def _room_size(sofa) -> np.ndarray | None:
    if str(getattr(sofa, "GLOBAL_RoomType", "")).lower() != "shoebox":
        return None
    a, b = getattr(sofa, "RoomCornerA", None), getattr(sofa, "RoomCornerB", None)
    if a is None or b is None:
        return None
    a, b = np.asarray(a, float).reshape(-1)[:3], np.asarray(b, float).reshape(-1)[:3]
    if a.shape != (3,) or b.shape != (3,) or np.any(a != 0) or not np.all(b > 0):
        log.info("SOFA room corners %s, %s: not a shoebox at the origin; no room size", a, b)
        return None
    return b


def load_sofa(p: Path, fs: float | None = None):
    """The RIRs of the SOFA file ``p`` as :class:`~rangeslam.datasets.rir_files.LoadedRirs`:
    rirs (M R, N') float64, fs, mics (M R, 3) [m], source (3,) [m], room_size (3,) when the file
    gives a shoebox at the origin. ``fs`` [Hz], when given, must agree with the file's.

    Raises:
        DataFormatError naming the file: not a SOFA file sofar reads, not impulse responses,
        several sampling rates, sources or emitters, positions not in metres, bad delays.
    """
    import sofar

    from rangeslam.datasets.rir_files import LoadedRirs

    try:
        sofa = sofar.read_sofa(str(p), verify=False, verbose=False)
    except Exception as exc:  # sofar and netCDF4 raise many kinds; each is "not readable"
        raise DataFormatError(f"{p}: not a SOFA file sofar can read ({exc})") from exc
    kind = str(getattr(sofa, "GLOBAL_DataType", ""))
    if not kind.startswith("FIR"):
        raise DataFormatError(
            f"{p}: GLOBAL_DataType is {kind!r}; only impulse responses (FIR) are read"
        )
    ir = _array(sofa, "Data_IR", p)
    if ir.ndim != 3 or ir.shape[2] < 3:
        raise DataFormatError(f"{p}: Data_IR must have shape (M, R, N); got {ir.shape}")
    m, r, _ = ir.shape
    rates = np.unique(_array(sofa, "Data_SamplingRate", p))
    if len(rates) != 1 or not rates[0] > 0:
        raise DataFormatError(f"{p}: Data_SamplingRate must be one rate > 0 Hz; got {rates}")
    if fs is not None and fs != rates[0]:
        raise DataFormatError(f"{p}: fs is {rates[0]:g} Hz, but fs={fs:g} was given")
    rirs = _delayed(ir, sofa, p).reshape(m * r, -1)
    size = _room_size(sofa)
    return LoadedRirs(
        rirs=frozen(rirs),
        fs=float(rates[0]),
        names=tuple(f"{p.name}:Data_IR[{i}, {j}]" for i in range(m) for j in range(r)),
        mics=frozen(_microphones(sofa, m, r, p)),
        source=frozen(_source(sofa, m, p)),
        room_size=None if size is None else frozen(size),
    )
