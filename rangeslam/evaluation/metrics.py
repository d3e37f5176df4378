"""Errors against ground truth: walls, trajectories after rigid alignment (APE), NEES.

Pure numpy (and scipy.stats for the NEES band); every function takes estimates and the truth and
returns numbers, never touching files or plots.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_float_array, as_points, shape_str
from rangeslam.errors import InvalidInputError
from rangeslam.geometry.alignment import Alignment, align
from rangeslam.geometry.room import Room

__all__ = [
    "ATTAINED_RTOL",
    "SHOEBOX_WALLS",
    "ApeStatistics",
    "BoundComparison",
    "PositionErrors",
    "ape",
    "ape_statistics",
    "mean_nees",
    "planar_source_error",
    "rms_against_bound",
    "shoebox_wall_errors",
    "trajectory_nees",
    "trajectory_rmse",
    "wall_errors",
]

#: Names of the walls of ``Room.shoebox(size)`` (its order), as :func:`shoebox_wall_errors` uses.
SHOEBOX_WALLS = ("west x0", "east xL", "south y0", "north yW", "floor z0", "ceiling zH")


def shoebox_wall_errors(
    wall_normals: ArrayLike,
    wall_offsets: ArrayLike,
    room_size: ArrayLike,
    *,
    max_angle: float = 25.0,
) -> np.ndarray:
    """(6,) metres: how far each wall of the shoebox [0, L] x [0, W] x [0, H] is from its estimate.

    For true wall k (``Room.shoebox`` order, :data:`SHOEBOX_WALLS`), the estimated wall with the
    nearest normal; the error is the distance from the centre of the true wall (the room's centre
    projected onto it) to that plane. inf when no estimated normal is within ``max_angle`` degrees.
    """
    normals = as_points(wall_normals, "wall_normals", dim=3)
    offsets = as_float_array(wall_offsets, "wall_offsets")
    if offsets.shape != (len(normals),):
        raise InvalidInputError(
            f"wall_offsets must have shape ({len(normals)},); got {shape_str(offsets.shape)}"
        )
    room = Room.shoebox(room_size)
    centre = np.asarray(room_size, dtype=float) / 2
    out = []
    for n_true, o_true in zip(room.normals, room.offsets, strict=True):
        p = centre + (o_true - n_true @ centre) * n_true
        cos = normals @ n_true
        j = int(np.argmax(cos))
        ok = cos[j] > np.cos(np.radians(max_angle))
        out.append(abs(normals[j] @ p - offsets[j]) if ok else np.inf)
    return np.array(out)


def wall_errors(
    room: Room, normals: np.ndarray, offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Offset errors (K,) in metres and normal angle errors (K,) in degrees, walls in the same order.

    The offset error of wall k is the distance from the true wall's centroid p_k (the paper's
    description of a wall by n_k and p_k) to the estimated plane, |n_k_est . p_k - o_k_est|: the
    offset where the wall is, independent of where the coordinate origin happens to be.
    """
    cos = np.clip(np.einsum("kd,kd->k", normals, room.normals), -1.0, 1.0)
    offset_err = np.abs(np.einsum("kd,kd->k", normals, room.wall_centroids) - offsets)
    return offset_err, np.degrees(np.arccos(cos))


def trajectory_rmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    """RMS error (metres) of ``estimate`` (M, d) against ``truth`` (M, d) after the best rigid
    motion with reflection (a SLAM frame is arbitrary up to both)."""
    return float(align(estimate, truth, reflection=True).rmse)


def trajectory_nees(
    alignment: Alignment, cov: np.ndarray | None, truth: np.ndarray, dof: int | None = None
) -> tuple[float, int]:
    """NEES of an aligned trajectory: e^T P^+ e with e (M d,) the error after ``alignment`` and
    P (M d, M d) the estimate's covariance rotated into the truth's frame; P^+ keeps its ``dof``
    largest eigenvalues (``eigh``): by default M d - d (d + 1) / 2, the rigid motion dropped; a
    walk fitted in its plane has 2 M - 3 (:attr:`rangeslam.mdu.SlamResult.trajectory_dof`).
    Returns (NEES, its dof)."""
    m, d = truth.shape
    full = m * d - d * (d + 1) // 2
    if dof is not None and not 0 < dof <= full:
        raise InvalidInputError(f"dof must be in [1, {full}] for {m} points in {d}-D; got {dof}")
    dof = full if dof is None else int(dof)
    if dof <= 0:
        raise InvalidInputError(f"{m} points in {d}-D leave nothing beyond a rigid motion")
    if cov is None:
        return float("nan"), dof
    rot = np.kron(np.eye(m), alignment.rotation)
    w, v = np.linalg.eigh(rot @ cov @ rot.T)
    w, v = w[-dof:], v[:, -dof:]
    proj = v.T @ (alignment.aligned - truth).ravel()
    return float(np.sum(proj**2 / w)), dof


def mean_nees(nees, dofs, level: float = 0.95) -> tuple[float, float, float]:
    """Mean NEES per degree of freedom over trials (those with a finite NEES), and the two-sided
    ``level`` chi-square band of that mean for a consistent estimator: (mean, low, high); NaNs
    when no trial has one."""
    from scipy.stats import chi2

    nees, dofs = np.asarray(nees, dtype=float), np.asarray(dofs, dtype=float)
    good = np.isfinite(nees)
    if not good.any():
        return float("nan"), float("nan"), float("nan")
    total = float(dofs[good].sum())
    lo, hi = chi2.ppf([(1 - level) / 2, (1 + level) / 2], total) / total
    return float(nees[good].sum() / total), float(lo), float(hi)


def planar_source_error(
    alignment: Alignment, sources: np.ndarray, landmarks: np.ndarray, height: float
) -> float:
    """RMS error (metres) of ``sources`` (K, 3) moved by ``alignment`` against ``landmarks``
    (K, 3), each taken up to its mirror image in the plane z = ``height`` of a planar walk."""
    got = alignment.apply(sources)
    mirrored = got.copy()
    mirrored[:, 2] = 2 * height - got[:, 2]
    d = np.minimum(
        np.linalg.norm(got - landmarks, axis=1), np.linalg.norm(mirrored - landmarks, axis=1)
    )
    return float(np.sqrt(np.mean(d**2)))


@dataclass(frozen=True)
class PositionErrors:
    """APE of one trajectory: position errors (n,) after rigid alignment, beacon errors (B,),
    metres; the aligned positions (n, d) and beacons (B, d). NaN where an estimate is missing."""

    errors: np.ndarray
    beacon_errors: np.ndarray
    aligned: np.ndarray
    aligned_beacons: np.ndarray


def ape(
    positions: np.ndarray, truth: np.ndarray, beacons: np.ndarray, true_beacons: np.ndarray
) -> PositionErrors:
    """Absolute position error as evo's APE: rigidly align ``positions`` (n, d) onto ``truth``
    (n, d) (no scale) and carry ``beacons`` (B, d) along. Rows that are not finite (a method that
    stopped) are left out of the alignment and count as missing (NaN) in the errors."""
    n, d = positions.shape
    ok = np.all(np.isfinite(positions), axis=1)
    fit = align(positions[ok], truth[ok])
    aligned = np.full((n, d), np.nan)
    aligned[ok] = fit.aligned
    errors = np.full(n, np.nan)
    errors[ok] = fit.errors
    moved = fit.apply(np.nan_to_num(beacons))
    moved[~np.all(np.isfinite(beacons), axis=1)] = np.nan
    beacon_errors = np.linalg.norm(moved - true_beacons, axis=1)
    return PositionErrors(errors, beacon_errors, aligned, moved)


@dataclass(frozen=True)
class ApeStatistics:
    """Mean, median, max and RMS (metres) of the finite position errors, as evo's APE reports
    them, and how many errors were missing (NaN: poses a method did not estimate)."""

    mean: float
    median: float
    max: float
    rmse: float
    missing: int


def ape_statistics(errors: np.ndarray) -> ApeStatistics:
    """The :class:`ApeStatistics` of ``errors`` (n,), metres, NaN where a pose is missing."""
    errors = np.asarray(errors, dtype=float)
    e = errors[np.isfinite(errors)]
    return ApeStatistics(
        mean=float(e.mean()),
        median=float(np.median(e)),
        max=float(e.max()),
        rmse=float(np.sqrt(np.mean(e**2))),
        missing=int(np.sum(~np.isfinite(errors))),
    )


#: A cell's bound counts as attained when its yardstick's RMS (the oracle's, see
#: :func:`rms_against_bound`) is within this relative distance of the RMS bound. Below it the
#: bound, a linearisation at the truth, is not a bound for this estimator (hard step bounds
#: active, few steps, an information that is nearly singular: the estimator is biased there);
#: above it the problem is in its threshold (ambiguity) region. Either way the bound is not
#: reported, the oracle alone is.
ATTAINED_RTOL = 0.10


@dataclass(frozen=True)
class BoundComparison:
    """RMS error over trials against the oracle's RMS error and the RMS of the per-trial
    Cramer-Rao bounds (the bound is on the mean squared error, so RMS, not a median).

    Attributes:
        rms_error: sqrt(mean(error^2)) over the trials with a finite error, a finite oracle
            error and a finite bound (units of the errors, e.g. metres).
        rms_oracle: the same of the oracle's errors (the estimator's own cost minimised from the
            truth; its Monte-Carlo RMS when given); equal to ``rms_error`` without an oracle.
        rms_bound: sqrt(mean(bound^2)) over the same trials.
        search: rms_error over the RMS of the oracle's errors on the same data: about 1 where
            the search finds the oracle's minimum.
        efficiency: rms_oracle / rms_bound.
        trials: how many trials entered.
        unidentifiable: trials whose bound is inf (not identifiable): counted, not averaged in.
        regime: "attained" (|efficiency - 1| <= ATTAINED_RTOL), "not attained" (the bound is
            not a bound here, or not reached: the oracle is the only yardstick), "not
            identifiable" (every bound inf) or "no bound" (none finite, e.g. at zero noise).
    """

    rms_error: float
    rms_oracle: float
    rms_bound: float
    search: float
    efficiency: float
    trials: int
    unidentifiable: int
    regime: str

    @property
    def attained(self) -> bool:
        """Whether the bound is attained in this cell (so it may be quoted as a lower bound)."""
        return self.regime == "attained"

    @property
    def lower_bound(self) -> float:
        """The RMS bound where it is attained, else NaN: the only bound a table may report."""
        return self.rms_bound if self.attained else float("nan")

    @property
    def ratio(self) -> float:
        """rms_error / rms_bound where the bound is attained, else NaN."""
        return self.rms_error / self.rms_bound if self.attained else float("nan")


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2)))


def rms_against_bound(
    errors: ArrayLike,
    bounds: ArrayLike,
    oracle_errors: ArrayLike | None = None,
    oracle_rms: ArrayLike | None = None,
) -> BoundComparison:
    """Compare per-trial errors (T,) with the per-trial bounds (T,) on them and the per-trial
    errors (T,) of the oracle (the estimator's own cost minimised from the truth; same units).

    The bound is judged by the oracle: it is a lower bound the cell may quote only where the
    oracle's RMS error is within :data:`ATTAINED_RTOL` of the RMS bound; elsewhere the oracle is
    the yardstick and ``search`` (error / oracle) says how well the search did. Without
    ``oracle_errors`` the errors are their own oracle (for an estimator that minimises its cost
    from the truth). ``oracle_rms`` (T,), the oracle's Monte-Carlo RMS error per trial over fresh
    noise draws of the same scene, when given, is what the bound is checked against (a steadier
    figure than one draw per trial); ``search`` stays against ``oracle_errors``, on the same data.
    Trials with an infinite bound are counted as not identifiable and left out; NaN errors,
    oracle errors or bounds (a failed method, zero noise) are left out too."""
    e = as_float_array(errors, "errors").ravel()
    b = as_float_array(bounds, "bounds").ravel()
    o = e if oracle_errors is None else as_float_array(oracle_errors, "oracle_errors").ravel()
    mc = o if oracle_rms is None else as_float_array(oracle_rms, "oracle_rms").ravel()
    if not (e.shape == b.shape == o.shape == mc.shape):
        raise InvalidInputError(
            "errors, bounds, oracle_errors and oracle_rms must have the same length; got "
            f"{e.size}, {b.size}, {o.size} and {mc.size}"
        )
    unidentifiable = int(np.sum(np.isposinf(b)))
    use = np.isfinite(e) & np.isfinite(b) & np.isfinite(o) & np.isfinite(mc)
    if not use.any():
        regime = "not identifiable" if unidentifiable else "no bound"
        nan = float("nan")
        return BoundComparison(nan, nan, nan, nan, nan, 0, unidentifiable, regime)
    rms_e, rms_o, rms_b = _rms(e[use]), _rms(mc[use]), _rms(b[use])
    rms_same = _rms(o[use])
    search = rms_e / rms_same if rms_same > 0 else float("nan")
    efficiency = rms_o / rms_b if rms_b > 0 else float("nan")
    attained = bool(abs(efficiency - 1.0) <= ATTAINED_RTOL)
    regime = "attained" if attained else "not attained"
    return BoundComparison(
        rms_e, rms_o, rms_b, search, efficiency, int(use.sum()), unidentifiable, regime
    )
