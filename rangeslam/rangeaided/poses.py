"""Pose algebra for range-aided SLAM, pure numpy: SE(2) rows (x, y, theta) and SE(3) rows
(x, y, z, qx, qy, qz, qw), composition, relative poses, dead reckoning along odometry chains.

Quaternions are Hamilton, scalar last (the PyFG files' order); rotation matrices act on columns
and are built with the usual formula (e.g. J. Sola, "Quaternion kinematics for the error-state
Kalman filter", 2017, eq. 115).
"""

from __future__ import annotations

import numpy as np

from rangeslam.errors import InvalidInputError

__all__ = [
    "compose",
    "dead_reckoning",
    "matrix_to_quaternion",
    "positions",
    "quaternion_to_matrix",
    "relative",
    "transform_points",
]


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotation matrices of (n, 4) quaternions (qx, qy, qz, qw), normalised first."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quaternion(rot: np.ndarray) -> np.ndarray:
    """(n, 4) unit quaternions (qx, qy, qz, qw), qw >= 0, of (n, 3, 3) rotation matrices
    (Shepperd's method: the largest of the four squares is taken first, for accuracy)."""
    rot = np.asarray(rot, dtype=float).reshape(-1, 3, 3)
    tr = np.trace(rot, axis1=1, axis2=2)
    diag = np.diagonal(rot, axis1=1, axis2=2)
    squares = np.column_stack([1 + 2 * diag - tr[:, None], 1 + tr])  # 4 qx^2, 4 qy^2, ...
    pick = np.argmax(squares, axis=1)
    out = np.empty((len(rot), 4))
    r = rot
    for k in range(4):
        m = pick == k
        if not np.any(m):
            continue
        s = np.sqrt(squares[m, k])  # = 4 |q_k| / 2 ... 2 |q_k|
        off = {
            "xy": r[m, 0, 1] + r[m, 1, 0], "xz": r[m, 0, 2] + r[m, 2, 0],
            "yz": r[m, 1, 2] + r[m, 2, 1], "wx": r[m, 2, 1] - r[m, 1, 2],
            "wy": r[m, 0, 2] - r[m, 2, 0], "wz": r[m, 1, 0] - r[m, 0, 1],
        }  # fmt: skip
        rows = {
            0: (s, off["xy"] / s, off["xz"] / s, off["wx"] / s),
            1: (off["xy"] / s, s, off["yz"] / s, off["wy"] / s),
            2: (off["xz"] / s, off["yz"] / s, s, off["wz"] / s),
            3: (off["wx"] / s, off["wy"] / s, off["wz"] / s, s),
        }[k]
        out[m] = 0.5 * np.column_stack(rows)
    out *= np.where(out[:, 3:] < 0, -1.0, 1.0)
    return out


def _split(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, d) translations and (n, d, d) rotations of (n, 3) or (n, 7) pose rows."""
    if poses.shape[1] == 3:
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        return poses[:, :2], np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    return poses[:, :3], quaternion_to_matrix(poses[:, 3:])


def _join(t: np.ndarray, rot: np.ndarray, theta: np.ndarray | None = None) -> np.ndarray:
    if rot.shape[1] == 2:
        angle = np.arctan2(rot[:, 1, 0], rot[:, 0, 0]) if theta is None else theta
        return np.column_stack([t, angle])
    return np.column_stack([t, matrix_to_quaternion(rot)])


def _check(poses, name: str) -> np.ndarray:
    arr = np.asarray(poses, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] not in (3, 7):
        raise InvalidInputError(f"{name} must have shape (n, 3) or (n, 7); got {arr.shape}")
    return arr


def compose(a, b) -> np.ndarray:
    """(n, 3) or (n, 7) poses a o b (b expressed in the frame of a, moved to a's frame's world).
    In 2-D the angles add without wrapping (theta_a + theta_b)."""
    a, b = _check(a, "a"), _check(b, "b")
    ta, ra = _split(a)
    tb, rb = _split(b)
    t = ta + np.einsum("nij,nj->ni", ra, tb)
    theta = a[:, 2] + b[:, 2] if a.shape[1] == 3 else None
    return _join(t, ra @ rb, theta)


def relative(a, b) -> np.ndarray:
    """(n, 3) or (n, 7) poses a^-1 o b: b in the frame of a (angles wrapped to (-pi, pi])."""
    a, b = _check(a, "a"), _check(b, "b")
    ta, ra = _split(a)
    tb, rb = _split(b)
    rt = np.swapaxes(ra, 1, 2)
    return _join(np.einsum("nij,nj->ni", rt, tb - ta), rt @ rb)


def transform_points(poses, points) -> np.ndarray:
    """(n, d) points given in the frames of (n,) poses, in the world."""
    t, rot = _split(_check(poses, "poses"))
    return t + np.einsum("nij,nj->ni", rot, np.asarray(points, dtype=float))


def positions(poses) -> np.ndarray:
    """(n, d) positions of (n, 3) or (n, 7) poses."""
    poses = _check(poses, "poses")
    return poses[:, :2] if poses.shape[1] == 3 else poses[:, :3]


def dead_reckoning(start, steps) -> np.ndarray:
    """(m + 1, 3) or (m + 1, 7) poses from ``start`` (one pose row) composed with the m
    relative ``steps`` in turn (pose k + 1 = pose k o step k). In 2-D, a running sum of angles
    and a cumulative sum of rotated steps (exact, vectorised); in 3-D, a loop."""
    start, steps = _check(start, "start"), _check(steps, "steps")
    if start.shape[1] != steps.shape[1] or len(start) != 1:
        raise InvalidInputError(
            f"start must be one pose of the steps' width {steps.shape[1]}; got {start.shape}"
        )
    if steps.shape[1] == 3:
        theta = start[0, 2] + np.concatenate([[0.0], np.cumsum(steps[:, 2])])
        c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
        dx = c * steps[:, 0] - s * steps[:, 1]
        dy = s * steps[:, 0] + c * steps[:, 1]
        x = start[0, 0] + np.concatenate([[0.0], np.cumsum(dx)])
        y = start[0, 1] + np.concatenate([[0.0], np.cumsum(dy)])
        return np.column_stack([x, y, theta])
    t, rot = _split(start)
    t, rot = t[0], rot[0]
    dt, drot = _split(steps)
    out_t, out_r = [t], [rot]
    for k in range(len(steps)):
        t = t + rot @ dt[k]
        rot = rot @ drot[k]
        out_t.append(t)
        out_r.append(rot)
    return _join(np.array(out_t), np.array(out_r))
