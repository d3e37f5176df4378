"""Where `calibrate`'s time goes on Fig. 3 scenes (issue 45): the SDP, the refinements, the judge.

    python benchmarks/profile_calibrate.py --scenes 20 --seed 52817

Fig. 3 scenes (``fig3_scene``: 6 microphones in a 1 m cube, a loudspeaker and its 5 first-order
images nearest the array), 1 mm range noise, ``calibrate(ranges, dim=3, rng=i)`` with
``noise_std`` not given (the issue's case) and given. Each part is timed by wrapping its function
(wall-clock, ``time.perf_counter``): the SDP solves of the convex iteration
(``EDMCompletionSDP.solve``) and within them Clarabel's call (cvxpy's ``solve_via_data``), the
search's refinement of each run (``fit_start``), the judge (``judge_calibration``) and within it
its least-squares refits, the verdict's checks (``calibration_verdict``) and the result
(``calibration_result``). "Calibration" is the whole call. Medians over the scenes; SDP solves
from the result's ``iterations``. The accuracy of each setting is in benchmarks/README.md.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np
from _common import machine, markdown_table, wrap_parts
from cvxpy.reductions.solvers.conic_solvers.clarabel_conif import CLARABEL

import rangeslam.mdu.calibration  # noqa: F401  (the module, which the function shadows)
from rangeslam.app.experiments import fig3_scene
from rangeslam.mdu import calibration_judge
from rangeslam.solvers.sdp import EDMCompletionSDP

CAL = sys.modules["rangeslam.mdu.calibration"]
PARTS = {
    "SDP solves (cvxpy and Clarabel)": (EDMCompletionSDP, "solve"),
    "  of which Clarabel's call": (CLARABEL, "solve_via_data"),
    "search: refinement of each run": (CAL, "fit_start"),
    "judge, in all": (CAL, "judge_calibration"),
    "  of which least-squares refits": (calibration_judge, "refine_unfolding"),
    "verdict checks": (CAL, "calibration_verdict"),
    "result": (CAL, "calibration_result"),
}


def profile(scenes: int, seed: int, given: bool) -> tuple[list[tuple], list[str]]:
    """(total s, parts, SDP solves) of each scene's calibration, and its statuses."""
    spent: dict[str, float] = {}
    unwrap = wrap_parts(PARTS, spent)
    rng = np.random.default_rng(seed)
    rows, statuses = [], []
    for i in range(scenes):
        scene = fig3_scene(rng)
        ranges = scene.ranges + 1e-3 * rng.standard_normal(scene.ranges.shape)
        spent.clear()
        t0 = time.perf_counter()
        out = CAL.calibrate(ranges, dim=3, noise_std=1e-3 if given else None, rng=i)
        rows.append((time.perf_counter() - t0, dict(spent), out.iterations))
        statuses.append(out.status.name)
    unwrap()  # the originals again for the next setting
    return rows, statuses


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--seed", type=int, required=True)
    args = ap.parse_args()
    med = statistics.median
    print(f"{args.scenes} Fig. 3 scenes, 1 mm, seed {args.seed}, {machine()}\n")
    for given in (False, True):
        rows, statuses = profile(args.scenes, args.seed, given)
        total = med(r[0] for r in rows)
        table = [["calibration", f"{total:.3f}", f"{max(r[0] for r in rows):.3f}", "100%"]]
        table += [[name, f"{med(r[1].get(name, 0.0) for r in rows):.3f}",
                   f"{max(r[1].get(name, 0.0) for r in rows):.3f}",
                   f"{med(r[1].get(name, 0.0) / r[0] for r in rows):.0%}"] for name in PARTS]  # fmt: skip
        counts = {s: statuses.count(s) for s in sorted(set(statuses))}
        print(f"noise_std {'given (1 mm)' if given else 'not given'}: {counts}; SDP solves median "
              f"{med(r[2] for r in rows)}, max {max(r[2] for r in rows)}\n")  # fmt: skip
        print(markdown_table(["part", "median s", "max s", "median share"], table) + "\n")


if __name__ == "__main__":
    main()
