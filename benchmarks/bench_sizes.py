"""The EDM start at the sizes people have.

    python benchmarks/bench_sizes.py [--trials 5] [--seed 0] [--steps 60 100 200]
        [--arrays 100x60] [--max-sdp-points N]

SLAM: random smooth non-planar 3-D walks of M steps (0.3 m steps, turn std 0.5 rad) in random
convex rooms, the loudspeaker and its 6 first-order images nearest the walk (7 landmarks), 1 cm
range noise, ``noise_std`` NOT given, step bounds +-20% of the true steps. Calibration: M receivers
and K sources uniform in a 5 x 4 x 3 m room, every range observed, 1 cm, ``noise_std`` NOT given.

Each size runs in a fresh process, so its peak resident memory is its own. Error: the receivers'
(trajectory's) RMS after the best rigid motion, reflection allowed; bound: the RMS bound on it
(:func:`rangeslam.mdu_crlb`, receivers' gauge, with the step priors ``slam`` uses); the ratio is
RMS error over RMS bound across the trials (:func:`rangeslam.evaluation.metrics.rms_against_bound`),
converged trials only. ``--max-sdp-points`` sets :data:`rangeslam.mdu.subsets.MAX_SDP_POINTS`
(a large value gives the single SDP over every point, the schedule before this item).
"""

from __future__ import annotations

import argparse
import multiprocessing
import resource
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from _common import machine, markdown_table

from rangeslam import align, calibrate, mdu_crlb
from rangeslam.evaluation.metrics import rms_against_bound
from rangeslam.geometry.edm import range_matrix
from rangeslam.mdu import subsets
from rangeslam.mdu.slam import slam
from rangeslam.sim.scenes import add_range_noise, walk_in_random_room
from rangeslam.sim.trajectories import step_lengths

SIGMA = 0.01
ROOM = np.array([5.0, 4.0, 3.0])


def walk_trial(m: int, rng: np.random.Generator) -> tuple[float, float, bool]:
    """One slam solve on a random walk of ``m`` steps: (error m, RMS bound m, converged)."""
    traj, landmarks = walk_in_random_room(m, rng=rng)
    ranges = add_range_noise(range_matrix(traj, landmarks), SIGMA, rng=rng)
    steps = step_lengths(traj)
    bounds = (0.8 * steps, 1.2 * steps)
    res = slam(ranges, step_bounds=bounds, rng=rng)
    bound = mdu_crlb(traj, landmarks, SIGMA, step_bounds=bounds).receiver_rmse
    return align(res.receivers, traj, reflection=True).rmse, bound, res.converged


def array_trial(m: int, k: int, rng: np.random.Generator) -> tuple[float, float, bool]:
    """One calibrate solve, ``m`` receivers and ``k`` sources: (error m, RMS bound m, converged)."""
    receivers = rng.uniform(0.0, 1.0, (m, 3)) * ROOM
    sources = rng.uniform(0.0, 1.0, (k, 3)) * ROOM
    ranges = add_range_noise(range_matrix(receivers, sources), SIGMA, rng=rng)
    res = calibrate(ranges, rng=rng)
    bound = mdu_crlb(receivers, sources, SIGMA).receiver_rmse
    return align(res.receivers, receivers, reflection=True).rmse, bound, res.converged


def run_case(case: str, size: tuple[int, ...], trials: int, seed: int, max_points: int) -> dict:
    """Every trial of one case and size (in a fresh process): errors, bounds, converged, times,
    the process's peak resident memory (MB)."""
    subsets.MAX_SDP_POINTS = max_points
    rng = np.random.default_rng([seed, *size])
    rows = []
    for _ in range(trials):
        t0 = time.perf_counter()
        out = walk_trial(size[0], rng) if case == "slam" else array_trial(*size, rng)
        rows.append((*out, time.perf_counter() - t0))
    errors, bounds, converged, seconds = (np.array(c) for c in zip(*rows, strict=True))
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"errors": errors, "bounds": bounds, "converged": converged.astype(bool),
            "seconds": seconds, "peak_mb": peak_mb}  # fmt: skip


def table_row(case: str, size: tuple[int, ...], out: dict) -> list[str]:
    """The markdown row of one case."""
    ok = out["converged"]
    cmp = rms_against_bound(out["errors"][ok], out["bounds"][ok])
    label = f"{size[0]} steps" if case == "slam" else f"{size[0]} x {size[1]}"
    return [
        case, label, f"{ok.sum()}/{len(ok)}", f"{100 * cmp.rms_error:.2f}",
        f"{100 * cmp.rms_bound:.2f}", f"{cmp.ratio:.2f}", f"{np.median(out['seconds']):.1f}",
        f"{out['seconds'].max():.1f}", f"{out['peak_mb']:.0f}",
    ]  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--steps", type=int, nargs="*", default=[60, 100, 200])
    ap.add_argument("--arrays", nargs="*", default=["100x60"], help="M x K, e.g. 100x60")
    ap.add_argument("--max-sdp-points", type=int, default=subsets.MAX_SDP_POINTS)
    args = ap.parse_args()
    print(f"# The EDM start at size (seed {args.seed}; {machine()})\n")
    print(f"SDP of at most {args.max_sdp_points} points; {args.trials} trials a row\n")
    header = [
        "estimator", "size", "converged", "RMS err (cm)", "RMS bound (cm)", "ratio",
        "median time (s)", "max time (s)", "peak memory (MB)",
    ]  # fmt: skip
    print(markdown_table(header, []), flush=True)
    cases = [("slam", (m,)) for m in args.steps]
    cases += [("calibrate", tuple(int(v) for v in a.split("x"))) for a in args.arrays]
    spawn = multiprocessing.get_context("spawn")
    for case, size in cases:
        with ProcessPoolExecutor(1, mp_context=spawn) as pool:
            out = pool.submit(
                run_case, case, size, args.trials, args.seed, args.max_sdp_points
            ).result()
        print(markdown_table(header, [table_row(case, size, out)]).splitlines()[-1], flush=True)


if __name__ == "__main__":
    main()
