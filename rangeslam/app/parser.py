"""The argument parser of the ``rangeslam`` command: one function per subcommand's arguments."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rangeslam.app import arg_types
from rangeslam.app.bench_command import bench as bench_command
from rangeslam.app.defaults import (
    DEFAULT_METHODS,
    FIG3_SIGMAS,
    FIG5_SIGMAS,
    FIG5_STEPS,
    PLAZA_METHODS,
)
from rangeslam.app.demo_command import demo as demo_command
from rangeslam.app.run_command import run as run_command
from rangeslam.app.run_help import RUN_DESCRIPTION, RUN_EPILOG
from rangeslam.app.simulate_command import add_simulate_parser

__all__ = ["RUN_FS_LIMITS", "SPEED_LIMITS", "CliParser", "DefaultsHelpFormatter", "build_parser"]

#: ``bench --trials`` and ``bench xtdoa --subsets``: per cell (10**20 ran without end).
MAX_TRIALS = 100_000
#: ``bench --jobs``: processes (100000 ran without end).
MAX_JOBS = 64
#: ``bench plaza --trials`` (random starts of a method) and ``bench xtdoa --robust`` (minutes a run).
MAX_RUNS = 1000
#: ``run --fs``: sampling rates of recorded RIRs, Hz.
RUN_FS_LIMITS = (1000.0, 1_000_000.0)
#: ``run --c``: speed of sound, m/s (air at -100 to +500 degC is 220-440; water about 1500).
SPEED_LIMITS = (100.0, 2000.0)


class CliParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line and exit code 2, without the usage dump."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        # -v on every parser of the tree, so it is taken before or after the subcommand; a
        # parser that does not see it leaves the attribute alone (SUPPRESS), main reads False.
        self.add_argument(
            "-v",
            "--verbose",
            action="store_true",
            default=argparse.SUPPRESS,
            help="log each step and its time on standard error (anywhere on the line)",
        )

    def add_subparsers(self, **kwargs):
        """Subcommands, as argparse's; remembered so that a missing one prints the help."""
        self.commands = super().add_subparsers(**kwargs)
        return self.commands

    def error(self, message: str) -> None:
        """Print ``rangeslam: error: message`` and exit with code 2; a command missing (plain
        ``rangeslam``, ``rangeslam bench``) prints the help with the list of commands first."""
        if getattr(self, "commands", None) is not None and message.startswith(
            "the following arguments are required"
        ):
            self.print_help(sys.stderr)
            print(file=sys.stderr)
        self.exit(2, f"rangeslam: error: {message}\n")


class DefaultsHelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Help that shows each option's default, except the empty ones (None, False)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None or action.default is False:
            return action.help
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    """The ``rangeslam`` parser: ``demo``, ``bench``, ``simulate`` and ``run``, each with
    ``func`` to call."""
    parser = CliParser(
        prog="rangeslam",
        description="Rooms, arrays and trajectories from ranges (acoustic echoes, radio beacons). "
        "Exit codes: 0 converged, 1 not converged (the reason is printed), 2 bad input.",
    )
    parser.add_argument("--version", action="version", version=f"rangeslam {_version()}")
    sub = parser.add_subparsers(
        dest="command", required=True, parser_class=CliParser, metavar="COMMAND"
    )
    _add_demo(sub)
    _add_bench(sub)
    add_simulate_parser(sub)
    _add_run(sub)
    return parser


def _version() -> str:
    """The installed rangeslam's version."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("rangeslam")
    except PackageNotFoundError:
        return "unknown (not installed)"


def _add_demo(sub) -> None:
    """``rangeslam demo``: the simulated rooms, and small Fig. 3 and Fig. 5 runs."""
    demo = sub.add_parser(
        "demo",
        help="simulate rooms, reconstruct them from echoes, small Fig. 3 and Fig. 5; print and plot",
        description="Problem 1 on two simulated rooms (the paper's shoebox and a room with a cut "
        "corner and a sloping ceiling), then small Fig. 3 (zero-knowledge calibration) and Fig. 5 "
        "(range-only SLAM, every method) runs. About a minute on 2 cores. Exit 0 when every room "
        "converged.",
        formatter_class=DefaultsHelpFormatter,
    )
    demo.add_argument(
        "--out", type=arg_types.writable_dir, default="rangeslam-out", help="output folder"
    )
    demo.add_argument("--seed", type=arg_types.seed, default=0, help="random seed (0 to 2^63 - 1)")
    demo.add_argument(
        "--mics", type=arg_types.int_in(4, 64), default=8, metavar="M", help="microphones, 4 to 64"
    )
    demo.add_argument(
        "--sources",
        type=arg_types.int_in(1, 8),
        default=2,
        metavar="J",
        help="loudspeakers, 1 to 8",
    )
    demo.add_argument(
        "--sigma",
        type=arg_types.noise_level,
        default=1e-3,
        help="range noise std, metres (0 to 10)",
    )
    demo.add_argument(
        "--outliers",
        type=arg_types.fraction,
        default=0.05,
        help="fraction of echo picks made wrong",
    )
    demo.set_defaults(func=demo_command)


def _add_bench(sub) -> None:
    """``rangeslam bench fig3|fig5|compare|plaza|xtdoa|pyfg``: one subcommand per experiment."""
    bench = sub.add_parser(
        "bench",
        help="the paper's experiments (fig3, fig5), every SLAM method side by side (compare), "
        "the CMU Plaza radio data (plaza), unsynchronised microphones on real data (xtdoa)",
        description="Benchmarks: each writes CSV per trial, a JSON and Markdown summary and a "
        "plot to --out as it goes, and shows progress. Run 'rangeslam bench EXPERIMENT -h' for "
        "an experiment's options.",
    )
    experiments = bench.add_subparsers(
        dest="which", required=True, parser_class=CliParser, metavar="EXPERIMENT"
    )
    common = _bench_common()
    fig3 = experiments.add_parser(
        "fig3",
        parents=[common],
        help="zero-knowledge array calibration against the CRLB (paper's Fig. 3)",
        description="Fig. 3: 6 microphones in a 1 m cube and 6 sources (a loudspeaker and its 5 "
        "first-order images nearest the array), ranges between them with noise, the array "
        "calibrated with no known position (Problem 2); error against the oracle and the CRLB "
        "per noise level.",
        formatter_class=DefaultsHelpFormatter,
    )
    fig3.add_argument(
        "--sigmas",
        type=arg_types.noise_level,
        nargs="+",
        default=list(FIG3_SIGMAS),
        metavar="SIGMA",
        help="range noise levels, metres (0 to 10)",
    )
    for name, text in (
        (
            "fig5",
            "range-only SLAM on the lemniscate (paper's Fig. 5): EDM only, EDM + GTSAM, GTSAM",
        ),
        (
            "compare",
            "every SLAM method on the same trials: fig5's and the EKF with its RTS smoother",
        ),
    ):
        slam = experiments.add_parser(
            name,
            parents=[common],
            help=text,
            description=text + ".",
            formatter_class=DefaultsHelpFormatter,
        )
        _add_slam_bench_options(slam)
        if name == "compare":
            slam.add_argument(
                "--regimes",
                action="store_true",
                help="the regime map instead: lemniscate and random walks in random rooms, "
                "bounds or none, each sigma and M, and 2-D, 30%% missing and 5%% wrong picks; "
                "GTSAM's random starts (one, and best of k in EDM + GTSAM's time) beside "
                "(default steps: 4 5 6 8 10 20; --bounds and --placement do not apply)",
            )
    plaza = experiments.add_parser(
        "plaza",
        help="range-only SLAM on the CMU Plaza radio data shipped with GTSAM",
        description="Every method on a CMU Plaza data set (Djugash et al., JFR 2009; shipped with "
        "GTSAM): errors against the ground truth, cost against trajectory length. Plaza2 is the "
        "held-out set. A few minutes with the defaults.",
        formatter_class=DefaultsHelpFormatter,
    )
    _add_plaza_options(plaza)
    _add_xtdoa_bench(experiments)
    _add_pyfg_bench(experiments)


def _add_pyfg_bench(experiments) -> None:
    """``rangeslam bench pyfg FILES``: range-aided SLAM methods on PyFG files."""
    from rangeslam.app.pyfg_bench import PYFG_METHODS

    pyfg = experiments.add_parser(
        "pyfg",
        help="range-aided SLAM on PyFG files (CORA's benchmark problems)",
        description="Each method on each PyFG file: status, time and APE against the file's "
        "reference values (one rigid alignment of all robots). Seconds a file.",
        formatter_class=DefaultsHelpFormatter,
    )
    pyfg.add_argument("files", nargs="+", type=Path, metavar="FILE", help="PyFG files (.pyfg)")
    pyfg.add_argument(
        "--methods",
        nargs="+",
        choices=list(PYFG_METHODS),
        default=list(PYFG_METHODS),
        help="methods to run",
    )
    pyfg.add_argument(
        "--out", type=arg_types.writable_dir, default="rangeslam-bench", help="output folder"
    )
    pyfg.set_defaults(func=bench_command)


def _add_xtdoa_bench(experiments) -> None:
    """``rangeslam bench xtdoa``: the xtdoa real data, the authors' protocol."""
    xtdoa = experiments.add_parser(
        "xtdoa",
        help="unsynchronised microphones and unknown emission times on the xtdoa real data",
        description="The xtdoa data (El Badawy et al., arXiv 2102.03565): random subsets of K of "
        "the 23 clean events, microphone and event offsets unknown; mean microphone error after "
        "a similarity and a rigid alignment, time per solve. About 1 s a solve: the full run "
        "(200 subsets for each of 16 sizes) takes about an hour.",
        formatter_class=DefaultsHelpFormatter,
    )
    xtdoa.add_argument(
        "--data",
        default="xtdoa",
        metavar="PATH",
        help="the xtdoa directory: a path, or a name under $RANGESLAM_DATA (else under "
        "../shared/data)",
    )
    xtdoa.add_argument(
        "--subsets",
        type=arg_types.positive_int_to(MAX_TRIALS),
        default=200,
        help=f"random subsets per K, 1 to {MAX_TRIALS}",
    )
    xtdoa.add_argument(
        "--sizes",
        type=arg_types.int_in(6, 23),
        nargs="+",
        default=list(range(6, 22)),
        metavar="K",
        help="numbers of events K",
    )
    xtdoa.add_argument("--seed", type=arg_types.seed, default=0, help="random seed (0 to 2^63 - 1)")
    xtdoa.add_argument(
        "--robust",
        type=arg_types.positive_int_to(MAX_RUNS),
        default=None,
        metavar="RUNS",
        help=f"instead of the protocol: the robust run on all 65 events without the authors' "
        f"mask, RUNS (1 to {MAX_RUNS}) times (seeds --seed, --seed + 1, ...); minutes a run",
    )
    xtdoa.add_argument(
        "--out", type=arg_types.writable_dir, default="rangeslam-bench", help="output folder"
    )
    xtdoa.set_defaults(func=bench_command)


def _bench_common() -> argparse.ArgumentParser:
    """Options every simulated benchmark takes: trials, parallelism, and the run options."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--trials",
        type=arg_types.positive_int_to(MAX_TRIALS),
        default=50,
        help=f"trials per cell, 1 to {MAX_TRIALS}",
    )
    common.add_argument(
        "--jobs",
        type=arg_types.positive_int_to(MAX_JOBS),
        default=1,
        help=f"trials in parallel processes, 1 to {MAX_JOBS}",
    )
    common.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="submit the trials to this Dask distributed scheduler (needs rangeslam[dask])",
    )
    _add_bench_run_options(common)
    return common


def _add_bench_run_options(bench: argparse.ArgumentParser) -> None:
    """What every benchmark takes, simulated or Plaza: seed, output folder, TUM files."""
    bench.add_argument("--seed", type=arg_types.seed, default=0, help="random seed (0 to 2^63 - 1)")
    bench.add_argument(
        "--out", type=arg_types.writable_dir, default="rangeslam-bench", help="output folder"
    )
    bench.add_argument(
        "--tum", action="store_true", help="also write every trajectory in the TUM format (evo)"
    )
    bench.set_defaults(func=bench_command)


def _add_slam_bench_options(slam: argparse.ArgumentParser) -> None:
    """The options of ``bench fig5`` and ``bench compare``: noise, steps, bounds."""
    slam.add_argument(
        "--sigmas",
        type=arg_types.noise_level,
        nargs="+",
        default=list(FIG5_SIGMAS),
        metavar="SIGMA",
        help="range noise levels, metres (0 to 10)",
    )
    slam.add_argument(
        "--steps",
        type=arg_types.int_in(3, 10_000),
        nargs="+",
        default=list(FIG5_STEPS),
        metavar="M",
        help="numbers of steps M (at least 3)",
    )
    slam.add_argument(
        "--bounds",
        choices=("both", "with", "without"),
        default="both",
        help="+-20%% step bounds, none, or both",
    )
    slam.add_argument(
        "--placement",
        choices=("centred", "random"),
        default="random",
        help="the true step uniform in its step bounds (default: real odometry bounds are not "
        "centred on the truth) or bounds centred on the true steps (the paper's setting)",
    )


def _add_plaza_options(plaza: argparse.ArgumentParser) -> None:
    """The options of ``rangeslam bench plaza``: data set, methods, lengths, starts."""
    plaza.add_argument(
        "--dataset", choices=("Plaza1", "Plaza2"), default="Plaza1", help="which CMU Plaza data set"
    )
    plaza.add_argument(
        "--methods",
        nargs="+",
        choices=PLAZA_METHODS,
        default=list(DEFAULT_METHODS),
        metavar="METHOD",
        help="methods to run; any of " + ", ".join(repr(m) for m in PLAZA_METHODS),
    )
    plaza.add_argument(
        "--trials",
        type=arg_types.positive_int_to(MAX_RUNS),
        default=3,
        help=f"random starts of each method that has them, 1 to {MAX_RUNS} (the others run once)",
    )
    plaza.add_argument(
        "--lengths",
        type=arg_types.int_in(0, 10**7),
        nargs="*",
        default=[250, 500, 1000, 0],
        metavar="N",
        help="also run the EDM pipelines on the first N poses (0: all); none to skip",
    )
    _add_bench_run_options(plaza)


def _add_run(sub) -> None:
    """``rangeslam run``: the room or the trajectory from the user's RIRs."""
    run = sub.add_parser(
        "run",
        help="the room (known microphones) or the trajectory (step bounds) from your RIRs; a "
        "robot's path from a beacon log",
        description=RUN_DESCRIPTION,
        epilog=RUN_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    run.add_argument(
        "rirs",
        nargs="+",
        type=Path,
        metavar="RIRS",
        help=".npz, .sofa, .wav or directory, one or several (see above); or a beacon log "
        "(.csv); or a PyFG file (.pyfg)",
    )
    run.add_argument(
        "--fs",
        type=arg_types.float_in(*RUN_FS_LIMITS, " Hz"),
        help=f"sampling rate, Hz, {RUN_FS_LIMITS[0]:g} to {RUN_FS_LIMITS[1]:g} (for an npz "
        "without fs; a check for the files that state one)",
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
        type=arg_types.float_in(*SPEED_LIMITS, " m/s"),
        help=f"speed of sound, m/s, {SPEED_LIMITS[0]:g} to {SPEED_LIMITS[1]:g} (default: the "
        "npz's c, else 343); array mode starts from it and estimates c (see --fixed-c)",
    )
    run.add_argument("--dim", type=int, choices=(2, 3), default=3, help="2 or 3 (walks; default 3)")
    run.add_argument(
        "--seed", type=arg_types.seed, default=0, help="random seed (0 to 2^63 - 1; default 0)"
    )
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
        "--out",
        type=arg_types.writable_dir,
        default="rangeslam-run",
        help="output folder (default rangeslam-run): a run that gets as far as writing first "
        "deletes an earlier run's files there (run_summary.*, run_*.csv, run_*.png), so the "
        "folder holds one run; other files are left alone",
    )
    _add_run_more(run)
    run.set_defaults(func=run_command)


def _add_run_more(run) -> None:
    """``run --fixed-c``, ``--excitation``, ``--unknown-emission``."""
    _add_run_speed(run)
    _add_run_recordings(run)


def _add_run_recordings(run) -> None:
    """``run --excitation`` and ``--unknown-emission``."""
    run.add_argument(
        "--excitation",
        type=Path,
        metavar="FILE",
        help="the RIRS files are recordings of this signal (a mono .wav at their rate, or .npy, "
        ".csv): deconvolved into RIRs first; an npz may hold 'recordings' and 'excitation' "
        "instead. Sample 0 of a recording is the start of the excitation (see --unknown-emission)",
    )
    run.add_argument(
        "--unknown-emission",
        action="store_true",
        help="array mode: sample 0 is not the emission; each loudspeaker's delay is estimated "
        "(from the direct paths, checked against the echoes) and reported +- its std; c is "
        "then kept as given",
    )


def _add_run_speed(run) -> None:
    """``run --fixed-c``."""
    run.add_argument(
        "--fixed-c",
        action="store_true",
        help="keep c as given; by default array mode (not --measured) "
        "estimates it with the loudspeaker from the direct paths and reports it +- its std",
    )
