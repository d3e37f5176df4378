"""Problem 1 on simulated rooms: wall accuracy against noise, wrong picks and room shape.

    python benchmarks/bench_room.py [--trials 100] [--seed 0]

8 random microphones (12 with wrong picks) and 1 or 2 loudspeakers uniform in the room, 0.3 m from
the walls; first-order echoes with Gaussian range noise and a fraction of wrong picks (0.2-2 m).
Wall error = distance from the true wall's centroid to the estimated plane; the CRLB column is the
median over trials of the largest per-wall bound (wall_crlb), in the same metric.
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import machine, markdown_table, timed

from rangeslam import Room, wall_crlb
from rangeslam.app.experiments import demo_rooms, room_experiment
from rangeslam.evaluation import rms_against_bound
from rangeslam.sim.scenes import random_convex_room


def rooms(kind: str, rng) -> Room:
    if kind == "shoebox 3-D":
        return Room.shoebox([5.1, 3.7, 2.6])
    if kind == "cut corner 3-D":
        return demo_rooms()["cut corner"]
    if kind == "random convex 3-D (6-8 walls)":
        return random_convex_room(3, int(rng.integers(6, 9)), rng=rng)
    if kind == "random convex 2-D (5-6 walls)":
        return random_convex_room(2, int(rng.integers(5, 7)), rng=rng)
    raise ValueError(kind)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    rows = []
    configs = [
        (0.0, 0.0, 8, 1),
        (1e-3, 0.0, 8, 1),
        (5e-3, 0.0, 8, 1),
        (1e-2, 0.0, 8, 1),
        (1e-3, 0.0, 8, 2),
        (1e-3, 0.1, 12, 2),
    ]
    for kind in (
        "shoebox 3-D",
        "cut corner 3-D",
        "random convex 3-D (6-8 walls)",
        "random convex 2-D (5-6 walls)",
    ):
        for sigma, frac, n_mics, n_src in configs:
            worst, errs, crlb, times, conv, within = [], [], [], [], 0, 0
            for _ in range(args.trials):
                room = rooms(kind, rng)
                exp, t = timed(
                    room_experiment,
                    room,
                    n_mics=n_mics,
                    n_sources=n_src,
                    sigma=sigma,
                    outlier_fraction=frac,
                    rng=rng,
                )
                times.append(t)
                conv += exp.result.converged
                worst.append(exp.offset_errors.max())
                errs.append(exp.offset_errors)
                within += bool(exp.offset_errors.max() < 0.01)
                if sigma > 0:
                    crlb.append(
                        wall_crlb(
                            exp.mics,
                            exp.sources,
                            room.normals,
                            room.offsets,
                            sigma,
                            points=room.wall_centroids,
                        )[0]
                    )
            worst = np.array(worst) * 1e3
            # every wall of every trial: RMS offset error against the RMS of the wall bounds
            cmp = rms_against_bound(np.concatenate(errs), np.concatenate(crlb)) if crlb else None
            rows.append(
                [
                    kind,
                    f"{sigma * 1e3:g}",
                    f"{frac:.0%}",
                    f"{n_mics}/{n_src}",
                    f"{cmp.rms_error * 1e3:.3g}" if cmp else "-",
                    f"{cmp.rms_bound * 1e3:.3g}" if cmp else "-",
                    f"{cmp.ratio:.2f} {cmp.regime}" if cmp else "-",
                    f"{np.median(worst):.3g}",
                    f"{np.percentile(worst, 95):.3g}",
                    f"{worst.max():.3g}",
                    f"{within / args.trials:.0%}",
                    f"{conv / args.trials:.0%}",
                    f"{np.median(times) * 1e3:.0f}",
                ]
            )
    print(
        f"## Problem 1, simulated ({args.trials} trials per row, seed {args.seed}; {machine()})\n"
    )
    print(
        markdown_table(
            [
                "room",
                "sigma [mm]",
                "wrong picks",
                "mics/speakers",
                "RMS wall offset error [mm]",
                "RMS CRLB [mm]",
                "RMS error / RMS CRLB, regime",
                "worst wall median [mm]",
                "p95 [mm]",
                "max [mm]",
                "all walls < 1 cm",
                "converged",
                "time [ms]",
            ],
            rows,
        )
    )


if __name__ == "__main__":
    main()
