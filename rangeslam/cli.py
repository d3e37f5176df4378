"""The ``rangeslam`` command. It parses, calls library functions and writes; no math lives here."""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

__all__ = ["main"]


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line and exit code 2, no usage dump
        self.exit(2, f"rangeslam: error: {message}\n")


def _writable_dir(text: str) -> Path:
    path = Path(text)
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".rangeslam-write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise argparse.ArgumentTypeError(f"cannot write to --out {text}: {exc.strerror}") from exc
    return path


def _non_negative(text: str) -> float:
    value = float(text)
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"must be >= 0; got {text}")
    return value


def _fraction(text: str) -> float:
    value = float(text)
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"must be in [0, 1]; got {text}")
    return value


def _demo(args: argparse.Namespace) -> int:
    import numpy as np

    from .experiments import demo_rooms, room_experiment
    from .plotting import plot_room_reconstruction

    rng = np.random.default_rng(args.seed)
    print(
        f"Problem 1 (paper, section 2): rooms from echoes with a known array of {args.mics} microphones, "
        f"{args.sources} loudspeaker(s), range noise {args.sigma * 1e3:g} mm, "
        f"{args.outliers * 100:g}% wrong echo picks, seed {args.seed}\n"
    )
    print(
        "| room | wall | true offset [m] | estimated [m] | offset error [mm] | normal error [deg] |"
    )
    print("|---|---|---|---|---|---|")
    summaries = []
    for name, room in demo_rooms().items():
        exp = room_experiment(
            room,
            n_mics=args.mics,
            n_sources=args.sources,
            sigma=args.sigma,
            outlier_fraction=args.outliers,
            rng=rng,
        )
        res = exp.result
        for k in range(room.n_walls):
            print(
                f"| {name} | {k} | {room.offsets[k]:.4f} | {res.wall_offsets[k]:.4f} | "
                f"{exp.offset_errors[k] * 1e3:.2f} | {exp.normal_errors_deg[k]:.3f} |"
            )
        injected = int(sum(o.sum() for o in exp.outliers))
        summaries.append((name, exp, injected))
        fname = args.out / f"room_{name.replace(' ', '_')}.png"
        plot_room_reconstruction(
            fname,
            true_room=room,
            estimated_room=res.room,
            mics=exp.mics,
            true_sources=exp.sources,
            estimated_sources=res.sources,
            image_sources=res.image_sources,
            title=f"{name}: reconstruction from echoes ({args.mics} mics)",
        )
    print(
        "\n| room | converged | loudspeaker error [mm] | wrong picks injected | rejected | RMS residual [mm] |"
    )
    print("|---|---|---|---|---|---|")
    for name, exp, injected in summaries:
        res = exp.result
        print(
            f"| {name} | {res.converged} | {', '.join(f'{e * 1e3:.2f}' for e in exp.source_errors)} | "
            f"{injected} | {res.n_outliers} | {res.residual_rms * 1e3:.2f} |"
        )
    rooms_ok = all(exp.result.converged for _, exp, _ in summaries)
    print("\nFig. 3 (paper, section 3): zero-knowledge array calibration, a small run\n")
    _run_bench("fig3", trials=10, seed=args.seed, out=args.out, sigmas=(0.0, 1e-3, 5e-3))
    print("\nFig. 5 (paper, section 4): range-only SLAM, every method on the same trials\n")
    _run_bench(
        "compare",
        trials=5,
        seed=args.seed,
        out=args.out,
        sigmas=(1e-2,),
        steps=(5, 10, 20),
        bounds=(True,),
    )
    _demo_slam_example(args)
    print(f"\nplots written to {args.out}/")
    return 0 if rooms_ok else 1


def _demo_slam_example(args: argparse.Namespace) -> None:
    """One Fig. 5 walk: the estimate with its GTSAM ellipses, and the walk's RIRs (Fig. 4C)."""
    import numpy as np

    from .alignment import align
    from .experiments import FIG5_ROOM_SIZE, slam_experiment
    from .plotting import plot_rir_matrix, plot_slam_estimate
    from .rir import shoebox_rirs
    from .trajectories import lemniscate

    rng = np.random.default_rng(args.seed)
    e = slam_experiment(15, 1e-2, True, rng)
    a = align(e.result.receivers, e.trajectory, reflection=True)
    plot_slam_estimate(
        args.out / "slam_estimate.png",
        trajectory=e.trajectory,
        landmarks=e.landmarks,
        receivers=e.result.receivers,
        sources=e.result.sources,
        receiver_cov=e.result.receiver_cov,
        source_cov=e.result.source_cov,
        rotation=a.rotation,
        translation=a.translation,
        title=f"EDM + GTSAM, 15 steps, sigma 1 cm, +-20% bounds: trajectory error "
        f"{e.error * 100:.1f} cm",
    )
    walk = lemniscate(60, step=0.1, phase=0.0)
    rirs = shoebox_rirs(FIG5_ROOM_SIZE, e.landmarks[0], walk, fs=16000, max_order=2)
    plot_rir_matrix(
        args.out / "rir_matrix.png",
        rirs[:, : int(0.04 * 16000)],
        16000,
        title="RIRs along the lemniscate (60 steps of 10 cm; Fig. 4C)",
    )


def _run_bench(
    which: str,
    *,
    trials: int,
    seed: int,
    out: Path,
    jobs: int = 1,
    scheduler: str | None = None,
    sigmas=None,
    steps=None,
    bounds=(True, False),
    placement: str = "centred",
    tum: bool = False,
) -> int:
    """Plan, run and write a benchmark: CSV per trial, timings, JSON and Markdown summaries, a
    plot, optionally TUM trajectories. Prints the Markdown table."""
    import time

    from . import benchmarking as bm
    from .plotting import plot_fig3, plot_fig5

    plan = bm.plan(
        which, trials, seed, sigmas=sigmas, steps=steps, bounds=bounds, placement=placement
    )
    t0 = time.perf_counter()
    outcomes = bm.run_trials(
        plan, jobs=jobs, scheduler=scheduler, keep_trajectories=tum, progress=sys.stderr.isatty()
    )
    wall = time.perf_counter() - t0
    rows = [o.row for o in outcomes]
    seconds = [o.seconds for o in outcomes]
    written = [bm.write_csv(out / f"{which}_trials.csv", rows)]
    written.append(
        bm.write_csv(
            out / f"{which}_timings.csv",
            [
                {"cell": r["cell"], "trial": r["trial"], **t}
                for r, t in zip(rows, seconds, strict=True)
            ],
        )
    )
    header, table, records = bm.summary_table(which, rows, seconds)
    text = bm.markdown(header, table)
    (out / f"{which}_summary.md").write_text(text + "\n")
    failed = sum(r["status"] != "ok" for r in rows)
    written.append(
        bm.write_summary(
            out / f"{which}_summary.json",
            bench=which,
            seed=seed,
            trials_per_cell=trials,
            jobs=jobs,
            scheduler=scheduler,
            failed_trials=failed,
            wall_seconds=wall,
            versions=bm.versions(),
            cells=records,
        )
    )
    if which == "fig3":
        written.append(plot_fig3(out / "fig3.png", rows))
    else:
        keys = [m for m in bm.SLAM_METHODS if which == "compare" or not m.startswith("ekf")]
        names = {m: bm.METHOD_NAMES[m] for m in keys}
        written.append(plot_fig5(out / f"{which}.png", rows, names))
    if tum:
        folder = out / "tum"
        folder.mkdir(exist_ok=True)
        for o in outcomes:
            for name, x in (o.trajectories or {}).items():
                bm.write_tum(
                    folder / f"{which}_cell{o.row['cell']}_trial{o.row['trial']}_{name}.tum", x
                )
        written.append(folder)
    print(text)
    print(
        f"\n{len(rows)} trials ({failed} failed) in {wall:.1f} s; seed {seed}; written: "
        + ", ".join(str(p) for p in written)
    )
    return 1 if failed == len(rows) else 0


def _run_plaza_bench(args: argparse.Namespace) -> int:
    """Every method on a Plaza data set, the cost against length, a plot; CSV, JSON, Markdown."""
    from . import benchmarking as bm
    from . import plaza_bench as pb
    from .datasets import plaza
    from .plotting import plot_plaza

    dataset = plaza(args.dataset)
    out = args.out
    t0 = time.perf_counter()
    kept: dict = {}
    rows = pb.method_rows(
        dataset, trials=args.trials, seed=args.seed, methods=args.methods, keep=kept
    )
    lengths = pb.length_rows(dataset, args.lengths, seed=args.seed) if args.lengths else []
    wall = time.perf_counter() - t0
    stem = f"plaza_{dataset.name}"
    written = [bm.write_csv(out / f"{stem}_methods.csv", rows)]
    if lengths:
        written.append(bm.write_csv(out / f"{stem}_lengths.csv", lengths))
    text = f"## {dataset.name}: methods\n\n" + bm.markdown(*pb.methods_table(rows))
    if lengths:
        text += "\n\n## Cost against trajectory length\n\n" + bm.markdown(
            *pb.lengths_table(lengths)
        )
    (out / f"{stem}_summary.md").write_text(text + "\n")
    written.append(
        bm.write_summary(
            out / f"{stem}_summary.json",
            bench="plaza",
            dataset=dataset.name,
            citation=dataset.citation,
            seed=args.seed,
            trials=args.trials,
            wall_seconds=wall,
            versions=bm.versions(),
            methods=rows,
            lengths=lengths,
        )
    )
    evaluations = {name: pb.evaluate(res, dataset) for name, res in kept.items()}
    written.append(plot_plaza(out / f"{stem}.png", dataset, kept, evaluations))
    if args.tum:
        folder = out / "tum"
        folder.mkdir(exist_ok=True)
        truth = dataset.truth_at(dataset.pose_time)
        bm.write_tum(folder / f"{stem}_truth.tum", truth, times=dataset.pose_time)
        for name, res in kept.items():
            bm.write_tum(
                folder / f"{stem}_{name.replace(' ', '_').replace('+', '_')}.tum",
                res.poses[:, :2],
                times=res.pose_time,
            )
        written.append(folder)
    print(text)
    failed = sum(r["status"] != "ok" for r in rows)
    print(
        f"\n{len(rows)} runs ({failed} failed) in {wall:.1f} s; seed {args.seed}; written: "
        + ", ".join(str(p) for p in written)
    )
    return 1 if failed == len(rows) else 0


def _bench(args: argparse.Namespace) -> int:
    from .benchmarking import BOUND_SETTINGS

    if args.which == "plaza":
        return _run_plaza_bench(args)

    bounds = BOUND_SETTINGS[args.bounds]
    return _run_bench(
        args.which,
        trials=args.trials,
        seed=args.seed,
        out=args.out,
        jobs=args.jobs,
        scheduler=args.scheduler,
        sigmas=args.sigmas,
        steps=args.steps,
        bounds=bounds,
        placement=args.placement,
        tum=args.tum,
    )


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive integer; got {text}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer; got {text}")
    return value


def build_parser() -> argparse.ArgumentParser:
    from .plaza_bench import DEFAULT_METHODS, PLAZA_METHODS

    parser = _Parser(prog="rangeslam", description="Rooms, arrays and trajectories from ranges.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    demo = sub.add_parser(
        "demo", help="simulate rooms, reconstruct them from echoes, print and plot"
    )
    demo.add_argument(
        "--out", type=_writable_dir, default=Path("rangeslam-out"), help="output directory"
    )
    demo.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    demo.add_argument(
        "--mics",
        type=int,
        default=8,
        choices=range(4, 65),
        metavar="M",
        help="number of microphones, 4..64 (default 8)",
    )
    demo.add_argument(
        "--sources",
        type=int,
        default=2,
        choices=range(1, 9),
        metavar="J",
        help="number of loudspeakers, 1..8 (default 2)",
    )
    demo.add_argument(
        "--sigma",
        type=_non_negative,
        default=1e-3,
        help="range noise std in metres (default 0.001)",
    )
    demo.add_argument(
        "--outliers",
        type=_fraction,
        default=0.05,
        help="fraction of echo picks made wrong (default 0.05)",
    )
    demo.set_defaults(func=_demo)

    bench = sub.add_parser(
        "bench", help="run the paper's experiments: fig3, fig5, or every SLAM method (compare)"
    )
    bench.add_argument(
        "which",
        choices=("fig3", "fig5", "compare", "plaza"),
        help="what to run (plaza: range-only SLAM on the CMU Plaza radio data)",
    )
    bench.add_argument(
        "--trials",
        type=_positive_int,
        default=50,
        help="trials per cell (50); plaza: random starts of the methods that have them",
    )
    bench.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    bench.add_argument(
        "--jobs", type=_positive_int, default=1, help="trials in parallel processes (default 1)"
    )
    bench.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="submit the trials to this Dask distributed scheduler (needs rangeslam[dask])",
    )
    bench.add_argument(
        "--out", type=_writable_dir, default=Path("rangeslam-bench"), help="output directory"
    )
    bench.add_argument(
        "--sigmas", type=_non_negative, nargs="+", help="range noise levels in metres"
    )
    bench.add_argument(
        "--steps", type=_positive_int, nargs="+", help="numbers of steps M (fig5, compare)"
    )
    bench.add_argument(
        "--bounds",
        choices=("both", "with", "without"),
        default="both",
        help="+-20%% step bounds, none, or both (fig5, compare)",
    )
    bench.add_argument(
        "--placement",
        choices=("centred", "random"),
        default="centred",
        help="step bounds centred on the true steps (the paper) or the true step uniform in them",
    )
    bench.add_argument(
        "--tum", action="store_true", help="also write every trajectory in the TUM format (evo)"
    )
    bench.add_argument(
        "--dataset",
        choices=("Plaza1", "Plaza2"),
        default="Plaza1",
        help="plaza: which CMU Plaza data set (default Plaza1)",
    )
    bench.add_argument(
        "--methods",
        nargs="+",
        choices=PLAZA_METHODS,
        default=list(DEFAULT_METHODS),
        metavar="METHOD",
        help="plaza: methods to run (default: all but 'isam2 random beacons'); one of "
        + ", ".join(repr(m) for m in PLAZA_METHODS),
    )
    bench.add_argument(
        "--lengths",
        type=int,
        nargs="*",
        default=[250, 500, 1000, 2000, 0],
        metavar="N",
        help="plaza: also run the EDM pipelines on the first N poses (0: all); none to skip",
    )
    bench.set_defaults(func=_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s"
    )
    from .errors import RangeSlamError

    try:
        return int(args.func(args))
    except RangeSlamError as exc:
        print(f"rangeslam: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # an output that cannot be written: one line, no traceback
        print(f"rangeslam: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
