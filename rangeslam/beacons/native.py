"""Range factors that are GTSAM's own C++, with the range calibration handled around them.

The joint model of :mod:`rangeslam.beacons.graph` fits, per calibration group g,

    measured range r = (1 + s_g) |t - beta| + b_g,

with Python ``CustomFactor`` s, which GTSAM calls under the GIL (many times slower when iSAM2
linearises from its worker threads). Here the offset is a native variable and the scale is held
fixed inside the factors:

    r / (1 + s_g) = |t - beta| + c_g,   sigma / (1 + s_g),   b_g = (1 + s_g) c_g,

a ``RangeFactorWithTransformBias2D`` (c_g a scalar variable; ``RangeFactor2D`` without an
offset). At a given s_g its whitened residual is exactly the joint model's, (1 + s_g) d + b_g - r
over sigma, so the robust kernel sees the same numbers; the weak prior on b_g becomes one on
c_g with sigma_b / (1 + s_g). The scale is then a profile: f(s) = min over the rest of the joint
cost. Its gradient at that minimum (envelope theorem) is

    df/ds_g = sum over the ranges of g of psi(u) (d + c_g) / sigma + s_g / sigma_s^2
              + (1 + s_g) c_g^2 / sigma_b^2,

with u the whitened residual and psi the kernel's influence function. The incremental run
takes secant steps on it (:class:`ScaleSecant`) as the data come in, swapping the range factors
when a step matters, and ends with the joint model itself (a few Levenberg-Marquardt
iterations): a map built at a scale a little off sits in a shallow valley of the profile that
the secant leaves only slowly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rangeslam.beacons.graph import key_c, key_l, key_x
from rangeslam.beacons.options import BeaconSlamOptions
from rangeslam.solvers.robust_kernels import ROBUST_KERNEL_CONSTANTS, robust_noise_model

__all__ = ["NativeRanges", "ScaleSecant", "influence", "scale_step"]

# A scale step is applied (the range factors rebuilt, which re-eliminates the whole graph) only
# when it moves a median range by more than this share of range_sigma.
SCALE_STEP_SIGMAS = 0.05
# One secant step changes a scale by at most this much (the first steps use the partial
# curvature, which overstates the profile's, so they are short; later ones could overshoot on a
# secant taken from little data).
MAX_SCALE_STEP = 0.05


def influence(u: np.ndarray, robust: str | None) -> np.ndarray:
    """psi(u) = rho'(u) of the kernel ``robust`` on whitened residuals u (u itself for None)."""
    if robust is None:
        return u
    k = ROBUST_KERNEL_CONSTANTS[robust]
    if robust == "huber":
        return np.clip(u, -k, k)
    if robust == "cauchy":
        return u / (1.0 + (u / k) ** 2)
    return np.where(np.abs(u) <= k, u * (1.0 - (u / k) ** 2) ** 2, 0.0)  # tukey


def weight(u: np.ndarray, robust: str | None) -> np.ndarray:
    """psi(u) / u, the kernel's weight (1 for None)."""
    safe = np.where(np.abs(u) > 1e-12, u, 1e-12)
    return influence(safe, robust) / safe


@dataclass
class NativeRanges:
    """The native range factors of one run: the model, the current scale error s per group and
    the rows of the ranges that have factors.

    Attributes:
        cfg: the run's options (range_calibration, range_sigma, robust, calibration_sigma).
        n_groups: calibration groups (1, or one per beacon with ``per_beacon``).
        scale_error: (G,) current s per group (0 until stepped).
    """

    cfg: BeaconSlamOptions
    n_groups: int
    scale_error: np.ndarray = field(default=None)

    def __post_init__(self) -> None:
        if self.scale_error is None:
            self.scale_error = np.zeros(self.n_groups)
        self.noise_models: dict[int, tuple] = {}

    @property
    def has_offset(self) -> bool:
        """Whether an offset variable c_g is estimated."""
        return self.cfg.range_calibration in ("offset", "affine")

    @property
    def has_scale(self) -> bool:
        """Whether a scale is estimated (by :class:`ScaleSecant`)."""
        return self.cfg.range_calibration in ("scale", "affine")

    def noise(self, gtsam, group: int):
        """The robust noise model sigma / (1 + s_g) of ``group``'s ranges (one object per group
        and scale, shared by its factors)."""
        k = 1.0 + self.scale_error[group]
        if self.noise_models.get(group, (None,))[0] != k:
            base = gtsam.noiseModel.Isotropic.Sigma(1, self.cfg.range_sigma / k)
            self.noise_models[group] = (k, robust_noise_model(gtsam, base, self.cfg.robust))
        return self.noise_models[group][1]

    def factor(self, gtsam, pose: int, beacon: int, r: float, group: int):
        """The native factor of range ``r`` [m] from pose ``pose`` to ``beacon`` (``group``)."""
        k = 1.0 + self.scale_error[group]
        noise = self.noise(gtsam, group)
        if self.has_offset:
            return gtsam.RangeFactorWithTransformBias2D(
                key_x(pose), key_l(beacon), key_c(group), float(r) / k, noise, gtsam.Pose2()
            )
        return gtsam.RangeFactor2D(key_x(pose), key_l(beacon), float(r) / k, noise)

    def offset_prior(self, gtsam, group: int):
        """The weak zero-mean prior on b_g as one on c_g = b_g / (1 + s_g)."""
        k = 1.0 + self.scale_error[group]
        sigma = self.cfg.calibration_sigma[1] / k
        return gtsam.PriorFactorDouble(
            key_c(group), 0.0, gtsam.noiseModel.Isotropic.Sigma(1, sigma)
        )

    def offsets(self, values, groups: np.ndarray) -> np.ndarray:
        """(len(groups),) c_g of ``groups`` in ``values`` (0 without an offset, or not yet in)."""
        if not self.has_offset:
            return np.zeros(len(groups))
        out = np.zeros(len(groups))
        for i, g in enumerate(groups):
            if values.exists(key_c(int(g))):
                out[i] = values.atDouble(key_c(int(g)))
        return out

    def scale_gradient(self, distances, ranges, groups, offsets_c):
        """Envelope gradient df/ds_g (G,) and the partial curvature d2f/ds_g^2 (G,) (Gauss-Newton
        with the kernel's IRLS weights; it overstates the profile's) from the current distances (R,) [m], their ranges (R,), groups
        (R,) and c of each range's group (R,)."""
        cfg, s = self.cfg, self.scale_error
        sigma_s, sigma_b = cfg.calibration_sigma
        k = 1.0 + s[groups]
        lever = distances + offsets_c
        u = (k * lever - ranges) / cfg.range_sigma
        grad = np.bincount(
            groups, influence(u, cfg.robust) * lever / cfg.range_sigma, self.n_groups
        )
        curv = np.bincount(
            groups, weight(u, cfg.robust) * lever**2 / cfg.range_sigma**2, self.n_groups
        )
        c = np.zeros(self.n_groups)
        c[groups] = offsets_c
        grad += s / sigma_s**2 + (1.0 + s) * c**2 / sigma_b**2
        curv += 1.0 / sigma_s**2 + c**2 / sigma_b**2
        return grad, curv


@dataclass
class ScaleSecant:
    """A secant on the profile gradient of the scale, per group (the groups taken apart).

    The profile's curvature is the partial curvature (the scale's own, others held) less what the
    rest of the graph takes up, which :meth:`step` learns as a ratio from two gradients on the
    same data (``same_data``); on new data it divides by the partial curvature times the last
    ratio (1 at first: a short, safe step). Steps are capped at :data:`MAX_SCALE_STEP`.
    """

    n_groups: int
    last_s: np.ndarray | None = None
    last_grad: np.ndarray | None = None
    ratio: np.ndarray | None = None

    def step(self, s: np.ndarray, grad: np.ndarray, curv: np.ndarray, same_data: bool):
        """The next s (G,) from the current s (G,), gradient and partial curvature (G,);
        ``same_data``: the last call saw the same ranges (its gradient is comparable)."""
        ratio = np.ones(self.n_groups) if self.ratio is None else self.ratio
        h = curv * ratio
        if same_data and self.last_s is not None:
            ds, dg = s - self.last_s, grad - self.last_grad
            with np.errstate(divide="ignore", invalid="ignore"):
                secant = dg / ds
            use = (np.abs(ds) > 1e-12) & np.isfinite(secant) & (secant > 0)
            h[use] = secant[use]
            ratio = ratio.copy()
            ratio[use] = np.minimum(secant[use] / curv[use], 1.0)
            self.ratio = ratio
        self.last_s, self.last_grad = s.copy(), grad.copy()
        return s + np.clip(-grad / h, -MAX_SCALE_STEP, MAX_SCALE_STEP)


def significant(step: np.ndarray, median_range: float, sigmas: float, cfg) -> bool:
    """Whether a scale step moves a median range [m] by more than ``sigmas`` range sigmas."""
    return bool(np.max(np.abs(step)) * median_range > sigmas * cfg.range_sigma)


def scale_step(estimate, data, rows, groups, native, secant, *, same_data: bool):
    """The next range scale errors (G,) from an iSAM2 ``estimate`` over the ranges ``rows`` (R,)
    of ``data`` (their groups ``groups`` (R,)), or None when the step does not matter
    (:func:`significant`)."""
    poses = np.array([estimate.atPose2(key_x(int(i))).translation() for i in data.range_pose[rows]])
    beacons = np.array([estimate.atPoint2(key_l(int(j))) for j in data.range_beacon[rows]])
    distances = np.linalg.norm(poses - beacons, axis=1)
    offsets_c = native.offsets(estimate, groups)
    grad, curv = native.scale_gradient(distances, data.ranges[rows], groups, offsets_c)
    s = native.scale_error
    new = secant.step(s, grad, curv, same_data)
    median = float(np.median(data.ranges[rows]))
    if not significant(new - s, median, SCALE_STEP_SIGMAS, native.cfg):
        return None
    return new
