"""Fuzz every public entry point of rangeslam.

Each entry point (every function and user-facing classmethod of ``rangeslam.__all__``, the EKF
baseline the issue names, and the ``rangeslam`` command through ``rangeslam.app.cli.main``) is
called on a small valid problem built with the package's own simulators, either as it is, with
its geometry made degenerate (a duplicated point, points coplanar or collinear within 1e-4 m), or
with one argument replaced by a value of one of the hostile families: magnitudes scaled by
1e-200..1e200, integers too large for a float, complex numbers, numeric strings, strings, arrays
where a scalar belongs (or a scalar where an array belongs), NaN/inf, empty arrays, wrong shapes,
None. hypothesis draws the family, the problem's seed, the argument and the value (seeded with
``--seed``; generation only, no shrinking, no example database).

Every call ends as one of:

- ok: it returned;
- refused: it raised a ``rangeslam.errors.RangeSlamError`` (the command: exit code 2 with a
  one-line message and no traceback);
- foreign: any other exception (type, message, argument and the last package frame recorded);
- hang: it ran past ``--timeout`` seconds (a SIGALRM per call; code inside a C extension is only
  interrupted when it returns to Python);
- converged-wrong: the result says CONVERGED but is farther from the truth the problem was built
  from than max(3 x the Cramer-Rao bound, 5 cm). The bound is the package's own
  (``multilateration_crlb``, ``mdu_crlb``; for a point with an unknown offset the same Fisher
  information with the offset a nuisance); without one, 5 cm. Only checked when the replaced
  argument is not part of the data the truth defines (a changed ``ranges`` has another truth).

Usage::

    python benchmarks/fuzz_entry_points.py --seed 1 --examples 200
    python benchmarks/fuzz_entry_points.py --seed 1 --examples 20 --heavy-examples 3 --out fuzz-out
    python benchmarks/fuzz_entry_points.py --seed 1 --only calibrate

Exit code 1 when any call was foreign, a hang or converged-wrong; 0 otherwise.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import functools
import io
import json
import re
import signal
import sys
import tempfile
import time
import traceback
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import seed as hypothesis_seed
from hypothesis import strategies as st

import rangeslam as rs
from rangeslam.errors import RangeSlamError
from rangeslam.geometry.edm import range_matrix
from rangeslam.status import Status

OUTCOMES = ("ok", "refused", "foreign", "hang", "converged-wrong")
FAILURES = ("foreign", "hang", "converged-wrong")
#: A converged answer may be this many Cramer-Rao bounds off, and at least FLOOR metres.
CRLB_FACTOR = 3.0
FLOOR = 0.05
#: Range noise of the valid problems, metres.
NOISE = 1e-3
#: The calibration scenes: Fig. 3 with this many microphones and sources (the loudspeaker and
#: its nearest first-order images).
N_MICS, N_SOURCES = 6, 6
#: The walks from RIRs: keyframes, and RIRs a step (one RIR a 0.3 m step tracks no echo; 8 a
#: step, as in tests/test_echo_tracking.py, converges in about a minute a walk).
WALK_STEPS, WALK_FRAMES = 8, 8
C = 343.0
FS = 16000
GEOMETRY_FAMILIES = ("valid", "duplicate", "near_flat")
ARGUMENT_FAMILIES = (
    "scaled", "bigint", "complex", "numeric_string", "string", "array_for_scalar", "nan_inf",
    "empty", "wrong_shape", "none",
)  # fmt: skip
FAMILIES = GEOMETRY_FAMILIES + ARGUMENT_FAMILIES

Check = Callable[[Any], "str | None"]


@dataclass
class Problem:
    """Keyword arguments of one call, the check of a converged answer against the truth, and
    the arguments that define that truth (replacing one of them leaves nothing to check)."""

    kwargs: dict[str, Any]
    check: Check | None = None
    data_args: frozenset[str] = frozenset()


@dataclass(frozen=True)
class EntryPoint:
    name: str
    call: Callable[..., Any]
    build: Callable[[np.random.Generator, str], Problem]
    heavy: bool = False


@dataclass
class Record:
    entry: str
    family: str
    argument: str
    outcome: str
    seconds: float
    problem_seed: int
    exc_type: str = ""
    message: str = ""
    frame: str = ""
    value: str = ""
    converged: bool = False


class Hang(BaseException):
    """Raised by the per-call alarm (a BaseException so that no ``except Exception`` eats it)."""


class CliRefused(Exception):
    """The command exited with code 2 and a one-line message: a refusal."""


# ---- geometry and values ---------------------------------------------------------------------


def warp(points: np.ndarray, geometry: str, gen: np.random.Generator) -> np.ndarray:
    """The points as drawn ("valid"), with row 1 a copy of row 0 ("duplicate"), or with their
    last coordinate within 1e-4 m of one value (coplanar in 3-D, collinear in 2-D)."""
    out = np.array(points, dtype=float)
    if geometry == "duplicate":
        out[1] = out[0]
    elif geometry == "near_flat":
        out[:, -1] = out[0, -1] + gen.uniform(-5e-5, 5e-5, len(out))
    return out


def numeric(value: Any) -> np.ndarray | None:
    """``value`` as a float array, or None when it is not numeric (strings, None, bools,
    dicts, objects)."""
    if value is None or isinstance(value, bool | np.bool_ | str | bytes | dict):
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None


def _wrong_shape(arr: np.ndarray, data) -> np.ndarray:
    options = [arr[None], arr.ravel()[:-1] if arr.size > 1 else np.zeros((2, 2))]
    if arr.ndim >= 2:
        options += [arr.T, arr[..., :-1], np.concatenate([arr, arr[..., :1]], axis=-1)]
    if arr.ndim == 1 and arr.size > 1:
        options += [arr[:-1], arr.reshape(1, -1), np.append(arr, arr[0])]
    return data.draw(st.sampled_from(options), label="reshaped")


def _at_one_element(arr: np.ndarray, new: Any, data, dtype=float) -> Any:
    if arr.size == 0:
        return new
    out = arr.astype(dtype)
    out.flat[data.draw(st.integers(0, arr.size - 1), label="index")] = new
    return out


def mutate(value: Any, family: str, data) -> Any:
    """``value`` replaced by one of the family's values (drawn with ``data``)."""
    arr = numeric(value)
    scalar = arr is not None and arr.ndim == 0
    if family == "scaled":
        sign = data.draw(st.sampled_from([-1, 1]), label="sign")
        factor = 10.0 ** (sign * data.draw(st.integers(1, 200), label="exponent"))
        return factor if arr is None else (float(arr) * factor if scalar else arr * factor)
    if family == "bigint":
        big = data.draw(st.sampled_from([10**400, -(10**400), 2**1024]), label="big")
        return big if arr is None or scalar else _at_one_element(arr, big, data, object)
    if family == "complex":
        imag = data.draw(st.sampled_from([0.0, 1e-3, 1.0]), label="imag")
        if arr is None:
            return complex(1.0, imag)
        return complex(float(arr), imag) if scalar else arr + 1j * imag
    if family == "numeric_string":
        if arr is None:
            return data.draw(st.sampled_from(["1", "0.5", "1e3", "nan", " 3"]), label="text")
        return repr(float(arr)) if scalar else arr.astype(str)
    if family == "string":
        return data.draw(st.text(max_size=6), label="text")
    if family == "array_for_scalar":
        if arr is None or scalar:
            return np.full(2, float(arr) if scalar else 1.0)
        return np.float64(arr.flat[0]) if arr.size else np.float64(1.0)
    if family == "nan_inf":
        bad = data.draw(st.sampled_from([np.nan, np.inf, -np.inf]), label="bad")
        return bad if arr is None or scalar else _at_one_element(arr, bad, data)
    if family == "empty":
        return np.zeros(0) if arr is None or scalar else np.zeros((0, *arr.shape[1:]))
    if family == "wrong_shape":
        return np.zeros((2, 3)) if arr is None or scalar else _wrong_shape(arr, data)
    return None  # "none"


def short(value: Any, limit: int = 120) -> str:
    """A one-line description of a drawn value (integers of 40 digits or more by their size)."""
    if isinstance(value, np.ndarray) and value.dtype == object:
        big = [i for i, v in enumerate(value.flat) if isinstance(v, int) and abs(v) > 2**1000]
        if big:
            digits = len(str(abs(value.flat[big[0]])))
            return f"array{value.shape} of floats, a {digits}-digit int at flat index {big[0]}"
    text = repr(value) if not isinstance(value, np.ndarray) else f"array{value.shape} {value!r}"
    text = re.sub(
        r"-?\d{40,}", lambda m: f"<{len(m.group().lstrip('-'))}-digit int>", " ".join(text.split())
    )
    return text if len(text) <= limit else text[: limit - 3] + "..."


# ---- checks of converged answers ---------------------------------------------------------------


def safe_bound(compute: Callable[[], float]) -> float | None:
    """A Cramer-Rao bound, or None when the package refuses or it is not finite."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            value = float(compute())
    except Exception:  # a degenerate geometry has no bound: use the floor
        return None
    return value if np.isfinite(value) else None


def judged(error: float, bound: float | None) -> str | None:
    tol = max(CRLB_FACTOR * (bound or 0.0), FLOOR)
    if np.isfinite(error) and error <= tol:
        return None
    shown = "none" if bound is None else f"{bound:.3g} m"
    return f"error {error:.3g} m > {tol:.3g} m (bound {shown})"


def point_check(get: Callable[[Any], Any], truth: np.ndarray, bound: Callable[[], float]) -> Check:
    """Converged answer ``get(result)``, one point, against ``truth``."""

    def check(result):
        est = np.asarray(get(result), dtype=float).reshape(truth.shape)
        return judged(float(np.linalg.norm(est - truth)), safe_bound(bound))

    return check


def aligned_check(
    get: Callable[[Any], Any], truth: np.ndarray, bound: Callable[[], float]
) -> Check:
    """Converged points ``get(result)`` against ``truth`` up to a rigid motion and reflection
    (RMS over the points)."""

    def check(result):
        est = np.asarray(get(result), dtype=float)
        return judged(rs.align(est, truth, reflection=True).rmse, safe_bound(bound))

    return check


def trace_bound(cov: np.ndarray) -> float:
    return float(np.sqrt(np.trace(cov)))


def offset_bound(anchors: np.ndarray, point: np.ndarray, sigma: float) -> float:
    """RMS Cramer-Rao bound on a point from ranges with one unknown offset (a nuisance):
    rows [u_i, 1] of the Jacobian, u_i the unit vector from anchor i to the point."""
    diff = point - anchors
    jac = np.hstack([diff / np.linalg.norm(diff, axis=1, keepdims=True), np.ones((len(diff), 1))])
    cov = np.linalg.inv(jac.T @ jac) * sigma**2
    return trace_bound(cov[:-1, :-1])


def is_converged(result: Any) -> bool:
    if getattr(result, "status", None) is Status.CONVERGED:
        return True
    return getattr(result, "converged", False) is True


# ---- valid small problems ----------------------------------------------------------------------


def noisy(ranges: np.ndarray, gen: np.random.Generator) -> np.ndarray:
    return rs_sim().add_range_noise(ranges, NOISE, rng=gen)


@functools.cache
def rs_sim():
    import rangeslam.sim as sim

    return sim


def build_multilaterate(gen, geometry, *, offset: float = 0.0) -> Problem:
    d = int(gen.choice([2, 3]))
    anchors = warp(gen.uniform(0.0, 4.0, (7, d)), geometry, gen)
    x = gen.uniform(1.0, 3.0, d)
    ranges = noisy(np.linalg.norm(anchors - x, axis=1), gen) + offset
    kwargs = dict(anchors=anchors, ranges=ranges, noise_std=NOISE, robust=False, rng=0)
    if offset:
        bound = functools.partial(offset_bound, anchors, x, NOISE)
    else:
        bound = lambda: trace_bound(rs.multilateration_crlb(anchors, x, NOISE))  # noqa: E731
    check = point_check(lambda r: r.position, x, bound)
    return Problem(kwargs, check, frozenset({"anchors", "ranges"}))


def fig3(gen, geometry):
    """A Fig. 3 scene (N_MICS microphones, N_SOURCES sources), its
    microphones warped."""
    from rangeslam.app.experiments import fig3_scene

    scene = fig3_scene(gen, n_mics=N_MICS, n_images=N_SOURCES - 1)
    mics = warp(scene.mics, geometry, gen)
    return mics, scene.sources


def build_calibrate(gen, geometry) -> Problem:
    mics, sources = fig3(gen, geometry)
    kwargs = dict(ranges=noisy(range_matrix(mics, sources), gen), dim=3, noise_std=NOISE, rng=0)
    bound = lambda: rs.mdu_crlb(mics, sources, NOISE).receiver_rmse  # noqa: E731
    return Problem(kwargs, aligned_check(lambda r: r.receivers, mics, bound), frozenset({"ranges"}))


def build_calibrate_unknown_emission(gen, geometry) -> Problem:
    mics, sources = fig3(gen, geometry)
    ranges = noisy(range_matrix(mics, sources), gen) + 0.3
    kwargs = dict(ranges=ranges, groups=None, dim=3, noise_std=NOISE, max_attempts=3, rng=0)
    bound = lambda: rs.mdu_crlb(mics, sources, NOISE).receiver_rmse  # noqa: E731
    check = aligned_check(lambda r: r.receivers, mics, bound)
    return Problem(kwargs, check, frozenset({"ranges", "groups"}))


def walk(gen, geometry, n: int = 6, d: int = 3) -> np.ndarray:
    """A walk of ``n`` points, steps of 0.3-0.6 m in random directions, warped."""
    steps = gen.standard_normal((n - 1, d))
    steps *= gen.uniform(0.3, 0.6, (n - 1, 1)) / np.linalg.norm(steps, axis=1, keepdims=True)
    traj = np.vstack([np.zeros(d), np.cumsum(steps, axis=0)]) + 1.5
    return warp(traj, geometry, gen)


def build_slam(gen, geometry) -> Problem:
    traj, land = walk(gen, geometry), gen.uniform(0.0, 4.0, (5, 3))
    steps = np.linalg.norm(np.diff(traj, axis=0), axis=1)
    bounds = (0.9 * steps, 1.1 * steps)
    kwargs = dict(ranges=noisy(range_matrix(traj, land), gen), step_bounds=bounds, dim=3,
                  noise_std=NOISE, max_attempts=3, rng=0)  # fmt: skip
    bound = lambda: rs.mdu_crlb(traj, land, NOISE, step_bounds=bounds).receiver_rmse  # noqa: E731
    check = aligned_check(lambda r: r.receivers, traj, bound)
    return Problem(kwargs, check, frozenset({"ranges", "step_bounds"}))


def build_ekf_slam(gen, geometry) -> Problem:
    problem = build_slam(gen, geometry)
    kwargs = {k: problem.kwargs[k] for k in ("ranges", "step_bounds", "dim", "noise_std", "rng")}
    return Problem(dict(kwargs, n_starts=2), problem.check, problem.data_args)


def shoebox_scene(gen, geometry, d: int = 3):
    """A 4 x 3 (x 2.5) m shoebox, 8 microphones 0.4 m from the walls, a source."""
    room = rs.Room.shoebox([4.0, 3.0, 2.5][:d])
    mics = warp(rs_sim().random_points_in_room(room, 8, margin=0.4, rng=gen), geometry, gen)
    source = rs_sim().random_points_in_room(room, 1, margin=0.4, rng=gen)[0]
    return room, mics, source


def build_reconstruct_room(gen, geometry, *, offset: float = 0.0) -> Problem:
    room, mics, source = shoebox_scene(gen, geometry, int(gen.choice([2, 3])))
    ranges = noisy(rs_sim().echo_ranges(room, mics, source), gen) + offset
    kwargs = dict(mics=mics, ranges=ranges, rng=0, max_hypotheses=100)
    if offset:
        kwargs["c"] = None
    bound = lambda: trace_bound(rs.multilateration_crlb(mics, source, NOISE))  # noqa: E731
    get = (lambda r: r.reconstruction.sources[0]) if offset else (lambda r: r.sources[0])
    return Problem(kwargs, point_check(get, source, bound), frozenset({"mics", "ranges"}))


@functools.cache
def rir_scene(index: int, geometry: str):
    """RIRs (8, 640) at 16 kHz of a 4 x 3 x 2.5 m shoebox, reflection order 1 (4 scenes a
    geometry, cached: pyroomacoustics is the slow part)."""
    gen = np.random.default_rng(index)
    _, mics, source = shoebox_scene(gen, geometry)
    rirs = rs_sim().shoebox_rirs((4.0, 3.0, 2.5), source, mics, fs=FS, max_order=1, duration=0.04)
    return rirs, mics, source


def rir_sigma() -> float:
    """Range noise of a pick on a sample grid: uniform over one sample."""
    return C / FS / np.sqrt(12.0)


def build_room_from_rirs(gen, geometry) -> Problem:
    rirs, mics, source = rir_scene(int(gen.integers(4)), geometry)
    kwargs = dict(rirs=rirs, fs=FS, mics=mics, c=C, rng=0, label_options={"max_hypotheses": 2000})
    bound = lambda: trace_bound(rs.multilateration_crlb(mics, source, rir_sigma()))  # noqa: E731
    check = point_check(lambda r: r.reconstruction.sources[0], source, bound)
    return Problem(kwargs, check, frozenset({"rirs", "fs", "mics", "c"}))


def build_run_rirs(gen, geometry) -> Problem:
    rirs, mics, source = rir_scene(int(gen.integers(4)), geometry)
    kwargs = dict(rirs=rirs, fs=FS, mics=mics, c=C, rng=0, label_options={"max_hypotheses": 2000})
    bound = lambda: trace_bound(rs.multilateration_crlb(mics, source, rir_sigma()))  # noqa: E731
    check = point_check(lambda r: r.source, source, bound)
    return Problem(kwargs, check, frozenset({"rirs", "fs", "mics", "c", "step_bounds"}))


@functools.cache
def walk_scene(index: int, geometry: str):
    """A walk as RIRs, as tests/test_echo_tracking.py builds it: WALK_STEPS keyframes of the
    Fig. 5 lemniscate (steps of 0.3 m) with WALK_FRAMES RIRs a step, a loudspeaker at random in
    the Fig. 5 room, order-3 RIRs at 16 kHz. Returns the RIRs, the keyframes, the walk at the
    keyframes and the landmarks (the loudspeaker and its 6 first-order images)."""
    from rangeslam.app.experiments import FIG5_ROOM_SIZE

    gen = np.random.default_rng(100 + index)
    k = WALK_FRAMES
    dense = rs_sim().lemniscate((WALK_STEPS - 1) * k + 1, step=0.3 / k, phase=gen.uniform(0, 6))
    dense = warp(dense, geometry, gen)
    room = rs.Room.shoebox(FIG5_ROOM_SIZE)
    source = rs_sim().random_points_in_room(room, 1, rng=gen)[0]
    rirs = rs_sim().shoebox_rirs(FIG5_ROOM_SIZE, source, dense, fs=FS, max_order=3)
    keys = np.arange(0, len(dense), k)
    landmarks = np.vstack([source, room.image_sources(source, 1).positions])
    return rirs, keys, dense[keys], landmarks


def build_walk_from_rirs(gen, geometry) -> Problem:
    rirs, keys, traj, landmarks = walk_scene(int(gen.integers(4)), geometry)
    steps = np.linalg.norm(np.diff(traj, axis=0), axis=1)
    bounds = (0.8 * steps, 1.2 * steps)
    kwargs = dict(rirs=rirs, fs=FS, step_bounds=bounds, keyframes=keys, c=C, dim=3, rng=0)
    bound = lambda: rs.mdu_crlb(traj, landmarks, rir_sigma(), step_bounds=bounds).receiver_rmse  # noqa: E731
    check = aligned_check(lambda r: r.trajectory, traj, bound)
    return Problem(kwargs, check, frozenset({"rirs", "fs", "step_bounds", "c", "keyframes"}))


def build_detect_echoes(gen, geometry) -> Problem:
    rirs, _, _ = rir_scene(int(gen.integers(4)), "valid")
    return Problem(dict(rir=rirs[int(gen.integers(6))], fs=FS, max_echoes=None, noise_window=None))


def build_detect_echoes_many(gen, geometry) -> Problem:
    rirs, _, _ = rir_scene(int(gen.integers(4)), "valid")
    return Problem(dict(rirs=rirs[:3], fs=FS, max_time=0.02))


@functools.cache
def detections(index: int, geometry: str, kind: str):
    rirs = (rir_scene if kind == "array" else walk_scene)(index, geometry)[0]
    return rs.detect_echoes_many(rirs, FS)


def build_label_echoes(gen, geometry) -> Problem:
    index = int(gen.integers(4))
    _, mics, _ = rir_scene(index, geometry)
    dets = detections(index, geometry, "array")
    return Problem(dict(detections=dets, mics=mics, c=C, max_hypotheses=2000, rng=0))


def build_track_echoes(gen, geometry) -> Problem:
    dets = detections(int(gen.integers(4)), geometry, "walk")
    return Problem(dict(detections=dets, max_step=0.1, c=C, max_gap=8, confirm=4))


@functools.cache
def scratch() -> Path:
    return Path(tempfile.mkdtemp(prefix="rangeslam-fuzz-"))


def build_load_rirs(gen, geometry) -> Problem:
    rirs, mics, _ = rir_scene(int(gen.integers(4)), geometry)
    path = scratch() / f"rirs-{int(gen.integers(1 << 30))}.npz"
    np.savez(path, rirs=rirs, fs=float(FS), mics=mics)
    return Problem(dict(path_or_paths=path, fs=None))


def points(gen, geometry, n: int = 6) -> np.ndarray:
    return warp(gen.uniform(0.0, 4.0, (n, int(gen.choice([2, 3])))), geometry, gen)


def build_edm(gen, geometry) -> Problem:
    return Problem(dict(points=points(gen, geometry)))


def build_edm_to_gram(gen, geometry) -> Problem:
    return Problem(dict(edm_matrix=rs.edm(points(gen, geometry))))


def build_gram_to_edm(gen, geometry) -> Problem:
    p = points(gen, geometry)
    return Problem(dict(gram=p @ p.T))


def build_is_edm(gen, geometry) -> Problem:
    p = points(gen, geometry)
    return Problem(dict(edm_matrix=rs.edm(p), dim=p.shape[1], rtol=1e-9))


def build_classical_mds(gen, geometry) -> Problem:
    p = points(gen, geometry)
    return Problem(dict(edm_matrix=rs.edm(p), dim=p.shape[1]))


def build_align(gen, geometry) -> Problem:
    p = points(gen, geometry)
    moved = p[:, ::-1] + gen.uniform(-1, 1, p.shape[1])
    return Problem(dict(estimate=moved, reference=p, reflection=True, scale=False))


def build_shoebox(gen, geometry) -> Problem:
    return Problem(dict(dims=gen.uniform(2.0, 6.0, int(gen.choice([2, 3])))))


def build_from_planes(gen, geometry) -> Problem:
    size = gen.uniform(2.0, 6.0, 3)
    normals = np.vstack([np.eye(3), -np.eye(3)])
    pts = np.vstack([size * np.eye(3), np.zeros((3, 3))])
    return Problem(dict(normals=normals, points=pts))


def build_from_vertices(gen, geometry) -> Problem:
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=float)
    return Problem(dict(vertices=warp(corners * gen.uniform(2.0, 6.0, 3), geometry, gen)))


def build_polygon(gen, geometry) -> Problem:
    angles = np.sort(gen.uniform(0, 2 * np.pi, 6))
    ring = np.column_stack([np.cos(angles), np.sin(angles)]) * 3.0
    return Problem(dict(vertices=warp(ring, geometry, gen)))


def build_mdu_crlb(gen, geometry) -> Problem:
    mics, sources = fig3(gen, geometry)
    return Problem(dict(receivers=mics, sources=sources, sigma=NOISE, mask=None, gauge="all"))


def build_multilateration_crlb(gen, geometry) -> Problem:
    anchors = points(gen, geometry, 6)
    point = gen.uniform(1.0, 3.0, anchors.shape[1])
    return Problem(dict(anchors=anchors, point=point, sigma=NOISE, mask=None))


def build_wall_crlb(gen, geometry) -> Problem:
    _, mics, source = shoebox_scene(gen, geometry)
    normals, offsets = np.array([[1.0, 0, 0], [0, 0, 1.0]]), np.array([4.0, 2.5])
    return Problem(dict(mics=mics, sources=source[None], normals=normals, offsets=offsets,
                        sigma=NOISE, points=None, mask=None))  # fmt: skip


@functools.cache
def beacon_run(index: int):
    """A short simulated beacon run: 150 steps of 0.12 m on a 5 m loop, four beacons, 1 cm
    range noise, a range every step, odometry of 1 mm and 0.5 mrad a step (so that the beacons
    are fixed to about 1 cm: the package has no bound for them, the 5 cm floor applies)."""
    from rangeslam.beacons.simulation import simulate_beacon_run

    gen = np.random.default_rng(200 + index)
    return simulate_beacon_run(gen, n_steps=150, radius=5.0, range_std=0.01,
                               odometry_std=(0.001, 0.0005), range_rate=1.0)  # fmt: skip


def odometry_kwargs(gen) -> dict[str, Any]:
    d = beacon_run(int(gen.integers(4))).data
    return dict(pose_time=d.pose_time, odometry=d.odometry, range_pose=d.range_pose,
                range_beacon=d.range_beacon, ranges=d.ranges)  # fmt: skip


def build_odometry_create(gen, geometry) -> Problem:
    return Problem(dict(odometry_kwargs(gen), n_beacons=4))


def build_odometry_ids(gen, geometry) -> Problem:
    kwargs = odometry_kwargs(gen)
    kwargs["range_ids"] = 10**12 + 7 * kwargs.pop("range_beacon")
    return Problem(kwargs)


def build_beacon_slam(gen, geometry, *, incremental: bool = False) -> Problem:
    run = beacon_run(int(gen.integers(4)))
    kwargs = dict(data=run.data, start_pose=tuple(run.poses[0]), initialisation="edm", rng=0,
                  window_length=150.0, robust="huber", range_calibration=None)  # fmt: skip
    if incremental:
        kwargs["update_every"] = 25
    else:
        kwargs["max_iterations"] = 30
    # No bound for the beacons in the package: the 5 cm floor. The simulated ranges have no
    # scale or offset, so the valid problem says so (range_calibration=None).
    check = aligned_check(lambda r: r.beacons, run.beacons, lambda: np.nan)
    return Problem(kwargs, check, frozenset({"data", "start_pose"}))


# ---- the command line ----------------------------------------------------------------------------


def argv_tokens(value: Any) -> list[str]:
    """A drawn value as command-line tokens (arrays and lists give one token per element)."""
    if isinstance(value, np.ndarray) and value.ndim > 0:
        return [str(v) for v in value.ravel()]
    if isinstance(value, list | tuple):
        return [str(v) for v in value]
    return [] if value is None else [str(value)]


def cli(command: list[str], **options: Any) -> int:
    """``rangeslam.app.cli.main`` on ``command`` plus ``--name value`` per option (an option
    whose value is None is left out); exit code 2 with a one-line message is a refusal."""
    from rangeslam.app.cli import main

    argv = list(command)
    for name, value in options.items():
        if name == "rirs":
            argv[1:1] = argv_tokens(value) or [""]
        elif value is not None:
            argv += [f"--{name.replace('_', '-')}", *argv_tokens(value)]
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
    text = err.getvalue()
    if "Traceback" in text:
        raise RuntimeError(f"traceback printed by rangeslam {' '.join(argv)}: {text[-300:]}")
    if code == 2:
        last = text.strip().splitlines()[-1] if text.strip() else ""
        if "error:" not in last:
            raise RuntimeError(f"exit 2 without a one-line error: {text[-300:]!r}")
        raise CliRefused(last)
    return code


def build_cli_run(gen, geometry) -> Problem:
    rirs, mics, source = rir_scene(int(gen.integers(4)), geometry)
    path = scratch() / f"run-{int(gen.integers(1 << 30))}.npz"
    np.savez(path, rirs=rirs, fs=float(FS), mics=mics, source=source)
    out = scratch() / "run-out"
    return Problem(dict(command=["run", "--mics-from-npz", "--out", str(out)], rirs=str(path),
                        fs=str(FS), c="343", dim="3", seed="0"))  # fmt: skip


def build_cli_simulate(gen, geometry) -> Problem:
    out = scratch() / "simulated.npz"
    return Problem(dict(command=["simulate", "room", "--out", str(out)], size=["4", "3", "2.5"],
                        mics="5", seed=str(int(gen.integers(100))), fs="8000", absorption="0.2",
                        order="1", noise="0.0"))  # fmt: skip


# ---- the entry points --------------------------------------------------------------------------


def ekf_slam(**kwargs):
    from rangeslam.baselines.ekf_slam import ekf_slam as run

    return run(**kwargs)


P = functools.partial
ENTRY_POINTS: tuple[EntryPoint, ...] = (
    EntryPoint("multilaterate", rs.multilaterate, build_multilaterate),
    EntryPoint(
        "multilaterate_with_offset",
        rs.multilaterate_with_offset,
        P(build_multilaterate, offset=0.4),
    ),
    EntryPoint("reconstruct_room", rs.reconstruct_room, build_reconstruct_room),
    EntryPoint(
        "reconstruct_room_unknown_emission",
        rs.reconstruct_room_unknown_emission,
        P(build_reconstruct_room, offset=0.3),
    ),
    EntryPoint("calibrate", rs.calibrate, build_calibrate, heavy=True),
    EntryPoint(
        "calibrate_unknown_emission",
        rs.calibrate_unknown_emission,
        build_calibrate_unknown_emission,
        heavy=True,
    ),
    EntryPoint("slam", rs.slam, build_slam, heavy=True),
    EntryPoint("baselines.ekf_slam", ekf_slam, build_ekf_slam, heavy=True),
    EntryPoint("mdu_crlb", rs.mdu_crlb, build_mdu_crlb),
    EntryPoint("multilateration_crlb", rs.multilateration_crlb, build_multilateration_crlb),
    EntryPoint("wall_crlb", rs.wall_crlb, build_wall_crlb),
    EntryPoint("edm", rs.edm, build_edm),
    EntryPoint("edm_to_gram", rs.edm_to_gram, build_edm_to_gram),
    EntryPoint("gram_to_edm", rs.gram_to_edm, build_gram_to_edm),
    EntryPoint("is_edm", rs.is_edm, build_is_edm),
    EntryPoint("classical_mds", rs.classical_mds, build_classical_mds),
    EntryPoint("align", rs.align, build_align),
    EntryPoint("Room.shoebox", rs.Room.shoebox, build_shoebox),
    EntryPoint("Room.from_planes", rs.Room.from_planes, build_from_planes),
    EntryPoint("Room.from_vertices", rs.Room.from_vertices, build_from_vertices),
    EntryPoint("Room.polygon", rs.Room.polygon, build_polygon),
    EntryPoint("detect_echoes", rs.detect_echoes, build_detect_echoes),
    EntryPoint("detect_echoes_many", rs.detect_echoes_many, build_detect_echoes_many),
    EntryPoint("label_echoes", rs.label_echoes, build_label_echoes),
    EntryPoint("track_echoes", rs.track_echoes, build_track_echoes),
    EntryPoint("load_rirs", rs.load_rirs, build_load_rirs),
    EntryPoint("room_from_rirs", rs.room_from_rirs, build_room_from_rirs, heavy=True),
    EntryPoint("run_rirs", rs.run_rirs, build_run_rirs, heavy=True),
    EntryPoint("walk_from_rirs", rs.walk_from_rirs, build_walk_from_rirs, heavy=True),
    EntryPoint("RangeOdometry.create", rs.RangeOdometry.create, build_odometry_create),
    EntryPoint(
        "RangeOdometry.from_beacon_ids", rs.RangeOdometry.from_beacon_ids, build_odometry_ids
    ),
    EntryPoint("beacon_slam", rs.beacon_slam, build_beacon_slam, heavy=True),
    EntryPoint(
        "beacon_slam_incremental",
        rs.beacon_slam_incremental,
        P(build_beacon_slam, incremental=True),
        heavy=True,
    ),
    EntryPoint("cli run", cli, build_cli_run, heavy=True),
    EntryPoint("cli simulate room", cli, build_cli_simulate, heavy=True),
)
BY_NAME = {entry.name: entry for entry in ENTRY_POINTS}


def uncovered() -> list[str]:
    """Functions of ``rangeslam.__all__`` no entry point calls (the smoke test keeps it empty)."""
    called = {getattr(e.call, "__name__", "") for e in ENTRY_POINTS}
    return [
        name
        for name in rs.__all__
        if callable(getattr(rs, name)) and not isinstance(getattr(rs, name), type)
        if name not in called
    ]


# ---- running -------------------------------------------------------------------------------------


def _alarm(signum, frame):
    raise Hang


def package_frame(exc: BaseException) -> str:
    """The last traceback frame inside the rangeslam package, as path:line in function."""
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if "/rangeslam/" in f.filename]
    if not frames:
        return "(no package frame)"
    f = frames[-1]
    return f"{f.filename.split('/rangeslam/', 1)[1]}:{f.lineno} in {f.name}"


def timed_call(call: Callable[..., Any], kwargs: dict[str, Any], timeout: float):
    """(result, exception) of one call under a SIGALRM after ``timeout`` seconds."""
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return call(**kwargs), None
    except (Exception, Hang, SystemExit) as exc:  # classifying is the point
        return None, exc
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def classify(result: Any, exc: BaseException | None, problem: Problem, argument: str):
    """(outcome, exception type, message, frame) of one call."""
    if isinstance(exc, Hang):
        return "hang", "", "", ""
    if isinstance(exc, RangeSlamError | CliRefused):
        return "refused", type(exc).__name__, str(exc)[:300], ""
    if exc is not None:
        return "foreign", type(exc).__name__, str(exc)[:300], package_frame(exc)
    if problem.check is not None and argument not in problem.data_args and is_converged(result):
        try:
            wrong = problem.check(result)
        except Exception as err:  # a converged result that cannot be read is wrong
            wrong = f"converged result unreadable: {type(err).__name__}: {err}"
        if wrong:
            return "converged-wrong", "", wrong, ""
    return "ok", "", "", ""


def one_call(entry: EntryPoint, data, timeout: float) -> Record:
    """Draw a family, a problem and (for an argument family) an argument and its value; call."""
    family = data.draw(st.sampled_from(FAMILIES), label="family")
    problem_seed = data.draw(st.integers(0, 2**31 - 1), label="problem seed")
    geometry = family if family in GEOMETRY_FAMILIES else "valid"
    problem = entry.build(np.random.default_rng(problem_seed), geometry)
    kwargs, argument, value = dict(problem.kwargs), "-", ""
    if family in ARGUMENT_FAMILIES:
        names = sorted(k for k in kwargs if k != "command")
        argument = data.draw(st.sampled_from(names), label="argument")
        kwargs[argument] = mutate(kwargs[argument], family, data)
        value = short(kwargs[argument])
    start = time.perf_counter()
    result, exc = timed_call(entry.call, kwargs, timeout)
    seconds = time.perf_counter() - start
    outcome, exc_type, message, frame = classify(result, exc, problem, argument)
    return Record(entry.name, family, argument, outcome, seconds, problem_seed, exc_type,
                  message, frame, value, exc is None and is_converged(result))  # fmt: skip


def fuzz_entry(entry: EntryPoint, examples: int, seed: int, timeout: float) -> list[Record]:
    """``examples`` hypothesis examples of ``entry`` at ``seed``: one record per call."""
    records: list[Record] = []

    @hypothesis_seed(seed)
    @settings(
        max_examples=examples,
        deadline=None,
        database=None,
        derandomize=False,
        phases=(Phase.generate,),
        suppress_health_check=list(HealthCheck),
    )
    @given(data=st.data())
    def run(data):
        records.append(one_call(entry, data, timeout))

    run()
    return records


# ---- reporting -----------------------------------------------------------------------------------


@dataclass
class Totals:
    """Outcomes per entry point; "converged" counts the calls whose result said CONVERGED (each
    checked against the truth unless the replaced argument was part of the data)."""

    counts: dict[str, dict[str, int]] = field(default_factory=dict)
    converged: dict[str, int] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)

    def add(self, name: str, records: list[Record]) -> None:
        self.counts[name] = {o: sum(r.outcome == o for r in records) for o in OUTCOMES}
        self.converged[name] = sum(r.converged for r in records)
        self.seconds[name] = sum(r.seconds for r in records)

    def table(self) -> str:
        header = ["entry point", "calls", *OUTCOMES, "converged", "seconds"]
        rows, total = [], dict.fromkeys(OUTCOMES, 0)
        for name, counts in self.counts.items():
            rows.append([name, sum(counts.values()), *counts.values(), self.converged[name],
                         f"{self.seconds[name]:.0f}"])  # fmt: skip
            for o in OUTCOMES:
                total[o] += counts[o]
        rows.append(["**total**", sum(total.values()), *total.values(),
                     sum(self.converged.values()), f"{sum(self.seconds.values()):.0f}"])  # fmt: skip
        lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        return "\n".join(lines + ["| " + " | ".join(str(c) for c in row) + " |" for row in rows])


def write_failures(out: Path, records: list[Record], meta: dict[str, Any]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    failed = [asdict(r) for r in records if r.outcome in FAILURES]
    (out / "fuzz_failures.json").write_text(json.dumps(dict(meta, failures=failed), indent=1))
    with open(out / "fuzz_failures.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(Record.__dataclass_fields__))
        writer.writeheader()
        writer.writerows(failed)


def describe(record: Record) -> str:
    where = f" at {record.frame}" if record.frame else ""
    kind = f"{record.exc_type}: " if record.exc_type else ""
    return (
        f"{record.outcome}: {record.entry} [{record.family}] {record.argument}={record.value} "
        f"(problem seed {record.problem_seed}): {kind}{record.message}{where}"
    )


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, required=True, help="hypothesis seed")
    parser.add_argument("--examples", type=int, default=200, help="examples per entry point")
    parser.add_argument("--heavy-examples", type=int, default=None,
                        help="examples per solver-heavy entry point (default: --examples)")  # fmt: skip
    parser.add_argument("--only", choices=sorted(BY_NAME), help="run one entry point")
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds a call may take")
    parser.add_argument("--out", type=Path, help="folder for fuzz_failures.json and .csv")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    heavy = args.examples if args.heavy_examples is None else args.heavy_examples
    entries = [BY_NAME[args.only]] if args.only else list(ENTRY_POINTS)
    totals, records = Totals(), []
    for entry in entries:
        got = fuzz_entry(entry, heavy if entry.heavy else args.examples, args.seed, args.timeout)
        totals.add(entry.name, got)
        records += got
        print(f"{entry.name}: {totals.counts[entry.name]}", file=sys.stderr, flush=True)
    print(totals.table())
    failed = [r for r in records if r.outcome in FAILURES]
    for record in failed:
        print(describe(record))
    if args.out is not None:
        meta = dict(seed=args.seed, examples=args.examples, heavy_examples=heavy,
                    timeout=args.timeout, rangeslam=rs.__version__)  # fmt: skip
        write_failures(args.out, records, meta)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
