"""``rangeslam simulate room|walk``: write an .npz of simulated RIRs with their ground truth, the
file ``rangeslam run`` reads, so the path from recordings to a map can be tried in two commands.

The recordings come from :mod:`rangeslam.sim.recordings`; this module reads the flags, writes
the file, and prints what it wrote and the ``rangeslam run`` command to try next. Exit 0 written,
2 bad input.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from rangeslam.app import arg_types

__all__ = ["add_simulate_parser", "simulate_room", "simulate_walk"]

#: ``--room`` choices: the rooms of ``rangeslam demo`` (:func:`rangeslam.app.experiments.demo_rooms`).
ROOMS = {"shoebox": "shoebox", "cut-corner": "cut corner"}

#: --fs: the limits rangeslam.sim.rir checks (MIN_SIM_FS, MAX_SIM_FS; tests/test_cli_limits.py
#: checks they agree), here so that --help imports no numpy.
FS_LIMITS = (1000, 1_000_000)
#: --order: below the library's MAX_SIM_ORDER (30), for time: ``simulate room`` took 9.7 s at
#: order 8, 31 s at 12 and 250 s at 16 (30 did not finish in 300 s) on a busy 2-core machine.
MAX_ORDER = 12
#: --size: each side of a simulated shoebox, metres.
SIZE_LIMITS = (0.5, 100.0)
#: --mics of ``simulate room``.
MAX_MICS = 256
#: --steps and --rirs-per-step of ``simulate walk``, and the walk's RIRs, (M - 1) K + 1, at most
#: MAX_WALK_RIRS: 1000 steps of 8 RIRs at 16 kHz took 21 s and 0.4 GB; 100000 steps ran
#: pyroomacoustics out of memory.
MAX_STEPS = 1000
MAX_RIRS_PER_STEP = 64
MAX_WALK_RIRS = 10_000
#: --mics of ``simulate room`` by default: one loudspeaker, and a session of several. The cut
#: corner's wall (1.1 m wide) reflects a loudspeaker only to the microphones whose specular point
#: falls on it: over 2000 random scenes of two loudspeakers (margin 0.5 m) its echoes reach 6
#: microphone-loudspeaker pairs or more (a wall has 3 unknowns) in 82% of scenes with 8
#: microphones, 95% with 12, 98% with 16 (``python benchmarks/bench_run_sessions.py --what
#: visibility --seed 12345``; benchmarks/README.md, "rangeslam run on simulated sessions").
ONE_MICS = 8
SESSION_MICS = 12
#: --sources of ``simulate room``: one file per loudspeaker.
MAX_SOURCES = 8
#: --noise: white noise std as a fraction of the largest sample.
MAX_NOISE = 100.0
#: --delay of ``simulate room``: seconds of recording before the emission, at most.
MAX_DELAY = 1.0


def _side(text: str) -> float:
    """A shoebox side in metres, in SIZE_LIMITS."""
    value = arg_types.positive_float(text)
    low, high = SIZE_LIMITS
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(
            f"must be from {low:g} to {high:g} m; got {arg_types.shown(text)}"
        )
    return value


def _coordinate(text: str) -> float:
    """A finite coordinate in metres (whether it is in the room is checked with the room)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"must be a number of metres; got {arg_types.shown(text)}"
        ) from None
    if not abs(value) < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number; got {arg_types.shown(text)}")
    return value


def _absorption(text: str) -> float:
    """A float in (0, 1]."""
    value = arg_types.fraction(text)
    if value == 0:
        raise argparse.ArgumentTypeError(f"must be in (0, 1]; got {arg_types.shown(text)}")
    return value


def _bound(text: str) -> float:
    """A float in [0, 1)."""
    value = arg_types.fraction(text)
    if value >= 1:
        raise argparse.ArgumentTypeError(f"must be in [0, 1); got {arg_types.shown(text)}")
    return value


def add_simulate_parser(sub) -> None:
    """Add ``simulate`` with its subcommands ``room`` and ``walk`` to the subparsers ``sub`` of
    the ``rangeslam`` parser; each sets ``func`` (args -> exit code)."""
    from rangeslam.app.parser import DefaultsHelpFormatter

    simulate = sub.add_parser(
        "simulate",
        help="write an .npz of simulated RIRs with their ground truth, for `rangeslam run`",
        description="Simulated RIRs (pyroomacoustics, image source method) with the geometry as "
        "ground truth, in the .npz `rangeslam run` reads; it prints the command to run next.",
    )
    kinds = simulate.add_subparsers(
        dest="what", required=True, parser_class=type(simulate), metavar="KIND"
    )
    room = kinds.add_parser(
        "room",
        formatter_class=DefaultsHelpFormatter,
        help="one loudspeaker heard by M fixed microphones (then: run --mics-from-npz)",
        description="RIRs of one loudspeaker at M microphones placed at random in a room, and the "
        "truth: microphones, loudspeaker, walls (room_size for a shoebox, wall_normals and "
        "wall_offsets for any room).",
    )
    room.add_argument(
        "--out", type=arg_types.npz_file, default="rangeslam-room.npz", help="output file"
    )
    which = room.add_mutually_exclusive_group()
    which.add_argument("--room", choices=tuple(ROOMS), default="shoebox", help="the demo's rooms")
    which.add_argument(
        "--size",
        type=_side,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help=f"a shoebox of this size, metres, each side {SIZE_LIMITS[0]:g} to "
        f"{SIZE_LIMITS[1]:g} (instead of --room)",
    )
    room.add_argument(
        "--mics",
        type=arg_types.int_in(4, MAX_MICS),
        default=None,
        metavar="M",
        help=f"microphones, 4 (a room in 3-D) to {MAX_MICS} (default {ONE_MICS}; with --sources "
        f"J > 1, {SESSION_MICS}: a small wall, the cut corner's, reflects each loudspeaker to "
        "few of 8 microphones)",
    )
    room.add_argument(
        "--sources",
        type=arg_types.int_in(1, MAX_SOURCES),
        default=1,
        metavar="J",
        help=f"loudspeakers, 1 to {MAX_SOURCES}: J > 1 writes one file per loudspeaker "
        "(OUT-src0.npz, ...; the same microphones; then: run them together)",
    )
    _add_common(room, fs=48000)
    _add_recordings(room)
    room.set_defaults(func=simulate_room)
    _add_walk_parser(kinds)


def _add_recordings(room) -> None:
    """``simulate room --recordings`` and ``--delay``."""
    room.add_argument(
        "--recordings",
        choices=("sweep", "mls"),
        help="write what the microphones record of this excitation instead of the RIRs (npz "
        "'recordings' and 'excitation'; --noise is then added to the recordings): a 0.5 s "
        "exponential sine sweep from 20 Hz to fs / 2, or a maximum-length sequence of about "
        "0.34 s; `run` deconvolves them",
    )
    room.add_argument(
        "--delay",
        type=arg_types.float_in(0.0, MAX_DELAY, " s"),
        default=0.0,
        metavar="S",
        help=f"the recording starts a delay drawn uniformly in [0, S] seconds (0 to "
        f"{MAX_DELAY:g}) before the emission, one per loudspeaker, written as emission_delay "
        "(then: run --unknown-emission)",
    )


def _add_walk_parser(kinds) -> None:
    """``simulate walk`` and its options."""
    from rangeslam.app.parser import DefaultsHelpFormatter

    walk = kinds.add_parser(
        "walk",
        formatter_class=DefaultsHelpFormatter,
        help="a microphone walking in a room, several RIRs a step (then: run --step-bounds-from-npz)",
        description="The paper's Fig. 5 walk as RIRs: a microphone on the lemniscate of eq. (12) "
        "(steps of about 33 cm) in a shoebox, recording a loudspeaker several times a step (echoes "
        "are followed from RIR to RIR; one RIR a step is too few), the steps' bounds, and the "
        "truth: trajectory at every RIR, landmarks (the loudspeaker and its image sources), walls.",
    )
    walk.add_argument(
        "--out", type=arg_types.npz_file, default="rangeslam-walk.npz", help="output file"
    )
    walk.add_argument(
        "--size",
        type=_side,
        nargs=3,
        default=[5.0, 4.0, 2.6],
        metavar=("X", "Y", "Z"),
        help=f"the shoebox, metres (the paper's Fig. 5 room), each side {SIZE_LIMITS[0]:g} to "
        f"{SIZE_LIMITS[1]:g}",
    )
    walk.add_argument(
        "--steps",
        type=arg_types.int_in(3, MAX_STEPS),
        default=15,
        metavar="M",
        help=f"positions of the walk, 3 (SLAM's least) to {MAX_STEPS}; the RIRs, (M - 1) K + 1, "
        f"at most {MAX_WALK_RIRS}",
    )
    walk.add_argument(
        "--rirs-per-step",
        type=arg_types.int_in(1, MAX_RIRS_PER_STEP),
        default=8,
        metavar="K",
        help=f"RIRs recorded each step, 1 to {MAX_RIRS_PER_STEP} (the steps are every K-th RIR)",
    )
    walk.add_argument(
        "--bounds", type=_bound, default=0.2, help="step bounds: true step times 1 -+ this"
    )
    _add_common(walk, fs=16000)
    walk.set_defaults(func=simulate_walk)


def _add_common(p: argparse.ArgumentParser, *, fs: int) -> None:
    """The options of both kinds: loudspeaker, seed, sampling rate, room acoustics, noise."""
    p.add_argument(
        "--source",
        type=_coordinate,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="loudspeaker position, metres (default: at random, 0.5 m from the walls)",
    )
    p.add_argument("--seed", type=arg_types.seed, default=0, help="random seed (0 to 2^63 - 1)")
    p.add_argument(
        "--fs",
        type=arg_types.int_in(*FS_LIMITS),
        default=fs,
        help=f"sampling rate, Hz, {FS_LIMITS[0]} to {FS_LIMITS[1]}",
    )
    p.add_argument("--absorption", type=_absorption, default=0.2, help="energy absorbed by a wall")
    p.add_argument(
        "--order",
        type=arg_types.int_in(1, MAX_ORDER),
        default=3,
        help=f"highest reflection order simulated, 1 to {MAX_ORDER}",
    )
    p.add_argument(
        "--noise",
        type=arg_types.float_in(0.0, MAX_NOISE),
        default=0.0,
        help=f"std of white noise added to every sample, as a fraction of the largest sample "
        f"(0 to {MAX_NOISE:g})",
    )


def _refuse(option: str, message: str) -> int:
    """Print ``rangeslam: error: option: message`` and return 2 (bad input)."""
    print(f"rangeslam: error: {option}: {message}", file=sys.stderr)
    return 2


def _source_outside(room, args: argparse.Namespace) -> str | None:
    """Why ``--source`` is not in ``room``, or None when it is (or was not given)."""
    import numpy as np

    if args.source is None:
        return None
    src = np.asarray(args.source, dtype=float)
    if room.contains(src[None])[0]:
        return None
    lo, hi = room.vertices.min(axis=0), room.vertices.max(axis=0)
    box = " x ".join(f"[{a:g}, {b:g}]" for a, b in zip(lo, hi, strict=True))
    return f"{' '.join(f'{v:g}' for v in src)} is outside the room (within {box} m)"


def _next_command(path: Path, flag: str) -> str:
    """The ``rangeslam run`` command line for ``path``."""
    return f"rangeslam run {shlex.quote(str(path))} {flag}"


def _room_flags(args: argparse.Namespace) -> str:
    """The options of the ``rangeslam run`` suggested after ``simulate room``."""
    return "--mics-from-npz" + (" --unknown-emission" if args.delay else "")


def simulate_room(args: argparse.Namespace) -> int:
    """``rangeslam simulate room``: the RIRs of a loudspeaker (or J, one file each) at M
    microphones, and the truth."""
    from rangeslam.app.experiments import demo_rooms
    from rangeslam.geometry.room import Room

    room = Room.shoebox(args.size) if args.size else demo_rooms()[ROOMS[args.room]]
    if args.mics is None:
        args.mics = SESSION_MICS if args.sources > 1 else ONE_MICS
    outside = _source_outside(room, args)
    if outside is not None:
        return _refuse("--source", outside)
    if args.sources > 1:
        return _simulate_loudspeakers(args, room)
    return _simulate_one(args, room, args.source, args.out)


def _simulate_loudspeakers(args: argparse.Namespace, room) -> int:
    """``simulate room --sources J``: one file per loudspeaker, the same microphones (the seed
    draws them first); loudspeaker 0 is --source or drawn as for one, the others drawn from
    (seed, j)."""
    import numpy as np

    from rangeslam.sim.scenes import random_points_in_room

    stem = args.out.with_suffix("")
    paths = [stem.with_name(f"{stem.name}-src{j}.npz") for j in range(args.sources)]
    for j, path in enumerate(paths):
        src = args.source
        if j > 0:
            gen = np.random.default_rng([args.seed, j])
            src = random_points_in_room(room, 1, margin=0.5, rng=gen)[0].tolist()
        code = _simulate_one(args, room, src, path, say_next=False, index=j)
        if code:
            return code
    print(f"next: rangeslam run {' '.join(shlex.quote(str(p)) for p in paths)} {_room_flags(args)}")
    return 0


def _simulate_one(
    args: argparse.Namespace, room, source, out: Path, *, say_next=True, index: int = 0
) -> int:
    """One loudspeaker's file (``simulate room``)."""
    import numpy as np

    from rangeslam.app.progress import Heartbeat
    from rangeslam.errors import InvalidInputError
    from rangeslam.sim.recordings import room_recording

    try:
        with Heartbeat("simulate room", step=f"{args.mics} RIRs (pyroomacoustics)"):
            rec = room_recording(
                room,
                n_mics=args.mics,
                source=source,
                fs=args.fs,
                absorption=args.absorption,
                max_order=args.order,
                noise=0.0 if args.recordings else args.noise,
                rng=args.seed,
            )
    except InvalidInputError as exc:
        return _refuse("--size" if args.size else "--room", str(exc))
    truth = {"room_size": rec.room_size} if rec.room_size is not None else {}
    signals = _signals(args, rec, index)
    np.savez(
        out,
        **signals,
        fs=rec.fs,
        c=rec.c,
        mics=rec.mics,
        source=rec.source,
        wall_normals=room.normals,
        wall_offsets=room.offsets,
        absorption=args.absorption,
        max_order=args.order,
        noise=args.noise,
        seed=args.seed,
        **truth,
    )
    what = (
        " x ".join(f"{v:g}" for v in rec.room_size) + " m shoebox" if truth else f"{args.room} room"
    )
    m, length = signals["recordings" if args.recordings else "rirs"].shape
    played = {"sweep": "an exponential sine sweep", "mls": "a maximum-length sequence"}
    kind = f"recordings of {played[args.recordings]}" if args.recordings else "RIRs"
    if args.delay:
        kind += f" starting {signals['emission_delay'] * 1e3:.3f} ms before the emission"
    print(
        f"wrote {out}: {m} {kind} ({rec.fs:g} Hz, {length / rec.fs:.3f} s) of a loudspeaker "
        f"at ({', '.join(f'{v:.2f}' for v in rec.source)}) m, microphones at random in the "
        f"{what} ({room.n_walls} walls, reflection order {args.order}); ground truth: "
        "mics, source, " + ("room_size, " if truth else "") + "wall_normals, wall_offsets"
    )
    if say_next:
        print(f"next: {_next_command(out, _room_flags(args))}")
    return 0


def _signals(args: argparse.Namespace, rec, index: int) -> dict:
    """What the npz holds of the sound: ``rirs``, or ``recordings`` of ``args.recordings`` with
    ``excitation`` (--noise added to the recordings); with ``--delay`` every row starts a delay
    drawn from (seed, loudspeaker ``index``) before the emission (``emission_delay``, s)."""
    import numpy as np

    from rangeslam.acoustics.deconvolution import excitation_signal, record, shift_signals

    gen = np.random.default_rng([args.seed, index, 36])
    x, extra = rec.rirs, {}
    if args.recordings:
        e = excitation_signal(args.recordings, rec.fs)
        x = record(rec.rirs, e)
        x = x + args.noise * np.abs(x).max() * gen.standard_normal(x.shape)
        extra["excitation"] = e
    if args.delay:
        delay = float(gen.uniform(0.0, args.delay))
        lead = int(np.ceil(delay * rec.fs))
        x = shift_signals(np.pad(x, ((0, 0), (0, lead))), delay * rec.fs)
        extra["emission_delay"] = delay
    return {"recordings" if args.recordings else "rirs": x, **extra}


def simulate_walk(args: argparse.Namespace) -> int:
    """``rangeslam simulate walk``: RIRs along a walk, its step bounds, and the truth."""
    import numpy as np

    from rangeslam.app.progress import Heartbeat
    from rangeslam.errors import InvalidInputError
    from rangeslam.geometry.room import Room
    from rangeslam.sim.recordings import walk_recording
    from rangeslam.sim.trajectories import step_lengths

    outside = _source_outside(Room.shoebox(args.size), args)
    if outside is not None:
        return _refuse("--source", outside)
    n_rirs = (args.steps - 1) * args.rirs_per_step + 1
    if n_rirs > MAX_WALK_RIRS:
        return _refuse(
            "--steps",
            f"{args.steps} positions with {args.rirs_per_step} RIRs a step (--rirs-per-step) are "
            f"{n_rirs} RIRs; at most {MAX_WALK_RIRS}",
        )
    try:
        with Heartbeat("simulate walk", step=f"{n_rirs} RIRs (pyroomacoustics)"):
            rec = walk_recording(
                args.size,
                n_steps=args.steps,
                rirs_per_step=args.rirs_per_step,
                bound=args.bounds,
                source=args.source,
                fs=args.fs,
                absorption=args.absorption,
                max_order=args.order,
                noise=args.noise,
                rng=args.seed,
            )
    except InvalidInputError as exc:
        return _refuse("--size", str(exc))
    np.savez(
        args.out,
        rirs=rec.rirs,
        fs=rec.fs,
        c=rec.c,
        keyframes=rec.keyframes,
        step_bounds=rec.step_bounds,
        trajectory=rec.frames,
        landmarks=rec.landmarks,
        source=rec.source,
        room_size=rec.room_size,
        wall_normals=rec.room.normals,
        wall_offsets=rec.room.offsets,
        absorption=args.absorption,
        max_order=args.order,
        noise=args.noise,
        seed=args.seed,
    )
    f, length = rec.rirs.shape
    steps = step_lengths(rec.trajectory)
    print(
        f"wrote {args.out}: {f} RIRs ({rec.fs:g} Hz, {length / rec.fs:.3f} s) along a walk of "
        f"{args.steps} steps ({args.rirs_per_step} RIRs a step, steps {steps.min():.2f}-"
        f"{steps.max():.2f} m, bounds +-{args.bounds:.0%}) in the "
        f"{' x '.join(f'{v:g}' for v in rec.room_size)} m shoebox, loudspeaker at "
        f"({', '.join(f'{v:.2f}' for v in rec.source)}) m; ground truth: trajectory (every RIR), "
        f"{len(rec.landmarks)} landmarks (loudspeaker and image sources up to order "
        f"{args.order}), source, room_size, wall_normals, wall_offsets"
    )
    print(f"next: {_next_command(args.out, '--step-bounds-from-npz')}")
    return 0
