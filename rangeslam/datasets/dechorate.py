"""Loader for the dEchorate subset: measured echo times of arrival with calibrated geometry.

Di Carlo, Tandeitnik, Foy, Bertin, Deleforge, Gannot, "dEchorate: a calibrated room impulse
response dataset for echo-aware signal processing", EURASIP J. Audio, Speech, and Music
Processing, 2021 (MIT licence). The directory holds ``positions.json`` and ``echo_toa.csv``
(see its README for format and provenance).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rangeslam._validation import frozen, shape_str
from rangeslam.datasets.paths import data_path
from rangeslam.errors import DataFormatError, InvalidInputError
from rangeslam.geometry.room import Room

__all__ = ["ECHO_LABELS", "DEchorate", "DechorateRirs", "load_dechorate", "load_dechorate_rirs"]

#: Columns of the range matrices: direct path, then the walls in Room.shoebox order.
ECHO_LABELS = ("direct", "west_x0", "east_xL", "south_y0", "north_yW", "floor_z0", "ceiling_zH")


@dataclass(frozen=True)
class DEchorate:
    """The dEchorate echo subset.

    Attributes:
        mics: (30, 3) calibrated microphone positions, metres (six horizontal linear arrays of 5).
        sources: (S, 3) calibrated loudspeaker positions, metres.
        room_size: (3,) L, W, H of the shoebox, metres.
        speed_of_sound: m/s.
        fs: sampling rate of the recordings, Hz.
        toa: (S, 30, 7) times of arrival in seconds from emission, columns as in ``ECHO_LABELS``.
        mic_array: (30,) index of the linear array each microphone belongs to.
    """

    mics: np.ndarray
    sources: np.ndarray
    room_size: np.ndarray
    speed_of_sound: float
    fs: float
    toa: np.ndarray
    mic_array: np.ndarray
    echo_labels: tuple[str, ...] = ECHO_LABELS

    @property
    def room(self) -> Room:
        """The calibrated shoebox; its walls are in the order of the echo columns 1..6."""
        return Room.shoebox(self.room_size)

    @property
    def pick_resolution(self) -> float:
        """Distance sound travels in one sample, c / fs, in metres (7.2 mm here).

        Echo peaks are picked to within a few samples, so a few times this is the natural
        ``inlier_threshold`` of :func:`rangeslam.reconstruct_room` on these data.
        """
        return self.speed_of_sound / self.fs

    def ranges(self, source: int) -> np.ndarray:
        """(30, 7) measured ranges in metres (toa times c) for loudspeaker ``source``."""
        return self.toa[source] * self.speed_of_sound


def _read_json(path: Path) -> dict:
    try:
        with path.open() as fh:
            return json.load(fh)
    except json.JSONDecodeError as exc:
        raise DataFormatError(f"{path}: not valid JSON ({exc})") from exc


def _vectors(data: dict, key: str, path: Path, n: int | None = None) -> np.ndarray:
    if key not in data:
        raise DataFormatError(f"{path}: missing key {key!r}")
    arr = np.asarray(data[key], dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3 or (n is not None and arr.shape[0] != n):
        raise DataFormatError(f"{path}: {key!r} must be a list of [x, y, z]; got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise DataFormatError(f"{path}: {key!r} holds non-finite values")
    return arr


def load_dechorate(path: str | Path = "dechorate") -> DEchorate:
    """Load the dEchorate subset from a directory holding positions.json and echo_toa.csv: a
    path, or a name under the data folder (:func:`rangeslam.datasets.data_path`; default
    ``dechorate``: ``$RANGESLAM_DATA/dechorate``, else ``../shared/data/dechorate``)."""
    root = data_path(path, what="dEchorate directory")
    pos_path, toa_path = root / "positions.json", root / "echo_toa.csv"
    for p in (pos_path, toa_path):
        if not p.is_file():
            raise FileNotFoundError(
                f"dEchorate file not found: {p} (pass the directory that holds it)"
            )
    meta = _read_json(pos_path)
    mics = _vectors(meta, "mics_calibrated", pos_path)
    sources = _vectors(meta, "sources_calibrated", pos_path)
    room_size = np.asarray(meta.get("room_size_LWH", []), dtype=float)
    if room_size.shape != (3,) or np.any(room_size <= 0):
        raise DataFormatError(f"{pos_path}: 'room_size_LWH' must be three positive lengths")
    c = float(meta.get("speed_of_sound_m_s", math.nan))
    fs = float(meta.get("fs_Hz", math.nan))
    if not (np.isfinite(c) and c > 0 and np.isfinite(fs) and fs > 0):
        raise DataFormatError(
            f"{pos_path}: 'speed_of_sound_m_s' and 'fs_Hz' must be positive numbers"
        )
    arrays = np.asarray(meta.get("mic_to_array", np.arange(len(mics)) // 5), dtype=int)

    n_mic, n_src = len(mics), len(sources)
    toa = np.full((n_src, n_mic, len(ECHO_LABELS)), np.nan)
    want = ["mic", "src"] + [f"toa_{lab}_s" for lab in ECHO_LABELS]
    with toa_path.open(newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header != want:
            raise DataFormatError(f"{toa_path}: header must be {','.join(want)}; got {header}")
        for row_no, row in enumerate(reader, start=2):
            if len(row) != len(want):
                raise DataFormatError(
                    f"{toa_path}, row {row_no}: expected {len(want)} fields, got {len(row)}"
                )
            try:
                mic, src = int(row[0]), int(row[1])
                vals = [float(v) for v in row[2:]]
            except ValueError as exc:
                raise DataFormatError(f"{toa_path}, row {row_no}: {exc}") from exc
            if not (0 <= mic < n_mic and 0 <= src < n_src):
                raise DataFormatError(
                    f"{toa_path}, row {row_no}: mic {mic} or src {src} out of range"
                )
            if not all(math.isfinite(v) and v > 0 for v in vals):
                raise DataFormatError(
                    f"{toa_path}, row {row_no}: times of arrival must be positive and finite"
                )
            if not np.all(np.isnan(toa[src, mic])):
                raise DataFormatError(
                    f"{toa_path}, row {row_no}: duplicate row for mic {mic}, src {src}"
                )
            toa[src, mic] = vals
    missing = np.argwhere(np.isnan(toa[:, :, 0]))
    if len(missing):
        s, m = missing[0]
        raise DataFormatError(
            f"{toa_path}: no row for mic {m}, src {s} ({len(missing)} pairs missing)"
        )
    return DEchorate(
        mics=frozen(mics),
        sources=frozen(sources),
        room_size=frozen(room_size),
        speed_of_sound=c,
        fs=fs,
        toa=frozen(toa),
        mic_array=frozen(arrays),
    )


@dataclass(frozen=True)
class DechorateRirs:
    """The measured dEchorate RIRs of ``rirs_src0_12mics.npz`` and their calibrated geometry.

    Attributes:
        rirs: (M, L) RIRs, t = 0 at emission. fs: Hz. mics: (M, 3) metres (``mics_v3``).
        source: (3,) metres (``src_v3``). room_size: (3,) L, W, H, metres (shoebox
        [0, L] x [0, W] x [0, H]). c: speed of sound, m/s. mic_ids: (M,) indices among the 30
        microphones of the dataset. room_code: which walls were reflective ('011111': not the floor).
    """

    rirs: np.ndarray
    fs: float
    mics: np.ndarray
    source: np.ndarray
    room_size: np.ndarray
    c: float
    mic_ids: np.ndarray
    room_code: str


def load_dechorate_rirs(path: str | Path = "dechorate") -> DechorateRirs:
    """Read ``rirs_src0_12mics.npz`` (the file, or the dEchorate directory holding it; a path or a
    name under the data folder, as :func:`load_dechorate`)."""
    p = data_path(path, what="dEchorate directory or file")
    if p.is_dir():
        p = p / "rirs_src0_12mics.npz"
    if not p.is_file():
        raise InvalidInputError(
            f"path must be the dEchorate directory or its npz file; {p} not found"
        )
    try:
        with np.load(p, allow_pickle=False) as data:
            raw = {k: data[k] for k in data.files}
    except (OSError, ValueError) as exc:
        raise DataFormatError(f"{p}: not a readable npz file ({exc})") from exc
    need = ("rirs", "fs", "mics_v3", "src_v3", "room_size", "c", "mic_ids", "room_code")
    missing = [k for k in need if k not in raw]
    if missing:
        raise DataFormatError(f"{p}: missing arrays {missing}")
    rirs = np.asarray(raw["rirs"], dtype=float)
    mics = np.asarray(raw["mics_v3"], dtype=float)
    if rirs.ndim != 2 or mics.shape != (rirs.shape[0], 3):
        raise DataFormatError(
            f"{p}: rirs {shape_str(rirs.shape)} and mics_v3 {shape_str(mics.shape)} do not match"
        )
    return DechorateRirs(
        rirs=frozen(rirs),
        fs=float(raw["fs"]),
        mics=frozen(mics),
        source=frozen(np.asarray(raw["src_v3"], dtype=float).reshape(3)),
        room_size=frozen(np.asarray(raw["room_size"], dtype=float).reshape(3)),
        c=float(raw["c"]),
        mic_ids=frozen(np.asarray(raw["mic_ids"], dtype=int)),
        room_code=str(raw["room_code"]),
    )
