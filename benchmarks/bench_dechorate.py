"""Problem 1 on real echoes: the dEchorate room from its 30 calibrated microphones.

    python benchmarks/bench_dechorate.py [--data dechorate] [--seeds 5]

Each loudspeaker alone and both together, with the default (data-driven) inlier rule and with a
fixed threshold of three samples (3 c / fs). Errors against the dataset's calibrated geometry:
wall offset at the wall's centroid, normal angle, loudspeaker position. Cite: Di Carlo et al.,
"dEchorate: a calibrated room impulse response dataset for echo-aware signal processing",
EURASIP JASMP 2021.
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import machine, markdown_table, timed

from rangeslam import reconstruct_room
from rangeslam.datasets import load_dechorate
from rangeslam.datasets.dechorate import ECHO_LABELS
from rangeslam.evaluation.metrics import wall_errors


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--data",
        default="dechorate",
        help="a path, or a name under $RANGESLAM_DATA (else ../shared/data)",
    )
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args()
    data = load_dechorate(args.data)
    walls = [lab.split("_")[0] for lab in ECHO_LABELS[1:]]
    rows, summary = [], []
    for name, speakers in (("loudspeaker 0", [0]), ("loudspeaker 1", [1]), ("both", [0, 1])):
        for rule, thr in (("default", None), ("3 samples", 3 * data.pick_resolution)):
            offs, lits, angs, srcs, times, used, conv = [], [], [], [], [], [], 0
            for seed in range(args.seeds):
                res, t = timed(
                    reconstruct_room,
                    data.mics,
                    [data.ranges(j) for j in speakers],
                    inlier_threshold=thr,
                    rng=seed,
                )
                off, ang = wall_errors(data.room, res.wall_normals, res.wall_offsets)
                offs.append(off)
                lits.append(np.abs(res.wall_offsets - data.room.offsets))
                angs.append(ang)
                srcs.append(
                    [
                        np.linalg.norm(res.sources[i] - data.sources[j])
                        for i, j in enumerate(speakers)
                    ]
                )
                times.append(t)
                used.append(f"{int(res.inliers.sum())}/{int(res.observed.sum())}")
                conv += res.converged
            off = np.median(offs, axis=0) * 100
            worst = np.max(offs, axis=0) * 100
            src = np.median(srcs, axis=0) * 100
            rows.append(
                [
                    name,
                    rule,
                    *[f"{o:.1f} ({w:.1f})" for o, w in zip(off, worst, strict=True)],
                    ", ".join(f"{s:.1f}" for s in src),
                    used[0],
                    f"{conv}/{args.seeds}",
                    f"{np.median(times):.2f}",
                ]
            )
            lit = np.median(lits, axis=0) * 100
            summary.append(
                [
                    name,
                    rule,
                    int(np.sum(off <= 5)),
                    f"{off.max():.1f}",
                    int(np.sum(lit <= 5)),
                    f"{lit.max():.1f}",
                    f"{np.max(angs):.1f}",
                ]
            )
    print(f"## dEchorate, measured echoes ({args.seeds} seeds; {machine()})\n")
    print("Wall offset error in cm at the wall's centroid: median over seeds (worst seed).\n")
    print(
        markdown_table(
            [
                "loudspeakers",
                "inlier rule",
                *walls,
                "loudspeaker error [cm]",
                "ranges used",
                "converged",
                "time [s]",
            ],
            rows,
        )
    )
    print()
    print(
        "Literal offset: |o_est - o_true| in the dataset's frame (origin at the south-west floor corner).\n"
    )
    print(
        markdown_table(
            [
                "loudspeakers",
                "inlier rule",
                "walls within 5 cm (centroid)",
                "worst wall [cm]",
                "walls within 5 cm (literal offset)",
                "worst literal [cm]",
                "worst normal [deg]",
            ],
            summary,
        )
    )


if __name__ == "__main__":
    main()
