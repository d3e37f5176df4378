"""dEchorate-style echo-pick errors: simulated first-order echo ranges as a real picker gets them.

The measured dEchorate picks (Di Carlo et al., EURASIP JASMP 2021; 30 microphones in six
horizontal linear arrays of five, loudspeakers 0 and 1, direct path + six first-order echoes)
are not "Gaussian noise plus a few outliers": their errors are correlated within each 5-mic
array. Measured minus true range over the 2 x 30 x 7 real picks (the numbers the defaults of
:class:`PickErrorModel` were taken from; array = one linear array, column = one echo):

* Per-pick scatter about a smooth trend along an array: 0 cm (the picks agree to 1 mm) for
  56% of the (column, array) blocks, 0.2-1.3 cm for most of the others (the 90th percentile
  is 0.9 cm), 1.9-3.6 cm for four blocks that hold a partial wrong pick.
* Per-(column, array) biases: |bias| quartiles 0.4 / 0.9 / 1.7 cm on the good blocks (direct
  path within 0.1-1 cm, ceiling within 0.1-1.9 cm); plus "biased columns" where several arrays
  pick a few cm late: loudspeaker 0 west +4.4..+8.0 cm on 4 of 6 arrays (trends along the
  array of -37..+30 cm/m), loudspeaker 0 floor +4.9..+6.3 cm on 3 arrays, loudspeaker 1 floor
  +6.8 cm on 1 array: 3 such columns of the 10 non-phantom wall columns, 8 of their 18 arrays.
* Phantom columns, one per loudspeaker: loudspeaker 0 south +47, +47, +12, +60, +62 cm on 5 of
  6 arrays (the sixth right), loudspeaker 1 north -60, -58, -13, -11, -6, -14 cm on all 6; one
  sign per column, trends along the array within +-10 cm/m, scatter 0.2-0.5 cm. Plus two
  single-array phantoms: loudspeaker 1 west -26..-32 cm on array 3 (-28 cm/m) and loudspeaker 1
  east -2..-13 cm on array 0 (-45 cm/m): 2 of the other 58 wall (column, array) blocks.
* Isolated gross errors: +4.90 m (loudspeaker 1 south, mic 18) and -2.23 m (loudspeaker 1 west,
  mic 27): 2 of the 360 wall picks. Isolated glitches of 2-7 cm on single picks: 5 of 360.

:func:`dechorate_picks` draws new errors of these kinds for one loudspeaker;
:func:`random_loudspeaker` and :func:`simulate_loudspeakers` draw new loudspeakers in the
dEchorate room so that calibration rules can be checked on scenes they were not tuned on.
Ranges are in metres; every random function takes ``rng`` (anything ``np.random.default_rng``
accepts) and never touches global random state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rangeslam.errors import InvalidInputError
from rangeslam.geometry.room import Room

__all__ = [
    "CLEAN",
    "GLITCH",
    "GROSS",
    "PHANTOM",
    "SHIFTED",
    "EchoPicks",
    "PickErrorModel",
    "dechorate_picks",
    "echo_ranges_dechorate",
    "random_loudspeaker",
    "simulate_loudspeakers",
]

#: Kinds of pick in :attr:`EchoPicks.kind`: right to within the noise and a small bias, in a
#: biased column (a few cm), a phantom reflection (tens of cm), an isolated glitch (a few cm),
#: an isolated gross error (metres).
CLEAN, SHIFTED, PHANTOM, GLITCH, GROSS = 0, 1, 2, 3, 4

#: Columns of one loudspeaker's block: direct path, then the six walls in Room.shoebox order.
N_COLUMNS = 7
_DIRECT, _CEILING = 0, 6
#: Wall columns that can be biased or phantom (the ceiling picks were all good: within 1.9 cm).
_WALLS = (1, 2, 3, 4, 5)


@dataclass(frozen=True)
class PickErrorModel:
    """Rates and magnitudes of dEchorate-style pick errors (lengths in metres, slopes in m/m).

    Attributes:
        noise_good: per-(column, array) scatter of the picks about their trend is drawn
            log-uniformly in this range for the direct path and ceiling (real: 0-0.2 cm).
        noise_walls: the same for the other walls (real: 0-1.3 cm, a few blocks 2-3.6 cm).
        bias_std: per-(column, array) bias, normal (real |bias| quartiles 0.4 / 0.9 / 1.7 cm).
        bias_slope_std: trend along the array of those biases, normal (real: mostly within
            +-5 cm/m, i.e. +-0.6 cm over the 25.5 cm arrays).
        biased_column_p: probability that a wall column is a "biased column" (real: 3 of 10).
        biased_array_p: in a biased column, probability that an array is biased (real: 8 of 18).
        biased_range: its bias, uniform in this range, positive (late picks; real: +4.4..+8 cm).
        biased_slope_std: trend along the array in a biased column (real: -37..+30 cm/m).
        phantom_counts: probabilities of 0, 1, 2 phantom columns per loudspeaker (real: one in
            each of the two; the rate of none or two is a guess).
        phantom_array_p: in a phantom column, probability that an array hears the phantom
            (real: 11 of 12).
        phantom_near_p: probability that a phantom array's offset is "near" (real: 6 of 11).
        phantom_near, phantom_far: uniform ranges of |offset| (real: 6-14 cm and 47-62 cm).
        phantom_slope_std: trend along the array of a phantom offset (real: within +-10 cm/m).
        phantom_noise: scatter about it, uniform (real: 0.1-0.5 cm).
        single_phantom_p: probability per other wall (column, array) of a phantom heard by that
            array only (real: 2 of 58), |offset| uniform in ``single_phantom_range`` (real: 2-32
            cm) with trend std ``single_phantom_slope_std`` (real: -28 and -45 cm/m).
        glitch_p, glitch_range: probability per wall pick of an isolated error and its magnitude
            range, sign random (real: 5 of 360, 2-7 cm).
        gross_p, gross_range: the same for isolated gross errors (real: 2 of 360, 2.2 and 4.9 m;
            a gross error that would make a range negative is flipped to positive).
    """

    noise_good: tuple[float, float] = (0.0005, 0.003)
    noise_walls: tuple[float, float] = (0.001, 0.015)
    bias_std: float = 0.01
    bias_slope_std: float = 0.05
    biased_column_p: float = 0.3
    biased_array_p: float = 0.45
    biased_range: tuple[float, float] = (0.04, 0.08)
    biased_slope_std: float = 0.2
    phantom_counts: tuple[float, float, float] = (0.2, 0.55, 0.25)
    phantom_array_p: float = 0.9
    phantom_near_p: float = 0.5
    phantom_near: tuple[float, float] = (0.05, 0.15)
    phantom_far: tuple[float, float] = (0.40, 0.65)
    phantom_slope_std: float = 0.05
    phantom_noise: tuple[float, float] = (0.001, 0.005)
    single_phantom_p: float = 0.035
    single_phantom_range: tuple[float, float] = (0.05, 0.35)
    single_phantom_slope_std: float = 0.3
    glitch_p: float = 0.014
    glitch_range: tuple[float, float] = (0.02, 0.07)
    gross_p: float = 0.0055
    gross_range: tuple[float, float] = (1.0, 5.0)


DEFAULT_MODEL = PickErrorModel()


@dataclass(frozen=True)
class EchoPicks:
    """Simulated picks of one or more loudspeakers (M microphones, K = 7 x loudspeakers).

    Attributes:
        ranges: (M, K) measured ranges, metres (true + errors).
        true_ranges: (M, K) true ranges, metres.
        kind: (M, K) int, the kind of error of each pick (CLEAN, SHIFTED, PHANTOM, GLITCH, GROSS).
        sources: (L, 3) the loudspeakers, metres (empty (0, 3) from :func:`dechorate_picks`).
    """

    ranges: np.ndarray
    true_ranges: np.ndarray
    kind: np.ndarray
    sources: np.ndarray

    @property
    def errors(self) -> np.ndarray:
        """(M, K) measured minus true range, metres."""
        return self.ranges - self.true_ranges


def _positions_along_arrays(mics: np.ndarray, arrays: np.ndarray) -> np.ndarray:
    """(M,) signed position of each microphone along its array's line (first to last mic),
    from the array's centroid, metres (0 for a one-mic array)."""
    t = np.zeros(len(mics))
    for a in np.unique(arrays):
        idx = np.flatnonzero(arrays == a)
        pts = mics[idx]
        axis = pts[-1] - pts[0]
        norm = float(np.linalg.norm(axis))
        if norm > 0:
            t[idx] = (pts - pts.mean(axis=0)) @ (axis / norm)
    return t


def _uniform_magnitude(rng: np.random.Generator, bounds: tuple[float, float], size=None):
    return rng.uniform(bounds[0], bounds[1], size)


def dechorate_picks(
    mics: ArrayLike,
    arrays: ArrayLike,
    true_ranges: ArrayLike,
    rng=None,
    model: PickErrorModel = DEFAULT_MODEL,
) -> EchoPicks:
    """Measured ranges of one loudspeaker as the dEchorate picker gets them.

    Args:
        mics: (M, 3) microphone positions, metres (used for the trends along each array).
        arrays: (M,) int, the linear array each microphone belongs to.
        true_ranges: (M, 7) true ranges, metres: direct path, then the first-order images of the
            west, east, south, north, floor and ceiling walls (Room.shoebox order).
        rng: anything ``np.random.default_rng`` accepts.
        model: rates and magnitudes (:class:`PickErrorModel`; defaults measured on dEchorate).

    Returns:
        :class:`EchoPicks` with (M, 7) ``ranges``, ``true_ranges`` and ``kind``. Errors, in
        order: (a) per-pick noise, its std drawn per (column, array); (b) a bias per (column,
        array) with a linear trend along the array, a few cm in "biased columns"; (c) phantom
        columns: 0-2 wall columns where most arrays hear a wrong reflection, tens of cm off (one
        sign per column, the magnitude per array, a small trend along it), and rare phantoms
        heard by one array; (d) rare isolated glitches (cm) and gross errors (metres).
    """
    rng = np.random.default_rng(rng)
    mics = np.asarray(mics, dtype=float)
    arrays = np.asarray(arrays)
    true = np.asarray(true_ranges, dtype=float)
    m = len(mics)
    if mics.shape != (m, 3) or arrays.shape != (m,) or true.shape != (m, N_COLUMNS):
        raise InvalidInputError(
            f"need mics (M, 3), arrays (M,) and true_ranges (M, {N_COLUMNS}); got "
            f"{mics.shape}, {arrays.shape}, {true.shape}"
        )
    t = _positions_along_arrays(mics, arrays)
    labels = np.unique(arrays)
    err = np.zeros((m, N_COLUMNS))
    kind = np.full((m, N_COLUMNS), CLEAN)

    # (c) phantom columns, chosen first: they replace the bias of the arrays that hear them.
    n_phantom = int(rng.choice(len(model.phantom_counts), p=model.phantom_counts))
    phantoms = rng.choice(_WALLS, size=n_phantom, replace=False)
    biased = {c for c in _WALLS if rng.random() < model.biased_column_p}
    for c in range(N_COLUMNS):
        good = c in (_DIRECT, _CEILING)
        sign = rng.choice((-1.0, 1.0))
        for a in labels:
            idx = arrays == a
            ta, n = t[idx], int(idx.sum())
            if c in phantoms and rng.random() < model.phantom_array_p:
                near = rng.random() < model.phantom_near_p
                size = _uniform_magnitude(rng, model.phantom_near if near else model.phantom_far)
                slope = rng.normal(0.0, model.phantom_slope_std)
                noise = _uniform_magnitude(rng, model.phantom_noise)
                err[idx, c] = sign * size + slope * ta + rng.normal(0.0, noise, n)
                kind[idx, c] = PHANTOM
                continue
            lo, hi = model.noise_good if good else model.noise_walls
            noise = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
            bias = rng.normal(0.0, model.bias_std)
            slope = rng.normal(0.0, model.bias_slope_std)
            if c in biased and rng.random() < model.biased_array_p:
                bias = _uniform_magnitude(rng, model.biased_range)
                slope = rng.normal(0.0, model.biased_slope_std)
                kind[idx, c] = SHIFTED
            elif not good and c not in phantoms and rng.random() < model.single_phantom_p:
                bias = rng.choice((-1.0, 1.0)) * _uniform_magnitude(rng, model.single_phantom_range)
                slope = rng.normal(0.0, model.single_phantom_slope_std)
                kind[idx, c] = PHANTOM
            err[idx, c] = bias + slope * ta + rng.normal(0.0, noise, n)

    add_isolated_errors(true, err, kind, model, rng)  # (d)
    return EchoPicks(true + err, true, kind, np.zeros((0, 3)))


def add_isolated_errors(
    true: np.ndarray, err: np.ndarray, kind: np.ndarray, model: PickErrorModel, rng
) -> None:
    """(d) of :func:`dechorate_picks`: isolated glitches (cm) and gross errors (metres) added to
    ``err`` (M, 7) in place, on wall picks only (the direct paths were all good); ``kind`` (M, 7)
    labelled to match. A gross error never makes a range negative."""
    m = true.shape[0]
    walls = np.zeros((m, N_COLUMNS), dtype=bool)
    walls[:, list(_WALLS)] = True
    u = rng.random((m, N_COLUMNS))
    gross = walls & (u < model.gross_p)
    glitch = walls & ~gross & (u < model.gross_p + model.glitch_p)
    signs = rng.choice((-1.0, 1.0), size=(m, N_COLUMNS))
    err[glitch] += signs[glitch] * _uniform_magnitude(rng, model.glitch_range, int(glitch.sum()))
    kind[glitch & (kind == CLEAN)] = GLITCH
    jump = signs[gross] * _uniform_magnitude(rng, model.gross_range, int(gross.sum()))
    base = (true + err)[gross]
    err[gross] += np.where(base + jump > 0, jump, np.abs(jump))
    kind[gross] = GROSS


def echo_ranges_dechorate(mics: ArrayLike, source: ArrayLike, room_size: ArrayLike) -> np.ndarray:
    """(M, 7) true ranges from ``mics`` (M, 3) to ``source`` (3,) and its six first-order images
    in the shoebox [0, L] x [0, W] x [0, H] (``room_size`` (3,)), metres, columns as the
    dEchorate picks (direct, west, east, south, north, floor, ceiling)."""
    mics = np.asarray(mics, dtype=float)
    src = np.asarray(source, dtype=float).reshape(3)
    images = Room.shoebox(np.asarray(room_size, dtype=float)).image_sources(src, 1).positions
    points = np.vstack([src[None, :], images])
    return np.linalg.norm(mics[:, None, :] - points[None, :, :], axis=2)


#: Draws of a loudspeaker position before giving up (the dEchorate room takes one or two).
MAX_DRAWS = 10_000


def random_loudspeaker(
    room_size: ArrayLike, mics: ArrayLike, rng=None, margin: float = 0.5
) -> np.ndarray:
    """(3,) a loudspeaker drawn uniformly in the shoebox [0, L] x [0, W] x [0, H] (``room_size``
    (3,), metres), at least ``margin`` metres from every wall and from every mic ((M, 3))."""
    rng = np.random.default_rng(rng)
    size = np.asarray(room_size, dtype=float).reshape(3)
    mics = np.asarray(mics, dtype=float)
    if np.any(size <= 2 * margin):
        raise InvalidInputError(f"room {size} has no point {margin} m from every wall")
    for _ in range(MAX_DRAWS):
        p = rng.uniform(margin, size - margin)
        if np.min(np.linalg.norm(mics - p, axis=1)) >= margin:
            return p
    raise InvalidInputError(f"no point found {margin} m from the walls and every mic")


def simulate_loudspeakers(
    mics: ArrayLike,
    arrays: ArrayLike,
    room_size: ArrayLike,
    n_loudspeakers: int,
    rng=None,
    model: PickErrorModel = DEFAULT_MODEL,
) -> EchoPicks:
    """``n_loudspeakers`` new loudspeakers in the dEchorate room and their picked echo ranges.

    Loudspeaker ``s`` is drawn, with its errors, from ``np.random.default_rng(seed(s))`` where
    the seeds are spawned from ``rng``: the first loudspeakers of a scene do not depend on how
    many are drawn (a scene of 2 is the first half of the scene of 4 at the same ``rng`` seed).

    Args:
        mics: (M, 3) microphones, metres; arrays: (M,) their linear array ids.
        room_size: (3,) L, W, H of the shoebox, metres.
        n_loudspeakers: L >= 1.
        rng: an int seed, a SeedSequence, or anything ``np.random.default_rng`` accepts.
        model: the pick-error model (:class:`PickErrorModel`).

    Returns:
        :class:`EchoPicks`: (M, 7 L) ranges, true ranges and kinds, the blocks of the
        loudspeakers side by side (hstack, as ``np.hstack([data.ranges(0), data.ranges(1)])``),
        and (L, 3) sources.
    """
    if isinstance(rng, int | np.integer | np.random.SeedSequence | None):
        seq = rng if isinstance(rng, np.random.SeedSequence) else np.random.SeedSequence(rng)
    else:
        seq = np.random.SeedSequence(np.random.default_rng(rng).integers(2**63))
    blocks, sources = [], []
    for child in seq.spawn(int(n_loudspeakers)):
        g = np.random.default_rng(child)
        src = random_loudspeaker(room_size, mics, g)
        true = echo_ranges_dechorate(mics, src, room_size)
        blocks.append(dechorate_picks(mics, arrays, true, g, model))
        sources.append(src)
    if not blocks:
        raise InvalidInputError("n_loudspeakers must be at least 1")
    return EchoPicks(
        np.hstack([b.ranges for b in blocks]),
        np.hstack([b.true_ranges for b in blocks]),
        np.hstack([b.kind for b in blocks]),
        np.array(sources),
    )
