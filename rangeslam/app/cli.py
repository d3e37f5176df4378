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

    from rangeslam.app.experiments import demo_rooms, room_experiment
    from rangeslam.app.plotting import plot_room_reconstruction

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

    from rangeslam.app import benchmarking as bm
    from rangeslam.app.plotting import plot_fig3, plot_fig5

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
    from rangeslam.app import benchmarking as bm
    from rangeslam.app import plaza_bench as pb
    from rangeslam.app.plotting import plot_plaza
    from rangeslam.datasets import plaza

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
    from rangeslam.app.benchmarking import BOUND_SETTINGS

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


def _read_matrix(path: Path, flag: str):
    """A numeric matrix from .npy, or .csv / .txt (comma- or whitespace-separated, '#' comments)."""
    import numpy as np

    from rangeslam.errors import DataFormatError, InvalidInputError

    if not path.is_file():
        raise InvalidInputError(f"{flag} {path}: no such file")
    try:
        if path.suffix.lower() == ".npy":
            arr = np.load(path, allow_pickle=False)
        else:
            text = path.read_text()
            delimiter = "," if "," in text else None
            arr = np.loadtxt(path, delimiter=delimiter, ndmin=2)
        arr = np.asarray(arr, dtype=float)
    except (OSError, ValueError) as exc:
        raise DataFormatError(f"{flag} {path}: not a readable numeric matrix ({exc})") from exc
    return arr


def _run_inputs(args: argparse.Namespace, loaded):
    """(mics, step_bounds, c, where each came from) from the flags and the npz."""
    import numpy as np

    from rangeslam.acoustics.echoes import SPEED_OF_SOUND
    from rangeslam.acoustics.pipeline import MEASURED_RIR_OPTIONS
    from rangeslam.errors import InvalidInputError

    m = loaded.n_rirs
    mics = bounds = None
    keys = loaded.keyframes
    if args.keyframes is not None:
        keys = _read_matrix(args.keyframes, "--keyframes").reshape(-1)
        if not np.all(keys == np.round(keys)):
            raise InvalidInputError(f"--keyframes {args.keyframes}: must hold RIR indices")
        keys = keys.astype(int)
    n = m if keys is None else len(keys)  # steps
    if args.mics is not None:
        mics = _read_matrix(args.mics, "--mics")
        if mics.shape != (m, 3):
            raise InvalidInputError(
                f"--mics {args.mics}: must hold one row x y z per RIR, ({m}, 3); got {mics.shape}"
            )
        origin = f"--mics {args.mics}"
    elif args.step_bounds is not None:
        b = _read_matrix(args.step_bounds, "--step-bounds")
        if b.shape == (n - 1, 2) and b.shape != (2, n - 1):
            b = b.T
        if b.shape != (2, n - 1):
            raise InvalidInputError(
                f"--step-bounds {args.step_bounds}: must hold lower and upper bounds of the "
                f"{n - 1} steps, (2, {n - 1}) or ({n - 1}, 2); got {b.shape}"
            )
        bounds = b
        origin = f"--step-bounds {args.step_bounds}"
    elif args.mics_from_npz or args.step_bounds_from_npz:
        want = "mics" if args.mics_from_npz else "step_bounds"
        value = getattr(loaded, want)
        if value is None:
            raise InvalidInputError(f"--{want.replace('_', '-')}-from-npz: the RIRs hold no {want}")
        mics, bounds = (value, None) if want == "mics" else (None, value)
        origin = f"{want} from the npz"
    elif loaded.mics is not None and loaded.step_bounds is not None:
        raise InvalidInputError(
            "the npz holds both mics and step_bounds: choose with --mics-from-npz (the room) or "
            "--step-bounds-from-npz (the trajectory)"
        )
    elif loaded.mics is not None:
        mics, origin = loaded.mics, "mics from the npz"
    elif loaded.step_bounds is not None:
        bounds, origin = loaded.step_bounds, "step_bounds from the npz"
    else:
        raise InvalidInputError(
            "say what is known: --mics FILE (microphone positions, (M, 3)) or --step-bounds FILE "
            "(bounds on each step of a moving microphone, (2, M - 1))"
        )
    if keys is not None and bounds is None:
        raise InvalidInputError("keyframes are steps of a walk: give step bounds with them")
    if args.measured and bounds is not None:
        raise InvalidInputError(
            "--measured is a preset of the array mode (room_from_rirs); not for --step-bounds"
        )
    if args.c is not None:
        c, c_origin = args.c, "--c"
    elif loaded.c is not None:
        c, c_origin = loaded.c, "the npz"
    else:
        c, c_origin = SPEED_OF_SOUND, "default"
    options = dict(MEASURED_RIR_OPTIONS) if args.measured else {}
    if keys is not None:
        options["keyframes"] = keys
    return (
        None if mics is None else np.asarray(mics),
        bounds,
        float(c),
        options,
        f"{origin}; c = {c:g} m/s ({c_origin})",
    )


def _fmt(v, scale: float = 1.0, digits: int = 4) -> str:
    import math

    if v is None:
        return "-"
    if isinstance(v, float) and not math.isfinite(v):
        return "none"
    return f"{v * scale:.{digits}f}"


def _run(args: argparse.Namespace) -> int:
    """`rangeslam run`: the map or the trajectory from RIRs, printed, written and plotted."""
    import warnings

    import numpy as np

    from rangeslam.acoustics.pipeline import (
        SHOEBOX_WALLS,
        RunErrors,
        evaluate_run,
        load_rirs,
        run_rirs,
    )
    from rangeslam.app import benchmarking as bm
    from rangeslam.errors import DegenerateGeometryError, InvalidInputError

    error = None
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always", UserWarning)
        try:
            loaded = load_rirs(args.rirs[0] if len(args.rirs) == 1 else args.rirs, fs=args.fs)
            mics, bounds, c, options, inputs = _run_inputs(args, loaded)
            res = run_rirs(
                loaded.rirs,
                loaded.fs,
                mics=mics,
                step_bounds=bounds,
                c=c,
                dim=args.dim,
                rng=args.seed,
                clipped="use" if args.use_clipped else "mask",
                **options,
            )
        except (InvalidInputError, DegenerateGeometryError) as exc:
            error = exc
    caught = [
        str(w.message)
        if issubclass(w.category, UserWarning)
        else f"{w.category.__name__}: {w.message}"
        for w in seen
    ]
    for text in caught:
        print(f"rangeslam: warning: {text}", file=sys.stderr)
    if error is not None:
        print(f"rangeslam: error: {error}", file=sys.stderr)
        return 2
    try:
        errs = evaluate_run(
            res, source=loaded.source, room_size=loaded.room_size, trajectory=loaded.trajectory
        )
    except (InvalidInputError, DegenerateGeometryError) as exc:  # the answer stands; the truth not
        print(f"rangeslam: warning: ground truth not compared: {exc}", file=sys.stderr)
        errs = RunErrors()
    out = args.out
    m, length = loaded.rirs.shape
    mode_text = (
        "array mode (known microphones: the room)"
        if res.mode == "array"
        else "walk mode (step bounds: the trajectory)"
    )
    lines = [
        f"# rangeslam run: {m} RIRs, {loaded.fs:g} Hz, {length} samples "
        f"({length / loaded.fs:.3f} s), {mode_text}",
        "",
        f"inputs: {', '.join(str(p) for p in args.rirs)}; {inputs}"
        + ("; measured-RIR preset" if args.measured else "")
        + f"; seed {args.seed}",
        "",
        f"**converged: {res.converged}**. {res.message}",
        "",
    ]
    flagged = res.silent | res.no_echoes | res.clipped
    if flagged.any():
        rows = [
            [
                f"rirs[{i}]",
                loaded.names[i],
                ", ".join(
                    w
                    for w, f in (
                        ("silent", res.silent[i]),
                        ("clipped", res.clipped[i]),
                        ("no echo detected", res.no_echoes[i] and not res.masked[i]),
                        ("masked", res.masked[i]),
                    )
                    if f
                ),
            ]
            for i in np.flatnonzero(flagged)
        ]
        lines += [bm.markdown(["RIR", "file", "problem"], rows), ""]
    record: dict = {
        "command": "run",
        "inputs": [str(p) for p in args.rirs],
        "names": list(loaded.names),
        "fs": loaded.fs,
        "c": c,
        "mode": res.mode,
        "converged": res.converged,
        "message": res.message,
        "seed": args.seed,
        "measured_preset": bool(args.measured),
        "silent": [int(i) for i in np.flatnonzero(res.silent)],
        "no_echoes": [int(i) for i in np.flatnonzero(res.no_echoes)],
        "clipped": [int(i) for i in np.flatnonzero(res.clipped)],
        "masked": [int(i) for i in np.flatnonzero(res.masked)],
        "use_clipped": bool(args.use_clipped),
        "warnings": caught,
    }
    written = []
    if res.mode == "array":
        src = res.source
        lines += [
            "| loudspeaker | x [m] | y [m] | z [m] | error [mm] |",
            "|---|---|---|---|---|",
            "| estimated | "
            + (" | ".join(_fmt(float(v)) for v in src) if src is not None else "- | - | -")
            + f" | {_fmt(errs.source_error, 1e3, 1)} |",
        ]
        if loaded.source is not None:
            lines.append("| true | " + " | ".join(_fmt(float(v)) for v in loaded.source) + " | |")
        record["source"] = None if src is None else src.tolist()
        record["source_error_m"] = errs.source_error
        wall_rows = []
        if res.wall_normals is not None:
            for k, (n, o) in enumerate(zip(res.wall_normals, res.wall_offsets, strict=True)):
                wall_rows.append(
                    {
                        "wall": k,
                        "nx": float(n[0]),
                        "ny": float(n[1]),
                        "nz": float(n[2]),
                        "offset_m": float(o),
                        "microphones": int(res.wall_support[k]),
                    }
                )
        lines += ["", f"{len(wall_rows)} walls (normal . x = offset, outward normal):", ""]
        lines.append(
            bm.markdown(
                ["wall", "normal", "offset [m]", "microphones"],
                [
                    [
                        str(w["wall"]),
                        "("
                        + ", ".join(f"{round(w[a], 3) + 0.0:+.3f}" for a in ("nx", "ny", "nz"))
                        + ")",
                        f"{round(w['offset_m'], 4) + 0.0:.4f}",
                        str(w["microphones"]),
                    ]
                    for w in wall_rows
                ],
            )
        )
        record["walls"] = wall_rows
        if errs.wall_errors is not None:
            lines += [
                "",
                "Against the true shoebox (nearest estimated wall within 25 degrees):",
                "",
                bm.markdown(
                    ["true wall", "error [mm]"],
                    [
                        [name, _fmt(float(e), 1e3, 1) if np.isfinite(e) else "no wall found"]
                        for name, e in zip(SHOEBOX_WALLS, errs.wall_errors, strict=True)
                    ],
                ),
            ]
            record["wall_errors_m"] = dict(
                zip(SHOEBOX_WALLS, (float(e) for e in errs.wall_errors), strict=True)
            )
        if wall_rows:
            written.append(bm.write_csv(out / "run_walls.csv", wall_rows))
    else:
        traj, marks = res.trajectory, res.landmarks
        if traj is not None and not (np.all(np.isfinite(traj)) and np.all(np.isfinite(marks))):
            lines.append("the trajectory or the landmarks are not finite: no answer to report")
        elif traj is not None:
            path_len = float(np.linalg.norm(np.diff(traj, axis=0), axis=1).sum())
            lines += [
                f"trajectory: {len(traj)} positions, {path_len:.3f} m long"
                + (
                    f", RMS error {errs.trajectory_rmse * 100:.2f} cm after rigid alignment "
                    "(with reflection) onto the true one"
                    if errs.trajectory_rmse is not None and np.isfinite(errs.trajectory_rmse)
                    else ""
                ),
                "",
                f"{len(marks)} landmarks (loudspeaker and image sources), SLAM frame:",
                "",
                bm.markdown(
                    ["landmark", *("xyz"[: marks.shape[1]])],
                    [[str(k), *(f"{v:.4f}" for v in p)] for k, p in enumerate(marks)],
                ),
            ]
            axes = "xyz"[: traj.shape[1]]
            written.append(
                bm.write_csv(
                    out / "run_trajectory.csv",
                    [
                        {"step": i, **{a: float(v) for a, v in zip(axes, p, strict=True)}}
                        for i, p in enumerate(traj)
                    ],
                )
            )
            written.append(
                bm.write_csv(
                    out / "run_landmarks.csv",
                    [
                        {"landmark": k, **{a: float(v) for a, v in zip(axes, p, strict=True)}}
                        for k, p in enumerate(marks)
                    ],
                )
            )
            record["trajectory"] = traj.tolist()
            record["landmarks"] = marks.tolist()
            record["trajectory_length_m"] = path_len
        else:
            lines.append("no trajectory: the tracking gave SLAM nothing to work on")
        record["trajectory_rmse_m"] = errs.trajectory_rmse
    written += _run_plots(args, loaded, res)
    text = "\n".join(lines)
    (out / "run_summary.md").write_text(text + "\n")
    written.insert(0, bm.write_summary(out / "run_summary.json", **record, versions=bm.versions()))
    print(text)
    print("\nwritten: " + ", ".join(str(p) for p in written))
    if not res.converged:
        print(f"rangeslam: not converged: {res.message}", file=sys.stderr)
        return 1
    return 0


def _run_plots(args: argparse.Namespace, loaded, res) -> list[Path]:
    """The RIR matrix, and the room (array) or the trajectory (walk)."""

    import numpy as np

    from rangeslam.app.plotting import plot_rir_matrix, plot_room_estimate, plot_walk_estimate
    from rangeslam.geometry.alignment import align
    from rangeslam.geometry.room import Room

    out = args.out
    fs = loaded.fs
    latest = max((float(d.times[-1]) for d in res.detections if d.found), default=0.0)
    n = min(loaded.rirs.shape[1], max(int(1.25 * latest * fs) + 1, 64))
    written = [
        plot_rir_matrix(
            out / "run_rir_matrix.png",
            loaded.rirs[:, :n],
            fs,
            title=f"{loaded.n_rirs} RIRs ({'microphones' if res.mode == 'array' else 'steps'})",
            xlabel="microphone" if res.mode == "array" else "step",
        )
    ]
    if res.mode == "array":
        rec = res.result.reconstruction
        true_room = Room.shoebox(loaded.room_size) if loaded.room_size is not None else None
        written.append(
            plot_room_estimate(
                out / "run_room.png",
                wall_normals=res.wall_normals,
                wall_offsets=res.wall_offsets,
                mics=res.mics,
                source=res.source,
                image_sources=res.image_sources,
                room=None if rec is None else rec.room,
                true_room=true_room,
                true_source=loaded.source,
                title=f"room from {loaded.n_rirs} RIRs: "
                + ("converged" if res.converged else "not converged"),
            )
        )
    elif res.trajectory is not None:
        s = res.result.slam
        rot = shift = None
        truth = loaded.trajectory
        finite = np.all(np.isfinite(res.trajectory))
        if truth is not None and truth.shape == res.trajectory.shape and finite:
            a = align(res.trajectory, truth, reflection=True)
            rot, shift = a.rotation, a.translation
        else:
            truth = None
        written.append(
            plot_walk_estimate(
                out / "run_trajectory.png",
                receivers=res.trajectory,
                sources=res.landmarks,
                receiver_cov=getattr(s, "receiver_cov", None),
                source_cov=getattr(s, "source_cov", None),
                true_trajectory=truth,
                rotation=rot,
                translation=shift,
                title=f"walk from {loaded.n_rirs} RIRs: "
                + ("converged" if res.converged else "not converged"),
            )
        )
    return written


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive integer; got {text}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer; got {text}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive number; got {text}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive number; got {text}")
    return value


def build_parser() -> argparse.ArgumentParser:
    from rangeslam.app.plaza_bench import DEFAULT_METHODS, PLAZA_METHODS

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
        type=_positive_float,
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
        "--c", type=_positive_float, help="speed of sound, m/s (default: the npz's c, else 343)"
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
        "--out", type=_writable_dir, default=Path("rangeslam-run"), help="output directory"
    )
    run.set_defaults(func=_run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s"
    )
    from rangeslam.errors import RangeSlamError

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
