"""``rangeslam demo``: simulated rooms reconstructed from echoes, then small Fig. 3 and Fig. 5
runs; tables printed, plots written."""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from typing import Any

__all__ = ["DEMO_STEPS", "demo", "demo_step"]


@dataclass(frozen=True)
class DemoRoom:
    """One demo room's run: its name, the :class:`~rangeslam.app.experiments.RoomExperiment`,
    and how many wrong echo picks were injected."""

    name: str
    experiment: Any
    injected: int


#: The demo's steps, as its progress names them ("step 2 of 4: Fig. 3 ...").
DEMO_STEPS = (
    "rooms from echoes",
    "Fig. 3, zero-knowledge calibration (30 trials)",
    "Fig. 5, range-only SLAM, every method (15 trials)",
    "a SLAM estimate and the RIR matrix",
)


def demo_step(k: int) -> str:
    """The name of the demo's step ``k`` (1-based) with its place: 'step 2 of 4: Fig. 3 ...'."""
    return f"step {k} of {len(DEMO_STEPS)}: {DEMO_STEPS[k - 1]}"


def demo(args: argparse.Namespace) -> int:
    """``rangeslam demo``: Problem 1 on the demo rooms, then Fig. 3 and Fig. 5 in small; 0 when
    every room converged. Each step is named on standard error as it starts, and its progress
    shown there (a bar on a terminal, lines elsewhere); stdout is flushed before each step."""
    from rangeslam.app.bench_command import run_bench
    from rangeslam.app.progress import Heartbeat

    print(
        f"Problem 1 (paper, section 2): rooms from echoes with a known array of {args.mics} microphones, "
        f"{args.sources} loudspeaker(s), range noise {args.sigma * 1e3:g} mm, "
        f"{args.outliers * 100:g}% wrong echo picks, seed {args.seed}\n",
        flush=True,
    )
    _announce(1)
    with Heartbeat("demo", step=demo_step(1)):
        summaries = _demo_rooms(args)
    _print_room_summaries(summaries)
    print(
        "\nwall centre to estimate: distance from the centre of the true wall to the estimated "
        "plane, the error that matters for a map (the offset alone ignores the tilt)."
    )
    rooms_ok = all(r.experiment.result.converged for r in summaries)
    print(
        "\nFig. 3 (paper, section 3): zero-knowledge array calibration, a small run\n", flush=True
    )
    _announce(2)
    run_bench(
        "fig3", trials=10, seed=args.seed, out=args.out, sigmas=(0.0, 1e-3, 5e-3), label=_bar(2)
    )
    print(
        "\nFig. 5 (paper, section 4): range-only SLAM, every method on the same trials\n",
        flush=True,
    )
    _announce(3)
    run_bench(
        "compare",
        trials=5,
        seed=args.seed,
        out=args.out,
        sigmas=(1e-2,),
        steps=(5, 10, 20),
        bounds=(True,),
        label=_bar(3),
    )
    sys.stdout.flush()
    _announce(4)
    with Heartbeat("demo", step=demo_step(4)):
        demo_slam_example(args)
    print(f"\nplots written to {args.out}/")
    for room in summaries:
        res = room.experiment.result
        if not res.converged:
            print(f"rangeslam: {room.name}: not converged: {res.message}", file=sys.stderr)
    return 0 if rooms_ok else 1


def _announce(k: int) -> None:
    """Say on standard error that the demo's step ``k`` starts."""
    print(f"rangeslam: demo: {demo_step(k)} ...", file=sys.stderr, flush=True)


def _bar(k: int) -> str:
    """The progress label of the demo's benchmark step ``k``: 'demo 2/4, Fig. 3'."""
    return f"demo {k}/{len(DEMO_STEPS)}, {DEMO_STEPS[k - 1].split(',')[0]}"


def _demo_rooms(args: argparse.Namespace) -> list[DemoRoom]:
    """Each demo room reconstructed: its per-wall table printed, its plot written."""
    import numpy as np

    from rangeslam.app.experiments import demo_rooms, room_experiment
    from rangeslam.app.plotting import plot_room_reconstruction

    rng = np.random.default_rng(args.seed)
    print(
        "| room | wall | true offset [m] | estimated offset [m] | wall centre to estimate [mm] "
        "| normal error [deg] |"
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
        summaries.append(DemoRoom(name, exp, injected))
        plot_room_reconstruction(
            args.out / f"room_{name.replace(' ', '_')}.png",
            true_room=room,
            estimated_room=res.room,
            mics=exp.mics,
            true_sources=exp.sources,
            estimated_sources=res.sources,
            image_sources=res.image_sources,
            title=f"{name}: reconstruction from echoes ({args.mics} mics)",
            converged=res.converged,
        )
    return summaries


def _print_room_summaries(summaries: list[DemoRoom]) -> None:
    """One line per room: converged, loudspeaker errors, wrong picks injected and rejected."""
    print(
        "\n| room | converged | loudspeaker error [mm] | wrong picks injected | rejected | RMS residual [mm] |"
    )
    print("|---|---|---|---|---|---|")
    for room in summaries:
        exp = room.experiment
        res = exp.result
        print(
            f"| {room.name} | {res.converged} | {', '.join(f'{e * 1e3:.2f}' for e in exp.source_errors)} | "
            f"{room.injected} | {res.n_outliers} | {res.residual_rms * 1e3:.2f} |"
        )


def demo_slam_example(args: argparse.Namespace) -> None:
    """One Fig. 5 walk: the estimate with its GTSAM ellipses, and the walk's RIRs (Fig. 4C)."""
    import numpy as np

    from rangeslam.app.experiments import FIG5_ROOM_SIZE, slam_experiment
    from rangeslam.app.plotting import plot_rir_matrix, plot_slam_estimate
    from rangeslam.geometry.alignment import align
    from rangeslam.sim.rir import shoebox_rirs
    from rangeslam.sim.trajectories import lemniscate

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
        title="RIRs along the lemniscate (60 steps of 10 cm, reflections up to order 2; Fig. 4C)",
    )
