"""The Fig. 5 walk as RIRs, end to end, against the same SLAM fed exact ranges with matched noise.

    python benchmarks/bench_walk_rirs.py [--walks 12] [--seed 0] [--frames-per-step 8] [--fs 16000]

Each walk: the lemniscate of eq. (12), M = 15 steps of t = 0.3 (about 33 cm), a loudspeaker
uniform in the 5 x 4 x 2.6 m room, pyroomacoustics RIRs (order 3, absorption 0.2) at
``frames-per-step`` RIRs a step (the SLAM steps are every that many), step bounds +-20 %.
:func:`rangeslam.acoustics.tracking.walk_from_rirs` gives the trajectory; the reference is
:func:`rangeslam.mdu.slam` on the exact ranges to the loudspeaker and its 6 first-order images with
N(0, sigma^2) noise, sigma the RMS error of the ranges the RIR pipeline used (each against the
nearest image source of order <= 3). Errors: trajectory RMS after rigid alignment (reflection
allowed: a planar walk is heard the same from both sides).
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
from _common import machine, markdown_table, timed

from rangeslam import Room, align
from rangeslam.acoustics.walk import walk_from_rirs
from rangeslam.app.experiments import FIG5_ROOM_SIZE
from rangeslam.geometry.edm import range_matrix
from rangeslam.mdu import slam
from rangeslam.sim.rir import shoebox_rirs
from rangeslam.sim.scenes import random_points_in_room
from rangeslam.sim.trajectories import lemniscate, step_lengths


def one_walk(rng: np.random.Generator, frames_per_step: int, fs: int, m: int = 15) -> dict:
    k = frames_per_step
    room = Room.shoebox(FIG5_ROOM_SIZE)
    traj = lemniscate((m - 1) * k + 1, step=0.3 / k, phase=rng.uniform(0, 2 * np.pi))
    src = random_points_in_room(room, 1, rng=rng)[0]
    landmarks = np.vstack([src, room.image_sources(src, 1).positions])
    images = np.vstack([src, room.image_sources(src, 3).positions])
    rirs = shoebox_rirs(FIG5_ROOM_SIZE, src, traj, fs=fs, absorption=0.2, max_order=3)
    keys = np.arange(0, len(traj), k)
    truth = traj[keys]
    steps = step_lengths(truth)
    bounds = (0.8 * steps, 1.2 * steps)
    w, seconds = timed(walk_from_rirs, rirs, fs, step_bounds=bounds, keyframes=keys, rng=rng)
    row = {"converged": w.converged, "seconds": seconds, "message": w.message}
    if w.slam is None:
        return {**row, "error": np.nan, "ref": np.nan, "sigma": np.nan, "landmarks": 0}
    err = align(w.trajectory, truth, reflection=True).rmse
    all_ranges = range_matrix(truth, images)
    used = np.concatenate(
        [
            np.abs(w.ranges[w.mask[:, c], c][:, None] - all_ranges[w.mask[:, c]]).min(axis=1)
            for c in range(w.ranges.shape[1])
        ]
    )
    sigma = float(np.sqrt(np.mean(used**2)))
    exact = range_matrix(truth, landmarks)
    ref = slam(
        exact + rng.normal(0, sigma, exact.shape), step_bounds=bounds, noise_std=sigma, rng=rng
    )
    ref_err = align(ref.receivers, truth, reflection=True).rmse
    return {
        **row,
        "error": err,
        "ref": ref_err,
        "sigma": sigma,
        "landmarks": w.ranges.shape[1],
        "used": int(w.mask.sum()),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--walks", type=int, default=12)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frames-per-step", type=int, default=8)
    ap.add_argument("--fs", type=int, default=16000)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    rows = []
    for j, seed in enumerate(np.random.SeedSequence(args.seed).spawn(args.walks)):
        r = one_walk(np.random.default_rng(seed), args.frames_per_step, args.fs)
        rows.append(r)
        print(
            f"walk {j}: error {1e3 * r['error']:.2f} mm, reference {1e3 * r['ref']:.2f} mm, "
            f"sigma {1e3 * r['sigma']:.2f} mm, converged {r['converged']}, {r['seconds']:.0f} s",
            flush=True,
        )
    err = np.array([r["error"] for r in rows])
    ref = np.array([r["ref"] for r in rows])
    conv = np.array([r["converged"] for r in rows])
    ok = conv & np.isfinite(err)
    ratio = err[ok] / np.maximum(ref[ok], 1e-6)
    for j, r in enumerate(rows):
        if not r["converged"]:
            print(f"walk {j} not converged: {r['message']}")
    print()
    print(
        markdown_table(
            [
                "walk",
                "RIR pipeline [mm]",
                "exact + matched noise [mm]",
                "ratio",
                "sigma [mm]",
                "landmarks",
                "converged",
                "s",
            ],
            [
                [
                    j,
                    f"{1e3 * r['error']:.2f}",
                    f"{1e3 * r['ref']:.2f}",
                    f"{r['error'] / max(r['ref'], 1e-6):.2f}",
                    f"{1e3 * r['sigma']:.2f}",
                    r["landmarks"],
                    r["converged"],
                    f"{r['seconds']:.0f}",
                ]
                for j, r in enumerate(rows)
            ],
        )
    )
    print()
    if not ok.any():
        print(f"{args.frames_per_step} RIRs a step, {args.fs} Hz: none of {len(rows)} converged")
        print(machine())
        return
    print(
        f"{args.frames_per_step} RIRs a step, {args.fs} Hz: converged {ok.sum()} of {len(rows)}; "
        f"mean error {1e3 * err[ok].mean():.2f} mm against {1e3 * ref[ok].mean():.2f} mm "
        f"(ratio of means {err[ok].mean() / ref[ok].mean():.2f}); per walk: median ratio "
        f"{np.median(ratio):.2f}, within 1.5x in {np.mean(ratio <= 1.5):.0%}, worst "
        f"{ratio.max():.2f}"
    )
    print(machine())


if __name__ == "__main__":
    main()
