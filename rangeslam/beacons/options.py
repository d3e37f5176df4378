"""The settings of range-only SLAM with odometry, parsed once at the front door."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from rangeslam._robust import ROBUST_KERNELS, robust_mode
from rangeslam._validation import as_float_array
from rangeslam.errors import InvalidInputError

__all__ = ["RANGE_CALIBRATIONS", "BeaconSlamOptions"]

#: Range models: measured range = (1 + s) * distance + b with s and b unknown ("affine"), s alone
#: ("scale"), b alone ("offset", a constant bias), or neither (None: ranges taken as distances).
RANGE_CALIBRATIONS = ("affine", "scale", "offset", None)


def positive_number(value, name: str) -> float:
    """A finite number > 0 (bools refused); InvalidInputError naming ``name`` otherwise."""
    ok = not isinstance(value, bool | np.bool_) and isinstance(value, int | float | np.number)
    ok = ok and not isinstance(value, complex | np.complexfloating)
    ok = ok and not (isinstance(value, int) and abs(value) > 2**1000)  # beyond any float
    if not (ok and np.isfinite(float(value)) and value > 0):
        raise InvalidInputError(f"{name} must be a positive number; got {value!r}")
    return float(value)


def one_of(value, name: str, choices: tuple, *, or_none: bool = False) -> None:
    """InvalidInputError naming ``name`` unless ``value`` is one of ``choices`` (or None with
    ``or_none``). Only strings and None are compared: an array, say, is refused as it is."""
    if value is None and or_none:
        return
    if not (value is None or isinstance(value, str)) or value not in choices:
        what = ("None or " if or_none else "") + f"one of {choices}"
        raise InvalidInputError(f"{name} must be {what}; got {value!r:.80}")


def min_window_length(min_spread: float) -> float:
    """The shortest window that can ever place a beacon, metres: 2 sqrt(2) ``min_spread``.

    A window's poses lie on a path of at most ``window_length`` metres, so within
    window_length / 2 of the path's midpoint: their covariance has trace <= window_length^2 / 4
    and its smaller eigenvalue <= window_length^2 / 8. A beacon is placed only when that
    eigenvalue's root (the RMS spread across the poses' line) reaches ``min_spread``.
    """
    return 2.0 * np.sqrt(2.0) * min_spread


def check_initialisation(initialisation: str, rng) -> None:
    """InvalidInputError unless ``initialisation`` is "edm" or "random" (the latter with a rng)."""
    if not isinstance(initialisation, str) or initialisation not in ("edm", "random"):
        raise InvalidInputError(f"initialisation must be 'edm' or 'random'; got {initialisation!r}")
    if initialisation == "random" and not isinstance(rng, np.random.Generator):
        raise InvalidInputError(
            f"rng must be a numpy Generator for initialisation='random'; got {rng!r}"
        )


@dataclass(frozen=True, eq=False)  # odometry_sigma is an array
class BeaconSlamOptions:
    """Settings of :func:`~rangeslam.beacons.beacon_slam` and its incremental form, validated on
    construction (InvalidInputError names the setting). Also the keywords those functions take.

    Attributes:
        range_calibration: the range model (:data:`RANGE_CALIBRATIONS`): "affine" (default),
            "scale", "offset" or None.
        per_beacon: one calibration per beacon instead of one shared by all.
        range_sigma: standard deviation of a range [m]; None (default): the ranges' own noise
            (:func:`~rangeslam.beacons.defaults.range_noise`).
        odometry_sigma: (3,) per-step standard deviations along and across the track [m] and of
            the heading [rad]; None (default): from the median step
            (:func:`~rangeslam.beacons.defaults.odometry_noise`).
        robust: kernel on the range factors: "huber" (default; also True), "cauchy", "tukey",
            or None / False (:data:`rangeslam.solvers.robust_kernels.ROBUST_VALUES`).
        calibration_sigma: zero-mean prior standard deviations of the scale error s and the
            offset b [m] (weak: they only keep the graph determinate).
        window_length: metres of travel per EDM window; None (default): a few median ranges
            (:data:`~rangeslam.beacons.defaults.WINDOW_RANGES`).
        keyframes: about how many ranges per window enter its EDM, shared among the beacons
            heard (each gets at least ``min_ranges``); the SDP has one point per keyframe pose
            plus one per beacon.
        min_ranges, min_spread: a beacon is placed in a window only when heard at least
            ``min_ranges`` times from poses spread ``min_spread`` metres across their line
            (None, the default: two range sigmas,
            :data:`~rangeslam.beacons.defaults.MIN_SPREAD_SIGMAS`).

    Settings left at None are derived from the data by
    :func:`~rangeslam.beacons.defaults.resolve_options` (never from one data set's scale).
        pose_weight: weight of the dead-reckoned pose-pose distances in a window's EDM fit
            (ranges weigh 1).
    """

    range_calibration: str | None = "affine"
    per_beacon: bool = False
    range_sigma: float | None = None
    odometry_sigma: np.ndarray | None = None
    robust: str | None = "huber"
    calibration_sigma: tuple[float, float] = (0.2, 10.0)
    window_length: float | None = None
    keyframes: int = 24
    min_ranges: int = 6
    min_spread: float | None = None
    pose_weight: float = 10.0

    def __post_init__(self) -> None:
        """Validate every setting and store it in its canonical type."""
        one_of(self.range_calibration, "range_calibration", RANGE_CALIBRATIONS)
        robust = robust_mode(self.robust, ROBUST_KERNELS, default_kernel="huber")
        object.__setattr__(self, "robust", robust)
        osig = None
        if self.odometry_sigma is not None:
            osig = as_float_array(self.odometry_sigma, "odometry_sigma")
            if osig.shape != (3,) or not np.all(np.isfinite(osig)) or np.any(osig <= 0):
                raise InvalidInputError(
                    "odometry_sigma must be three positive numbers (along [m], across [m], "
                    f"heading [rad] per step) or None (from the data); got {self.odometry_sigma!r}"
                )
        csig = as_float_array(self.calibration_sigma, "calibration_sigma")
        if csig.shape != (2,) or not np.all(np.isfinite(csig)) or np.any(csig <= 0):
            raise InvalidInputError(
                "calibration_sigma must be two positive numbers (prior sd of the scale error s "
                f"and of the offset b [m]); got {self.calibration_sigma!r}"
            )
        for name in ("range_sigma", "window_length", "min_spread", "pose_weight"):
            value = getattr(self, name)
            if value is not None or name == "pose_weight":
                object.__setattr__(self, name, positive_number(value, name))
        for name in ("keyframes", "min_ranges"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, int | np.integer) and value >= 3):
                raise InvalidInputError(f"{name} must be an integer >= 3; got {value!r}")
            object.__setattr__(self, name, int(value))
        shortest = min_window_length(1.0 if self.min_spread is None else self.min_spread)
        if self.window_length is not None and self.min_spread is None:
            shortest = 0.0  # checked once min_spread is derived from the data
        if self.window_length is not None and self.window_length < shortest:
            raise InvalidInputError(
                f"window_length must be >= {shortest:.4g} m (2 sqrt(2) min_spread: a shorter "
                f"window's poses can never spread min_spread = {self.min_spread:g} m across their "
                f"line, so no window would place a beacon); got {self.window_length:g}"
            )
        if not isinstance(self.per_beacon, bool | np.bool_):
            raise InvalidInputError(f"per_beacon must be True or False; got {self.per_beacon!r}")
        object.__setattr__(self, "per_beacon", bool(self.per_beacon))
        object.__setattr__(self, "odometry_sigma", osig)
        object.__setattr__(self, "calibration_sigma", (float(csig[0]), float(csig[1])))

    @classmethod
    def from_settings(cls, settings: dict) -> BeaconSlamOptions:
        """The options from keyword ``settings`` (defaults for the rest); unknown names refused."""
        known = sorted(f.name for f in fields(cls))
        unknown = sorted(set(settings) - set(known))
        if unknown:
            raise InvalidInputError(f"unknown setting(s) {unknown}; known: {known}")
        return cls(**settings)
