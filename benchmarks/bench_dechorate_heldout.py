"""Held-out dEchorate-style calibration: new loudspeakers with simulated real-style pick errors.

    python benchmarks/bench_dechorate_heldout.py [--scenes 20] [--seed 0] [--loudspeakers 2 4]
        [--data dechorate] [--no-real] [--dump results.pkl]

The 30 dEchorate microphones stay where they are; each scene draws L new loudspeakers in the
dEchorate room (at least 0.5 m from the walls and every mic) and their direct + six first-order
echo ranges with the pick errors of :mod:`rangeslam.sim.echo_picks` (per-pick noise, biases per
(column, array), phantom columns heard by whole arrays, rare gross errors), calibrated on the two
real loudspeakers. ``calibrate(ranges, dim=3, rng=seed)`` runs with its defaults (robust="auto",
noise unknown). Microphone error: distance to the true position after the best rigid motion
(with reflection) of all 30. "Right": median <= 3 cm and every mic <= 10 cm; "converged-wrong"
is CONVERGED but not right. The real configurations (loudspeaker 0, 1, 0+1) run once first.
Scene ``seed + i`` with L loudspeakers holds the first loudspeakers of the same scene with more.
"""

from __future__ import annotations

import argparse
import pickle
import sys
from pathlib import Path

import numpy as np
from _common import machine, markdown_table, timed

from rangeslam import align, calibrate
from rangeslam.datasets import load_dechorate
from rangeslam.sim.echo_picks import CLEAN, simulate_loudspeakers
from rangeslam.status import Status

#: A calibration is "right" when the median mic error is at most MEDIAN_OK and the worst MAX_OK.
MEDIAN_OK, MAX_OK = 0.03, 0.10
#: A pick counts as wrong (for the dropped-range tallies) when it is this far off, metres.
WRONG_PICK = 0.03


def run_case(name, seed, n_ls, ranges, truth, true_ranges=None, kind=None):
    """One defaults calibration; a dict of the numbers of the table and what the analysis needs."""
    out, dt = timed(calibrate, ranges, dim=3, rng=seed)
    err = align(out.receivers, truth, reflection=True).errors
    dropped = out.observed & ~out.inliers
    case = {
        "name": name,
        "seed": seed,
        "L": n_ls,
        "status": out.status.name,
        "converged": bool(out.status is Status.CONVERGED),
        "median": float(np.median(err)),
        "max": float(err.max()),
        "errors": err,
        "time": dt,
        "dropped": int(dropped.sum()),
        "inliers": np.asarray(out.inliers),
        "residual_rms": out.residual_rms,
        "message": out.message,
        "ranges": ranges,
        "truth": truth,
        "true_ranges": true_ranges,
        "kind": kind,
        "receivers": np.asarray(out.receivers),
        "sources": np.asarray(out.sources),
    }
    case["right"] = case["median"] <= MEDIAN_OK and case["max"] <= MAX_OK
    if true_ranges is not None:
        wrong = np.abs(ranges - true_ranges) > WRONG_PICK
        case["wrong_picks"] = int(wrong.sum())
        case["wrong_dropped"] = int((wrong & dropped).sum())
    return case


def row(c) -> list[object]:
    picks = f"{c['wrong_dropped']}/{c['wrong_picks']}" if "wrong_picks" in c else "-"
    verdict = ("right" if c["right"] else "WRONG") if c["converged"] else "-"
    return [
        c["name"],
        c["seed"],
        c["L"],
        c["status"],
        f"{c['median'] * 100:.2f}",
        f"{c['max'] * 100:.2f}",
        f"{c['dropped']}/{c['ranges'].size}",
        picks,
        verdict,
        f"{c['time']:.1f}",
    ]


HEADER = [
    "scene",
    "seed",
    "L",
    "status",
    "median mic error [cm]",
    "worst mic [cm]",
    "ranges dropped",
    "wrong picks (>3 cm) dropped",
    "converged answer",
    "time [s]",
]


def summary(cases) -> str:
    lines = []
    for n_ls in sorted({c["L"] for c in cases if c["name"] == "sim"}):
        sel = [c for c in cases if c["name"] == "sim" and c["L"] == n_ls]
        conv = [c for c in sel if c["converged"]]
        counts = {
            "converged-right": sum(c["right"] for c in conv),
            "converged-wrong": sum(not c["right"] for c in conv),
            "not-converged-but-right": sum(c["right"] for c in sel if not c["converged"]),
            "not-converged-and-wrong": sum(not c["right"] for c in sel if not c["converged"]),
        }
        statuses: dict[str, int] = {}
        for c in sel:
            statuses[c["status"]] = statuses.get(c["status"], 0) + 1
        med = np.median([c["median"] for c in sel]) * 100
        times = [c["time"] for c in sel]
        lines.append(
            f"- L = {n_ls}, {len(sel)} scenes: "
            + ", ".join(f"{k} {v}" for k, v in counts.items())
            + f"; statuses {statuses}; median of median errors {med:.2f} cm; "
            f"time median {np.median(times):.1f} s, max {max(times):.1f} s"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--data",
        default="dechorate",
        help="a path, or a name under $RANGESLAM_DATA (else ../shared/data)",
    )
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--loudspeakers", type=int, nargs="+", default=[2, 4])
    ap.add_argument("--no-real", action="store_true", help="skip the real configurations")
    ap.add_argument("--dump", type=Path, help="pickle every case (inputs, answer) to this file")
    args = ap.parse_args()
    data = load_dechorate(args.data)
    cases = []

    def record(case) -> None:
        cases.append(case)
        print("| " + " | ".join(str(v) for v in row(case)) + " |", file=sys.stderr, flush=True)
        if args.dump:
            with args.dump.open("wb") as fh:
                pickle.dump(cases, fh)

    if not args.no_real:
        for label, blocks in (("real 0", [0]), ("real 1", [1]), ("real 0+1", [0, 1])):
            ranges = np.hstack([data.ranges(s) for s in blocks])
            true = np.hstack(
                [
                    np.linalg.norm(
                        data.mics[:, None]
                        - np.vstack(
                            [
                                data.sources[s][None],
                                data.room.image_sources(data.sources[s], 1).positions,
                            ]
                        )[None],
                        axis=2,
                    )
                    for s in blocks
                ]
            )
            record(run_case(label, 0, len(blocks), ranges, data.mics, true))
    for n_ls in args.loudspeakers:
        for i in range(args.scenes):
            seed = args.seed + i
            picks = simulate_loudspeakers(data.mics, data.mic_array, data.room_size, n_ls, seed)
            kind = picks.kind
            record(run_case("sim", seed, n_ls, picks.ranges, data.mics, picks.true_ranges, kind))
    print(f"## dEchorate held-out calibration, defaults, 30 microphones ({machine()})\n")
    print(markdown_table(HEADER, [row(c) for c in cases]))
    print()
    print(summary(cases))
    real_clean = [c for c in cases if c["kind"] is not None]
    if real_clean:
        n_clean = sum(int((c["kind"] == CLEAN).sum()) for c in real_clean)
        print(f"\n(simulated picks: {n_clean} of {sum(c['kind'].size for c in real_clean)} clean)")


if __name__ == "__main__":
    main()
