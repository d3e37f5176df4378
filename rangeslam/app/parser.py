"""The argument parser of the ``rangeslam`` command: one function per subcommand's arguments."""

from __future__ import annotations

import argparse
from pathlib import Path

from rangeslam.app import arg_types
from rangeslam.app.bench_command import bench as bench_command
from rangeslam.app.demo_command import demo as demo_command
from rangeslam.app.run_command import run as run_command

__all__ = ["CliParser", "build_parser"]


class CliParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line and exit code 2, without the usage dump."""

    def error(self, message: str) -> None:
        """Print ``rangeslam: error: message`` and exit with code 2."""
        self.exit(2, f"rangeslam: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``rangeslam`` parser: ``demo``, ``bench`` and ``run``, each with ``func`` to call."""
    parser = CliParser(prog="rangeslam", description="Rooms, arrays and trajectories from ranges.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=CliParser)
    _add_demo(sub)
    _add_bench(sub)
    _add_run(sub)
    return parser


def _add_demo(sub) -> None:
    """``rangeslam demo``: the simulated rooms, and small Fig. 3 and Fig. 5 runs."""
    demo = sub.add_parser(
        "demo", help="simulate rooms, reconstruct them from echoes, print and plot"
    )
    demo.add_argument(
        "--out", type=arg_types.writable_dir, default="rangeslam-out", help="output directory"
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
        type=arg_types.non_negative,
        default=1e-3,
        help="range noise std in metres (default 0.001)",
    )
    demo.add_argument(
        "--outliers",
        type=arg_types.fraction,
        default=0.05,
        help="fraction of echo picks made wrong (default 0.05)",
    )
    demo.set_defaults(func=demo_command)


def _add_bench(sub) -> None:
    """``rangeslam bench``: the paper's experiments and the Plaza bench."""
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
        type=arg_types.positive_int,
        default=50,
        help="trials per cell (50); plaza: random starts of the methods that have them",
    )
    bench.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    bench.add_argument(
        "--jobs",
        type=arg_types.positive_int,
        default=1,
        help="trials in parallel processes (default 1)",
    )
    bench.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="submit the trials to this Dask distributed scheduler (needs rangeslam[dask])",
    )
    bench.add_argument(
        "--out", type=arg_types.writable_dir, default="rangeslam-bench", help="output directory"
    )
    bench.add_argument(
        "--sigmas", type=arg_types.non_negative, nargs="+", help="range noise levels in metres"
    )
    bench.add_argument(
        "--steps", type=arg_types.positive_int, nargs="+", help="numbers of steps M (fig5, compare)"
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
    _add_plaza_options(bench)
    bench.set_defaults(func=bench_command)


def _add_plaza_options(bench: argparse.ArgumentParser) -> None:
    """The options of ``rangeslam bench plaza``: data set, methods, lengths."""
    from rangeslam.app.plaza_bench import DEFAULT_METHODS, PLAZA_METHODS

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


def _add_run(sub) -> None:
    """``rangeslam run``: the room or the trajectory from the user's RIRs."""
    run = sub.add_parser(
        "run",
        help="the room (known microphones) or the trajectory (step bounds) from your RIRs",
        description="RIRs of one loudspeaker: an .npz (rirs (M, L), fs; optionally mics, "
        "step_bounds, c, and ground truth source / room_size / trajectory), one multichannel WAV, "
        "a directory of mono WAVs (natural order of names) or several mono WAVs (in the order "
        "given). With microphone positions: the room (walls, loudspeaker); with step bounds of a "
        "moving microphone: its trajectory and the landmarks. Exit 0 converged, 1 not converged, "
        "2 bad input.",
    )
    run.add_argument("rirs", nargs="+", type=Path, metavar="RIRS", help=".npz, .wav or directory")
    run.add_argument(
        "--fs",
        type=arg_types.positive_float,
        help="sampling rate, Hz (for an npz without fs; a check for WAVs)",
    )
    known = run.add_mutually_exclusive_group()
    known.add_argument(
        "--mics", type=Path, metavar="FILE", help="microphone positions (M, 3): .npy, .csv, .txt"
    )
    known.add_argument(
        "--mics-from-npz", action="store_true", help="use the npz's mics (when it has both)"
    )
    known.add_argument(
        "--step-bounds",
        type=Path,
        metavar="FILE",
        help="lower and upper bound of each step, metres: (2, M - 1) or (M - 1, 2), .npy/.csv/.txt",
    )
    known.add_argument(
        "--step-bounds-from-npz", action="store_true", help="use the npz's step_bounds"
    )
    run.add_argument(
        "--keyframes",
        type=Path,
        metavar="FILE",
        help="walks: the RIRs (0-based indices) that are steps, when more RIRs than steps were "
        "recorded (default: the npz's keyframes, else every RIR)",
    )
    run.add_argument(
        "--c",
        type=arg_types.positive_float,
        help="speed of sound, m/s (default: the npz's c, else 343)",
    )
    run.add_argument("--dim", type=int, choices=(2, 3), default=3, help="2 or 3 (walks; default 3)")
    run.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    run.add_argument(
        "--measured",
        action="store_true",
        help="preset for measured RIRs (rangeslam.acoustics.pipeline.MEASURED_RIR_OPTIONS: matched filter "
        "with the direct sound, echoes in the first 30 ms, 4 cm labelling tolerance)",
    )
    run.add_argument(
        "--use-clipped",
        action="store_true",
        help="use clipped RIRs (default: leave them out, like silent ones, with a warning)",
    )
    run.add_argument(
        "--out", type=arg_types.writable_dir, default="rangeslam-run", help="output directory"
    )
    run.set_defaults(func=run_command)
