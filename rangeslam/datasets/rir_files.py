"""Room impulse responses from files: one ``.npz``, one SOFA file (:mod:`rangeslam.datasets.sofa_files`),
one multichannel WAV, or several mono WAVs.

Several loudspeakers are several of those, one each (:func:`one_per_loudspeaker` tells them from
the mono WAVs of one): ``.npz`` files, multichannel WAVs, or directories of mono WAVs.

:func:`load_rirs` reads them, with whatever else an npz says (microphones, step bounds, the speed
of sound, ground truth), into a :class:`LoadedRirs`; :func:`rangeslam.acoustics.pipeline.run_rirs`
runs a pipeline on them. Bad files are refused with a :class:`~rangeslam.errors.DataFormatError`
naming the file: RIRs of different lengths or sampling rates (never padded, cropped or resampled:
sample 0 must be the emission in every RIR), NaN or infinite samples, a missing sampling rate,
arrays of the wrong shape.
"""

from __future__ import annotations

import re
import struct
import warnings
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rangeslam._validation import as_float_array, as_scalar, frozen, shape_str
from rangeslam.datasets.paths import data_path
from rangeslam.errors import DataFormatError, InvalidInputError

__all__ = [
    "LoadedRirs",
    "SilentRirWarning",
    "check_transposed",
    "load_excitation",
    "load_rirs",
    "one_per_loudspeaker",
    "read_numbers",
]


# scipy.io.wavfile's warnings when a file ends before its RIFF header says (scipy 1.x wording).
TRUNCATED = re.compile(r"EOF|prematurely|Incomplete chunk|truncat", re.IGNORECASE)


class SilentRirWarning(UserWarning):
    """A RIR has every sample 0: no range can come from it, its row is masked."""


@dataclass(frozen=True, eq=False)
class LoadedRirs:
    """RIRs read by :func:`load_rirs`, with whatever else the file said. M RIRs of L samples.

    Attributes:
        rirs: (M, L) float64, sample n at time n / fs from the emission; int PCM scaled to [-1, 1).
        fs: sampling rate, Hz.
        names: (M,) where each row came from: ``"file.npz:rirs[m]"``, ``"mic03.wav"``,
            ``"array.wav:channel 2"``.
        mics: (M, 3) microphone positions, metres, when an npz held them (``mics``, or dEchorate's
            ``mics_v3``); else None.
        step_bounds: (2, M - 1) lower and upper bounds on each step, metres (npz ``step_bounds``);
            else None.
        c: speed of sound, m/s (npz ``c``); else None.
        source: (d,) true loudspeaker position (npz ``source`` or ``src_v3``), for evaluation only.
        room_size: (3,) true shoebox size (npz ``room_size``), for evaluation only.
        trajectory: true microphone positions of a walk, (M, d) at every RIR or at the keyframes
            (npz ``trajectory``), for evaluation.
        keyframes: (M,) the RIRs that are SLAM steps (npz ``keyframes``), when there are more
            RIRs than steps; else None.
        landmarks: (K, d) true image sources (the landmarks of a walk; npz ``landmarks``), for
            evaluation only.
        wall_normals: (W, d) true outward unit wall normals (npz ``wall_normals``), for evaluation
            only; a room that is not a shoebox is given this way, with ``wall_offsets``.
        wall_offsets: (W,) true wall offsets, metres: wall k is {x : n_k . x = offset_k}.
        recorded: True when ``rirs`` holds recordings of an excitation (npz ``recordings``
            instead of ``rirs``), still to be deconvolved.
        excitation: (E,) the excitation the recordings are of (npz ``excitation``), or None.
        emission_delay: seconds from sample 0 to the true emission (npz ``emission_delay``), for
            evaluation only; None when not stated.
    """

    rirs: np.ndarray
    fs: float
    names: tuple[str, ...]
    mics: np.ndarray | None = None
    step_bounds: np.ndarray | None = None
    c: float | None = None
    source: np.ndarray | None = None
    room_size: np.ndarray | None = None
    trajectory: np.ndarray | None = None
    keyframes: np.ndarray | None = None
    landmarks: np.ndarray | None = None
    wall_normals: np.ndarray | None = None
    wall_offsets: np.ndarray | None = None
    recorded: bool = False
    excitation: np.ndarray | None = None
    emission_delay: float | None = None

    @property
    def n_rirs(self) -> int:
        """M."""
        return int(self.rirs.shape[0])


def _natural_key(path: Path) -> list:
    """Sort key of a file name with its numbers compared as numbers (mic2 before mic10)."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def check_fs(fs: object, name: str = "fs") -> float:
    """``fs`` as a positive finite float, Hz; InvalidInputError naming ``name`` otherwise."""
    return as_scalar(fs, name, low=0.0, low_open=True, expected="a positive number of Hz")


def first_bad(x: np.ndarray) -> tuple[int, ...] | None:
    """Index of the first entry of ``x`` that is NaN or infinite, or None when all are finite."""
    bad = np.argwhere(~np.isfinite(x))
    return None if len(bad) == 0 else tuple(int(i) for i in bad[0])


def load_rirs(
    path_or_paths: str | Path | Sequence[str | Path], *, fs: float | None = None
) -> LoadedRirs:
    """Read M RIRs from one ``.npz``, one multichannel WAV, or several mono WAVs.

    Args:
        path_or_paths: one of
            - an ``.npz`` with ``rirs`` (M, L) (or ``recordings`` (M, L) of an ``excitation``
              (E,), then ``recorded`` is True) and ``fs`` (scalar, Hz), and optionally ``mics``
              (M, 3) (or dEchorate's ``mics_v3``), ``step_bounds`` (2, M - 1), ``keyframes``
              (the RIRs that are steps, when not all are), ``c`` (m/s), and
              ground truth for evaluation: ``source`` (or ``src_v3``), ``room_size``,
              ``trajectory`` (M, 3), ``emission_delay`` (s); other arrays are ignored;
            - a ``.sofa`` file of impulse responses (AES69, read with sofar), with the
              microphone and source positions it carries
              (:func:`rangeslam.datasets.sofa_files.load_sofa`);
            - a WAV file: each channel is one RIR;
            - a directory: its WAV files, one mono RIR each, in natural order of their names
              (``mic2.wav`` before ``mic10.wav``);
            - a list of WAV files, one mono RIR each, in the order given.

            Each path is used as given when it exists, else looked up under the data folder
            (:func:`rangeslam.datasets.data_path`: ``$RANGESLAM_DATA``, else ``../shared/data``),
            so ``"dechorate/rirs_src0_12mics.npz"`` reads the dEchorate RIRs.
        fs: sampling rate, Hz, for an npz without ``fs``. When the files state one, ``fs`` must
            agree with it (it is a check, never a resampling).

    Integer PCM is scaled to [-1, 1) (divided by 2^(bits - 1); 8-bit is unsigned, centred first);
    float WAVs are read as they are.

    Raises:
        DataFormatError naming the file: unreadable (empty, not a WAV, a truncated WAV that
        ends before its header says), wrong shapes, NaN or infinite samples, files
        of different lengths or sampling rates (nothing is padded, cropped or resampled), a
        multichannel file among several, ``fs`` missing or contradicting the file.
        InvalidInputError: no such file (DataNotFoundError, naming the paths tried), a directory
        without WAV files, a bad ``fs``.
    """
    if fs is not None:
        fs = check_fs(fs)
    if isinstance(path_or_paths, str | Path):
        p = data_path(path_or_paths, what="RIR file")
        if p.is_dir():
            paths = sorted(
                (q for q in p.iterdir() if q.suffix.lower() == ".wav" and q.is_file()),
                key=_natural_key,
            )
            if not paths:
                npz = sorted(q.name for q in p.glob("*.npz"))
                hint = f"; it holds {', '.join(npz[:3])}: pass that file" if npz else ""
                raise InvalidInputError(f"no .wav files in the directory {p}{hint}")
        else:
            paths = [p]
    elif isinstance(path_or_paths, Sequence) and not isinstance(path_or_paths, bytes):
        if not all(isinstance(q, str | Path) for q in path_or_paths):
            raise InvalidInputError(
                f"path_or_paths must be a path or a list of paths; got {path_or_paths!r:.80}"
            )
        paths = [data_path(q, what="RIR file") for q in path_or_paths]
        if not paths:
            raise InvalidInputError("path_or_paths must name at least one file; got none")
    else:
        raise InvalidInputError(
            f"path_or_paths must be a path or a list of paths; got {type(path_or_paths).__name__}"
        )
    for q in paths:
        if not q.is_file():
            what = "is a directory, not a file" if q.is_dir() else "does not exist"
            raise InvalidInputError(f"RIR file {q} {what}")
    return _load_files(paths, fs)


def _load_files(paths: list[Path], fs: float | None) -> LoadedRirs:
    """The RIRs of existing files ``paths``: one .npz or .sofa, else WAVs."""
    suffixes = {q.suffix.lower() for q in paths}
    if suffixes & {".npz", ".sofa"}:
        if len(paths) != 1:
            raise InvalidInputError(
                "path_or_paths: give one .npz, or WAV files (or one .sofa); got "
                + ", ".join(str(q) for q in paths[:4])
            )
        if paths[0].suffix.lower() == ".sofa":
            from rangeslam.datasets.sofa_files import load_sofa

            return load_sofa(paths[0], fs)
        return _load_npz(paths[0], fs)
    for q in paths:
        if q.suffix.lower() != ".wav":
            alone = " (a beacon log is given alone)" if q.suffix.lower() in (".csv", ".txt") else ""
            raise DataFormatError(f"{q}: not a .wav or .npz file (nor .sofa){alone}")
    return _load_wavs(paths, fs)


def _npz_array(raw: dict, keys: tuple[str, ...], p: Path, shape: tuple[int | None, ...]):
    """The first of ``keys`` in ``raw`` as finite float64 of ``shape`` (None: any size), or None."""
    for key in keys:
        if key in raw:
            try:
                arr = as_float_array(raw[key], key)
            except InvalidInputError as exc:
                raise DataFormatError(f"{p}: {key} is not numeric ({exc})") from exc
            if arr.ndim != len(shape) or any(
                s is not None and a != s for a, s in zip(arr.shape, shape, strict=True)
            ):
                want = shape_str(tuple("*" if s is None else s for s in shape))  # type: ignore[misc]
                raise DataFormatError(
                    f"{p}: {key} must have shape {want}; got {shape_str(arr.shape)}"
                )
            bad = first_bad(arr)
            if bad is not None:
                raise DataFormatError(f"{p}: {key}{list(bad)} is {arr[bad]}, not a finite number")
            return arr
    return None


def _npz_signals(raw: dict, p: Path) -> tuple[str, np.ndarray]:
    """(key, (M, L) float64) of the npz's ``rirs``, else its ``recordings``, checked."""
    key = "recordings" if "recordings" in raw and "rirs" not in raw else "rirs"
    if key not in raw:
        raise DataFormatError(
            f"{p}: no 'rirs' array (M, L) (nor 'recordings'); it holds {sorted(raw)}"
        )
    try:
        rirs = as_float_array(raw[key], key)
    except InvalidInputError as exc:
        raise DataFormatError(f"{p}: {key} is not numeric ({exc})") from exc
    if rirs.ndim != 2 or rirs.shape[1] < 3 or rirs.shape[0] < 1:
        raise DataFormatError(
            f"{p}: {key} must have shape (M, L), one per row; got {shape_str(rirs.shape)}"
        )
    bad = first_bad(rirs)
    if bad is not None:
        raise DataFormatError(f"{p}: {key}[{bad[0]}] sample {bad[1]} is {rirs[bad]}")
    return key, rirs


def transposed_by(shape: tuple[int, int], counts: dict[str, int]) -> str | None:
    """The first name in ``counts`` (what each other array says M is: {what: count}) that
    gives the RIRs' length L rather than M, for RIRs of ``shape`` (M, L) with M != L: evidence
    they were stored transposed; None when there is none."""
    m, length = shape
    if m == length:
        return None
    return next((what for what, count in counts.items() if count == length), None)


def check_orientation(raw: dict, key: str, shape: tuple[int, int], p: Path) -> None:
    """DataFormatError naming ``key`` (the RIRs, (M, L)) when the npz's microphones (M, 3),
    step bounds (2, M - 1) or trajectory (M, d) count L of them instead of M: the RIRs were
    stored transposed, (L, M), and the other array is right (it was blamed instead)."""
    counts = {}
    for name in ("mics", "mics_v3"):
        if name in raw and np.ndim(raw[name]) == 2 and np.shape(raw[name])[1] == 3:
            counts[f"{name} {shape_str(np.shape(raw[name]))}"] = np.shape(raw[name])[0]
    if "keyframes" not in raw:
        if "step_bounds" in raw and np.ndim(raw["step_bounds"]) == 2:
            b = np.shape(raw["step_bounds"])
            counts[f"step_bounds {shape_str(b)}"] = b[1] + 1
        if "trajectory" in raw and np.ndim(raw["trajectory"]) == 2:
            counts[f"trajectory {shape_str(np.shape(raw['trajectory']))}"] = len(raw["trajectory"])
    what = transposed_by(shape, counts)
    if what is not None:
        raise DataFormatError(transposed_message(str(p), key, shape, what))


def transposed_message(where: str, key: str, shape: tuple[int, int], what: str) -> str:
    """The error of RIRs ``key`` of ``shape`` in the file ``where`` stored transposed, as
    ``what`` shows."""
    m, length = shape
    return (
        f"{where}: {key} must have shape (M, L), one RIR of L samples per row; got "
        f"{shape_str(shape)}, and {what} counts {length} RIRs: {key} is stored transposed "
        f"(save {key}.T, shape ({length}, {m}))"
    )


def check_transposed(loaded: LoadedRirs, what: str, count: int) -> None:
    """DataFormatError naming the npz's RIRs (not ``what``, an array given beside them that
    counts ``count`` RIRs) when they were stored transposed: ``count`` is their length L, not
    their number M. WAV channels cannot be transposed: nothing to check for them."""
    where, _, key = loaded.names[0].partition(":")
    if not where.lower().endswith(".npz") or not key:
        return
    if transposed_by(loaded.rirs.shape, {what: count}) is not None:
        key = key.split("[")[0]
        raise DataFormatError(transposed_message(where, key, loaded.rirs.shape, what))


def _load_npz(p: Path, fs: float | None) -> LoadedRirs:
    """The RIRs and whatever else the npz ``p`` holds, each array checked."""
    if not zipfile.is_zipfile(p):
        raise DataFormatError(
            f"{p}: not an npz file (an npz is a zip archive of .npy arrays, as numpy.savez "
            "writes it)"
        )
    try:
        with np.load(p, allow_pickle=False) as data:
            raw = {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise DataFormatError(f"{p}: not a readable npz file ({exc})") from exc
    key, rirs = _npz_signals(raw, p)
    check_orientation(raw, key, rirs.shape, p)
    m = rirs.shape[0]
    file_fs = _npz_array(raw, ("fs",), p, ())
    if file_fs is None and fs is None:
        raise DataFormatError(f"{p}: no 'fs' array; give the sampling rate (fs=, --fs)")
    if file_fs is not None:
        file_fs = float(file_fs)
        if not file_fs > 0:
            raise DataFormatError(f"{p}: fs must be a positive number of Hz; got {file_fs:g}")
        if fs is not None and fs != file_fs:
            raise DataFormatError(f"{p}: fs is {file_fs:g} Hz, but fs={fs:g} was given")
    mics = _npz_array(raw, ("mics", "mics_v3"), p, (m, 3))
    bounds = _npz_array(raw, ("step_bounds",), p, (2, None))
    c = _npz_array(raw, ("c",), p, ())
    if c is not None and not c > 0:
        raise DataFormatError(f"{p}: c must be a positive speed of sound in m/s; got {c}")
    excitation = _npz_array(raw, ("excitation",), p, (None,))
    delay = _npz_array(raw, ("emission_delay",), p, ())
    source = _npz_array(raw, ("source", "src_v3"), p, (None,))
    size = _npz_array(raw, ("room_size",), p, (3,))
    trajectory = _npz_array(raw, ("trajectory",), p, (None, None))
    landmarks = _npz_array(raw, ("landmarks",), p, (None, None))
    normals = _npz_array(raw, ("wall_normals",), p, (None, None))
    offsets = _npz_array(raw, ("wall_offsets",), p, (None,))
    if (normals is None) != (offsets is None) or (
        normals is not None and len(normals) != len(offsets)
    ):
        raise DataFormatError(
            f"{p}: wall_normals (W, d) and wall_offsets (W,) come together, one row per wall"
        )
    keys = None
    if "keyframes" in raw:
        keys = np.asarray(raw["keyframes"])
        if keys.ndim != 1 or not np.issubdtype(keys.dtype, np.integer):
            raise DataFormatError(f"{p}: keyframes must be (M,) integers; got {keys.dtype}")
    n_steps = m if keys is None else len(keys)
    if bounds is not None and bounds.shape != (2, n_steps - 1):
        raise DataFormatError(
            f"{p}: step_bounds must have shape (2, {n_steps - 1}) for {n_steps} steps; got "
            f"{shape_str(bounds.shape)}"
        )
    return LoadedRirs(
        rirs=frozen(rirs),
        fs=float(file_fs if file_fs is not None else fs),
        names=tuple(f"{p.name}:{key}[{i}]" for i in range(m)),
        mics=None if mics is None else frozen(mics),
        step_bounds=None if bounds is None else frozen(bounds),
        c=None if c is None else float(c),
        source=None if source is None else frozen(source),
        room_size=None if size is None else frozen(size),
        trajectory=None if trajectory is None else frozen(trajectory),
        keyframes=None if keys is None else frozen(keys.astype(int)),
        landmarks=None if landmarks is None else frozen(landmarks),
        wall_normals=None if normals is None else frozen(normals),
        wall_offsets=None if offsets is None else frozen(offsets),
        recorded=key == "recordings",
        excitation=None if excitation is None else frozen(excitation),
        emission_delay=None if delay is None else float(delay),
    )


def wav_data_shortfall(q: Path) -> int:
    """Bytes the ``data`` chunk of the RIFF/RIFX WAV ``q`` declares but the file does not hold.

    0 for a complete file, and for anything this walk cannot follow (RF64, a malformed header):
    scipy's reader judges those. Catches a file cut inside its samples even when its RIFF size
    was rewritten to match (scipy then reads the samples that are there without a warning).
    """
    found = _find_chunk(q, b"data")
    return 0 if found is None else max(0, found[0] + found[1] - q.stat().st_size)


def wav_channels(q: Path) -> int | None:
    """The number of channels the ``fmt`` chunk of the RIFF/RIFX WAV ``q`` declares; None for
    anything this walk cannot follow (the loader judges such a file)."""
    found = _find_chunk(q, b"fmt ")
    if found is None:
        return None
    with q.open("rb") as f:
        f.seek(found[0])
        body = f.read(4)
    return struct.unpack(found[2] + "HH", body)[1] if len(body) == 4 else None


def _find_chunk(q: Path, wanted: bytes) -> tuple[int, int, str] | None:
    """(offset of its body, its declared size, byte order) of the first ``wanted`` chunk of the
    RIFF/RIFX WAV ``q``; None when there is none or the walk cannot follow the file."""
    size = q.stat().st_size
    with q.open("rb") as f:
        head = f.read(12)
        if len(head) < 12 or head[:4] not in (b"RIFF", b"RIFX") or head[8:12] != b"WAVE":
            return None
        order = "<" if head[:4] == b"RIFF" else ">"
        pos = 12
        while pos + 8 <= size:
            f.seek(pos)
            chunk_id, chunk_size = struct.unpack(order + "4sI", f.read(8))
            if chunk_id == wanted:
                return pos + 8, chunk_size, order
            pos += 8 + chunk_size + (chunk_size % 2)
    return None


def one_per_loudspeaker(paths: Sequence[Path]) -> bool:
    """True when the RIRS ``paths`` (two or more) are one loudspeaker each: ``.npz`` files,
    multichannel WAVs (channel m: microphone m) or directories of mono WAVs; False when they are
    mono WAVs, one microphone each, of one loudspeaker (or anything else: the loader judges it).

    Raises:
        InvalidInputError naming RIRS: the forms mixed (an .npz among WAVs, mono WAVs among
        multichannel ones, directories among files).
    """
    kinds = {}
    for q in map(Path, paths):
        if q.is_dir():
            kinds[q] = "a directory of mono WAVs"
        elif q.suffix.lower() in (".npz", ".sofa"):
            kinds[q] = "an .npz"  # a .sofa file too: one loudspeaker's RIRs
        elif q.suffix.lower() == ".wav" and q.is_file():
            channels = wav_channels(q)  # None: not a WAV this walk follows
            kinds[q] = {None: "a WAV", 1: "a mono WAV"}.get(channels, "a multichannel WAV")
        else:
            kinds[q] = "another file"
    forms = set(kinds.values())
    if len(forms) > 1 and ("an .npz" in forms or not forms & {"another file", "a WAV"}):
        first = {form: q for q, form in reversed(kinds.items())}  # each form's first path
        examples = [f"{q} ({form})" for form, q in reversed(first.items())]
        raise InvalidInputError(
            "RIRS: several files are one loudspeaker each (.npz files, multichannel WAVs or "
            "directories of mono WAVs) or one microphone each (mono WAVs), not a mix; got "
            + ", ".join(examples)
        )
    return len(forms) == 1 and not forms & {"a mono WAV", "a WAV", "another file"}


def _read_wav(q: Path) -> tuple[float, np.ndarray]:
    """(fs, (C, N) float64) of one WAV file, int PCM scaled to [-1, 1)."""
    from scipy.io import wavfile

    if q.stat().st_size == 0:
        raise DataFormatError(f"{q}: empty file (0 bytes), not a WAV file")
    try:
        with warnings.catch_warnings(record=True) as caught:
            # Record scipy's WavFileWarnings: unknown chunks (cue, list) are harmless, but a file
            # that ends before its header says (truncated) would otherwise load silently with the
            # samples it has.
            warnings.simplefilter("always", wavfile.WavFileWarning)
            rate, data = wavfile.read(q)
    except (
        OSError,
        ValueError,
        EOFError,
        struct.error,
        MemoryError,
        OverflowError,
        IndexError,
        ZeroDivisionError,  # a header declaring 0 channels or 0 bytes per sample
        TypeError,  # a damaged format field: numpy is asked for a dtype such as '<f251'
        UnboundLocalError,  # scipy 1.17 on a file without a data chunk
    ) as exc:
        raise DataFormatError(f"{q}: not a readable WAV file ({exc})") from exc
    for w in caught:
        text = str(w.message)
        if not issubclass(w.category, wavfile.WavFileWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        elif TRUNCATED.search(text):
            raise DataFormatError(
                f"{q}: truncated WAV file: it ends before its header says ({text}); "
                "re-export or copy it again"
            )
    short = wav_data_shortfall(q)
    if short:
        raise DataFormatError(
            f"{q}: truncated WAV file: its data chunk is {short} bytes shorter than its header "
            "says; re-export or copy it again"
        )
    data = np.asarray(data)
    if data.dtype.kind not in "iuf" or data.ndim not in (1, 2):
        raise DataFormatError(
            f"{q}: not a readable WAV file (samples of dtype {data.dtype}, {data.ndim} dims)"
        )
    if data.dtype == np.uint8:
        x = (data.astype(float) - 128.0) / 128.0
    elif np.issubdtype(data.dtype, np.integer):
        x = data.astype(float) / float(2 ** (8 * data.dtype.itemsize - 1))
    else:
        x = data.astype(float)
    x = x.reshape(len(x), -1).T
    if x.shape[1] < 3:
        raise DataFormatError(f"{q}: holds {x.shape[1]} samples; a RIR needs at least 3")
    bad = first_bad(x)
    if bad is not None:
        where = f"channel {bad[0]} " if x.shape[0] > 1 else ""
        raise DataFormatError(f"{q}: {where}sample {bad[1]} is {x[bad]}, not a finite number")
    return float(rate), x


def _load_wavs(paths: list[Path], fs: float | None) -> LoadedRirs:
    """The RIRs of one multichannel WAV or several mono WAVs of one length and sampling rate."""
    read = []
    for q in paths:
        rate, x = _read_wav(q)
        if rate <= 0:
            raise DataFormatError(f"{q}: sampling rate {rate:g} Hz in the header")
        if fs is not None and rate != fs:
            raise DataFormatError(f"{q}: sampled at {rate:g} Hz, but fs={fs:g} was given")
        if len(paths) > 1 and x.shape[0] > 1:
            raise DataFormatError(
                f"{q}: has {x.shape[0]} channels; with several files each must be mono (one RIR "
                "per file), or give one multichannel file"
            )
        q0, rate0, x0 = read[0] if read else (q, rate, x)
        if rate != rate0:
            raise DataFormatError(
                f"{q}: sampled at {rate:g} Hz, but {q0} at {rate0:g} Hz; RIRs must share one "
                "sampling rate (resample them first)"
            )
        if x.shape[1] != x0.shape[1]:
            raise DataFormatError(
                f"{q}: has {x.shape[1]} samples, but {q0} has {x0.shape[1]}; RIRs must all have "
                "the same length, sample 0 at the emission (nothing is padded or cropped)"
            )
        read.append((q, rate, x))
    names = [
        name
        for q, _, x in read
        for name in ([q.name] if len(x) == 1 else [f"{q.name}:channel {c}" for c in range(len(x))])
    ]
    return LoadedRirs(
        rirs=frozen(np.vstack([x for _, _, x in read])), fs=read[0][1], names=tuple(names)
    )


def load_excitation(path: str | Path) -> tuple[float | None, np.ndarray]:
    """(fs or None, (E,) samples) of an excitation signal: a mono WAV (its rate; int PCM scaled to
    [-1, 1)), an ``.npy`` or a ``.csv`` / ``.txt`` column of numbers (no rate: the recordings').

    Raises:
        InvalidInputError: no such file. DataFormatError naming the file: unreadable, not mono
        or one column, fewer than 1 sample, NaN or infinite samples, all zeros.
    """
    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(f"{p}: no such file")
    rate = None
    if p.suffix.lower() == ".wav":
        rate, x = _read_wav(p)
        if x.shape[0] != 1:
            raise DataFormatError(f"{p}: has {x.shape[0]} channels; an excitation is mono")
        x = x[0]
    else:
        try:
            x = read_numbers(p, ndmin=1)
        except (OSError, ValueError) as exc:  # UnicodeDecodeError is a ValueError
            raise DataFormatError(f"{p}: not a readable excitation ({exc})") from exc
        if x.ndim == 2 and 1 in x.shape:
            x = x.reshape(-1)
        if x.ndim != 1 or len(x) < 1:
            raise DataFormatError(
                f"{p}: an excitation is one signal, (E,); got shape {shape_str(x.shape)}"
            )
    bad = first_bad(x)
    if bad is not None:
        raise DataFormatError(f"{p}: sample {bad[0]} is {x[bad]}, not a finite number")
    if not np.any(x):
        raise DataFormatError(f"{p}: every sample is 0; an excitation must play something")
    return rate, frozen(x)


def read_numbers(path: Path, *, ndmin: int) -> np.ndarray:
    """The float64 array of an ``.npy``, or of a ``.csv`` / ``.txt`` (comma- or
    whitespace-separated, '#' comments, a first row of column names such as ``x,y,z`` skipped;
    at least ``ndmin`` dimensions). Raises what numpy raises (OSError, ValueError): each caller
    names the file and what it wanted."""
    if path.suffix.lower() == ".npy":
        arr = np.load(path, allow_pickle=False)
    else:
        lines = without_header(path.read_text().splitlines())
        delimiter = "," if any("," in line.split("#")[0] for line in lines) else None
        arr = np.loadtxt(lines, delimiter=delimiter, ndmin=ndmin)
    return np.asarray(arr, dtype=float)


def without_header(lines: list[str]) -> list[str]:
    """``lines`` of numbers with the first row blanked (so the others keep their numbers) when
    none of its fields is a number: column names, ``x,y,z``."""
    for k, line in enumerate(lines):
        fields = [f for f in re.split(r"[,\s]+", line.split("#")[0]) if f]
        if not fields:
            continue
        for f in fields:
            try:
                float(f)
            except ValueError:
                continue
            return lines  # a number: the first row is data
        return [*lines[:k], "", *lines[k + 1 :]]
    return lines
