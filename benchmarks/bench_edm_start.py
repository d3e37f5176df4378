"""The cost of the EDM start, before and after the cheap start.

    python benchmarks/bench_edm_start.py [--trials 10] [--seed 0] [--steps 5 8 10]
        [--starts cheap full] [--calibration-trials 50] [--skip-slam] [--skip-calibration]
        [--regime-walks 16 --seeds 1 2]

SLAM: random smooth non-planar 3-D walks (``random_walk``, 0.3 m steps, turn std 0.5 rad) in
random convex rooms (6 walls), a loudspeaker uniform in the room and its 6 first-order images
nearest the walk (7 landmarks); 1 cm range noise, ``noise_std`` NOT given; step bounds +-20% of
the true steps, or none. Methods, on the same ranges: ``slam`` with each ``edm_start`` (``full``:
the older schedule, every convex-iteration run of up to 50 SDP solves; ``cheap``: stop at
the first run the verdict accepts, runs stopped early on the embedding) and GTSAM alone, best final
cost of 3 GTSAM-style random starts (the peer). Error: trajectory RMS after the
best rigid motion with reflection; success: error < 10 cm.

Calibration: the Fig. 3 scene (6 microphones in a 1 m cube, a loudspeaker and its 5 nearest
first-order images), sigma = 0 and 1 cm, ``noise_std`` NOT given; success: error < 1 mm at
sigma = 0, < 3x the configuration's CRLB otherwise.

SDP solves are counted by wrapping ``EDMCompletionSDP.solve``. Times are medians over the trials; speed as ratios in
the same run.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _common import machine, markdown_table

from rangeslam import align
from rangeslam.app.experiments import calibration_experiment, gtsam_style_start
from rangeslam.errors import SolverError
from rangeslam.geometry.edm import range_matrix
from rangeslam.mdu.slam import slam
from rangeslam.sim.scenes import add_range_noise, walk_in_random_room
from rangeslam.sim.trajectories import step_lengths
from rangeslam.solvers import sdp
from rangeslam.solvers.gtsam_graph import refine_graph

SOLVES = {"n": 0}


def count_solves() -> None:
    """Wrap the SDP's ``solve`` (the cvxpy model) so that every SDP solve is counted in SOLVES."""
    original = sdp.EDMCompletionSDP.solve

    def solve(self, z):
        SOLVES["n"] += 1
        return original(self, z)

    sdp.EDMCompletionSDP.solve = solve


def walk_scene(m: int, sigma: float, rng: np.random.Generator):
    """(trajectory (M, 3), landmarks (7, 3), noisy ranges (M, 7)): a smooth random walk in a
    random convex room, the loudspeaker and its 6 first-order images nearest the walk."""
    traj, landmarks = walk_in_random_room(m, rng=rng)
    ranges = add_range_noise(range_matrix(traj, landmarks), sigma, rng=rng)
    return traj, landmarks, ranges


def gtsam_best_of(k: int, ranges, bounds, sigma_graph: float, rng) -> tuple[np.ndarray, float]:
    """GTSAM alone from ``k`` GTSAM-style random starts, the lowest final graph cost kept:
    (trajectory (M, 3), seconds)."""
    t0 = time.perf_counter()
    best, best_cost = None, np.inf
    for _ in range(k):
        x0, s0 = gtsam_style_start(ranges, bounds, rng)
        try:
            fit = refine_graph(
                x0, s0, ranges, noise_std=sigma_graph, step_bounds=bounds, covariances=False,
                max_iterations=5000,
            )  # fmt: skip
        except SolverError:
            continue
        if fit.error < best_cost:
            best, best_cost = fit.receivers, fit.error
    seconds = time.perf_counter() - t0
    return (x0 if best is None else best), seconds


def slam_rows(args, rng) -> list[list[str]]:
    """One row per (M, bounds, method)."""
    rows = []
    for bounded in (True, False):
        for m in args.steps:
            stats = {name: [] for name in [*args.starts, "gtsam3"]}
            for _ in range(args.trials):
                traj, _, ranges = walk_scene(m, 0.01, rng)
                steps = step_lengths(traj)
                bounds = (0.8 * steps, 1.2 * steps) if bounded else None
                seed = int(rng.integers(2**31))
                for start in args.starts:
                    SOLVES["n"] = 0
                    t0 = time.perf_counter()
                    res = slam(ranges, step_bounds=bounds, edm_start=start, rng=seed)
                    dt = time.perf_counter() - t0
                    err = align(res.receivers, traj, reflection=True).rmse
                    stats[start].append((err, dt, SOLVES["n"], res.attempts, res.converged))
                x, dt = gtsam_best_of(3, ranges, bounds, 0.01, np.random.default_rng(seed))
                err = align(x, traj, reflection=True).rmse
                stats["gtsam3"].append((err, dt, 0, 0, True))
            peer = np.median([s[1] for s in stats["gtsam3"]])
            for name, runs in stats.items():
                a = np.array(runs, dtype=float)
                rows.append(
                    [
                        m,
                        "+-20%" if bounded else "none",
                        name if name == "gtsam3" else f"slam, edm_start={name}",
                        f"{np.median(a[:, 0]) * 100:.2f}",
                        f"{np.sqrt(np.mean(a[:, 0] ** 2)) * 100:.2f}",
                        f"{np.mean(a[:, 0] < 0.1) * 100:.0f}%",
                        f"{np.median(a[:, 1]):.3f}",
                        f"{np.median(a[:, 1]) / peer:.1f}x",
                        "-" if name == "gtsam3" else f"{np.median(a[:, 2]):.0f}",
                        "-" if name == "gtsam3" else f"{np.median(a[:, 3]):.0f}",
                        "-" if name == "gtsam3" else f"{np.mean(a[:, 4]) * 100:.0f}%",
                    ]
                )
                print("| " + " | ".join(str(c) for c in rows[-1]) + " |", flush=True)
    return rows


def calibration_rows(args, rng) -> list[list[str]]:
    """One row per (sigma, edm_start)."""
    rows = []
    for sigma in (0.0, 0.01):
        stats = {name: [] for name in args.starts}
        for _ in range(args.calibration_trials):
            seed = int(rng.integers(2**31))
            for start in args.starts:
                SOLVES["n"] = 0
                t0 = time.perf_counter()
                run = calibration_experiment(
                    sigma, np.random.default_rng(seed), noise_std=None, edm_start=start
                )
                dt = time.perf_counter() - t0
                ok = run.mic_error < (1e-3 if sigma == 0 else 3 * run.mic_crlb)
                stats[start].append((run.mic_error, dt, SOLVES["n"], ok, run.result.converged))
        peer = np.median([s[1] for s in stats[args.starts[0]]])
        for name, runs in stats.items():
            a = np.array(runs, dtype=float)
            rows.append(
                [
                    f"{sigma * 1e3:g} mm",
                    f"calibrate, edm_start={name}",
                    f"{np.median(a[:, 0]) * 1e3:.3g}",
                    f"{np.sqrt(np.mean(a[:, 0] ** 2)) * 1e3:.3g}",
                    f"{int(a[:, 3].sum())}/{len(a)}",
                    f"{np.median(a[:, 1]):.3f}",
                    f"{np.median(a[:, 1]) / peer:.2f}x",
                    f"{np.median(a[:, 2]):.0f}",
                    f"{np.mean(a[:, 4]) * 100:.0f}%",
                ]
            )
            print("| " + " | ".join(str(c) for c in rows[-1]) + " |", flush=True)
    return rows


def regime_walk_row(walks: int, seed: int) -> list[str]:
    """The cheap start's criterion on the regime map's walks (``RegimeCell("random", 8, True,
    0.01)``): ``slam`` without ``noise_std`` against GTSAM best of 3 random starts given the
    noise, ``walks`` scenes drawn from ``seed``, paired per walk in this process."""
    from rangeslam.app.regimes import RegimeCell, draw_scene, run_random_starts

    rng = np.random.default_rng(seed)
    cell = RegimeCell("random", 8, True, 0.01)
    ours, peer, t_ours, t_peer = [], [], [], []
    for _ in range(walks):
        scene = draw_scene(cell, rng)
        t0 = time.perf_counter()
        out = slam(scene.ranges, step_bounds=scene.step_bounds, mask=scene.mask, rng=rng)
        t_ours.append(time.perf_counter() - t0)
        best3 = run_random_starts(scene, cell, rng, budget=np.inf, max_starts=3)
        t_peer.append(best3.seconds)
        ours.append(align(out.receivers, scene.trajectory, reflection=True).rmse * 100)
        peer.append(align(best3.receivers, scene.trajectory, reflection=True).rmse * 100)
    a, b = np.array(ours), np.array(peer)
    ta, tb = np.median(t_ours), np.median(t_peer)
    return [
        str(seed),
        f"{np.median(a):.2f} / {np.median(b):.2f} cm ({np.median(a) / np.median(b):.2f}x)",
        f"{np.mean(a < 10) * 100:.0f}% / {np.mean(b < 10) * 100:.0f}%",
        f"{np.sqrt(np.mean(a**2)):.2f} / {np.sqrt(np.mean(b**2)):.2f}",
        f"{ta:.2f} / {tb:.2f} s ({ta / tb:.1f}x)",
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--calibration-trials", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, nargs="+", default=[5, 8, 10])
    ap.add_argument("--starts", nargs="+", default=["cheap", "full"])
    ap.add_argument("--skip-slam", action="store_true")
    ap.add_argument("--skip-calibration", action="store_true")
    ap.add_argument(
        "--regime-walks", type=int, default=0,
        help="also the cheap start's criterion on this many regime-map walks per seed (--seeds)",
    )  # fmt: skip
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    args = ap.parse_args()
    count_solves()
    rng = np.random.default_rng(args.seed)
    print(f"# The EDM start (seed {args.seed}; {machine()})\n")
    if not args.skip_slam:
        print(f"## slam, {args.trials} walks per row, 1 cm, noise_std not given\n")
        header = [
            "M", "bounds", "method", "median err (cm)", "RMS err (cm)", "< 10 cm",
            "median time (s)", "time / GTSAM best-of-3", "SDP solves (median)",
            "runs (median)", "converged",
        ]  # fmt: skip
        print(markdown_table(header, []), flush=True)
        slam_rows(args, rng)
    if not args.skip_calibration:
        print(f"\n## calibrate, Fig. 3, {args.calibration_trials} scenes, noise_std not given\n")
        header = [
            "sigma", "method", "median err (mm)", "RMS err (mm)", "success", "median time (s)",
            f"time / {args.starts[0]}", "SDP solves (median)", "converged",
        ]  # fmt: skip
        print(markdown_table(header, []), flush=True)
        calibration_rows(args, rng)
    if args.regime_walks:
        print(f"\n## slam vs GTSAM best of 3, {args.regime_walks} regime-map walks per seed\n")
        header = [
            "seed", "slam median / best-of-3 median (error)", "success slam / best-of-3 (< 10 cm)",
            "RMS error slam / best-of-3 (cm)", "median time slam / best-of-3",
        ]  # fmt: skip
        print(markdown_table(header, []), flush=True)
        for seed in args.seeds:
            print("| " + " | ".join(regime_walk_row(args.regime_walks, seed)) + " |", flush=True)


if __name__ == "__main__":
    main()
