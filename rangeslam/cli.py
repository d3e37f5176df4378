"""The ``rangeslam`` command. It parses, calls library functions and writes; no math lives here."""

from __future__ import annotations

import argparse
import logging
import sys
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
    print(f"\nplots written to {args.out}/")
    return 0 if all(exp.result.converged for _, exp, _ in summaries) else 1


def build_parser() -> argparse.ArgumentParser:
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


if __name__ == "__main__":
    raise SystemExit(main())
