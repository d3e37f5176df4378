"""Loader for the xtdoa real data: unsynchronised microphones, unknown sources and emission times.

El Badawy, Larsson, Pollefeys, Dokmanic, "Localizing unsynchronized sensors with unknown sources",
arXiv 2102.03565 (data from their repository swing-research/xtdoa, MIT licence). The directory
holds ``real_data_M12_K65.mat`` (see its README for format, provenance and the authors' protocol).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rangeslam._validation import frozen, shape_str
from rangeslam.datasets.paths import data_path
from rangeslam.errors import DataFormatError, InvalidInputError

__all__ = ["XTDOA_CITATION", "XTDOA_FILE", "XtdoaDataset", "xtdoa"]

XTDOA_CITATION = (
    "El Badawy, Larsson, Pollefeys, Dokmanic, 'Localizing unsynchronized sensors with unknown "
    "sources', arXiv 2102.03565 (data: swing-research/xtdoa, MIT licence)"
)
XTDOA_FILE = "real_data_M12_K65.mat"


@dataclass(frozen=True)
class XtdoaDataset:
    """The xtdoa measurements (12 microphones, 65 acoustic events).

    Attributes:
        receivers: (M, 3) measured microphone positions, metres (points as rows; the file's
            ``X_r`` transposed).
        arrivals: (M, K) times of arrival times the speed of sound, metres:
            T[m, k] = ||x_m - s_k|| + a_m + b_k + noise, a (M,) and b (K,) unknown.
        clean: (M, K) bool, True where the authors judged the arrival clean (their ``W``).
    """

    receivers: np.ndarray
    arrivals: np.ndarray
    clean: np.ndarray

    @property
    def clean_columns(self) -> np.ndarray:
        """(C,) indices of the events clean at every microphone (23 in the file)."""
        return np.flatnonzero(self.clean.all(axis=0))


def _field(data: dict, key: str, path: Path, shape: tuple[int, ...] | None) -> np.ndarray:
    if key not in data:
        raise DataFormatError(f"{path}: variable {key!r} missing; found {sorted(data)}")
    value = np.asarray(data[key])
    if value.ndim != 2 or (shape is not None and value.shape != shape):
        want = shape_str(shape) if shape is not None else "a 2-D array"
        raise DataFormatError(f"{path}: {key} must be {want}; got {shape_str(value.shape)}")
    if not np.issubdtype(value.dtype, np.number) or not np.all(np.isfinite(value)):
        raise DataFormatError(f"{path}: {key} must be finite numbers; got dtype {value.dtype}")
    return value


def xtdoa(path: str | Path = "xtdoa") -> XtdoaDataset:
    """Load the xtdoa data from ``path`` (the directory holding ``real_data_M12_K65.mat``, or
    the file itself): a path, or a name under the data folder
    (:func:`rangeslam.datasets.data_path`; default ``xtdoa``: ``$RANGESLAM_DATA/xtdoa``, else
    ``../shared/data/xtdoa``).

    Raises DataNotFoundError (an InvalidInputError) when the path does not exist, naming the
    paths tried; InvalidInputError when the directory does not hold the file; DataFormatError
    when the file is not a MATLAB file with ``T`` (M, K), ``W`` (M, K) of 0/1 and ``X_r`` (3, M).
    """
    from scipy.io import loadmat
    from scipy.io.matlab import MatReadError

    p = data_path(path, what="xtdoa directory or file")
    file = p / XTDOA_FILE if p.is_dir() else p
    if not file.is_file():
        raise InvalidInputError(
            f"path must be the xtdoa directory (holding {XTDOA_FILE}) or that file; got {p}"
        )
    try:
        data = loadmat(file)
    except (MatReadError, ValueError, TypeError, OSError) as exc:
        raise DataFormatError(f"{file}: not a readable MATLAB file ({exc})") from exc
    arrivals = _field(data, "T", file, None).astype(float)
    weights = _field(data, "W", file, arrivals.shape)
    if not np.all(np.isin(weights, (0, 1))):
        raise DataFormatError(f"{file}: W must hold only 0 and 1; got {np.unique(weights)[:5]}")
    positions = _field(data, "X_r", file, (3, arrivals.shape[0])).astype(float)
    return XtdoaDataset(
        receivers=frozen(positions.T.copy()),
        arrivals=frozen(arrivals),
        clean=frozen(weights.astype(bool)),
    )
