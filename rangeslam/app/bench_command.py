"""``rangeslam bench``: plan, run and write a benchmark (Fig. 3, Fig. 5, compare, Plaza).

Each command here parses nothing and computes nothing: it calls the benchmarks-as-library
(:mod:`rangeslam.app.benchmarking`, :mod:`rangeslam.app.plaza_bench`) and writes what they return.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

__all__ = ["bench", "run_bench", "run_plaza_bench"]


def bench(args: argparse.Namespace) -> int:
    """``rangeslam bench WHICH``: the Plaza bench, or a simulated one with the parsed options."""
    from rangeslam.app.benchmarking import BOUND_SETTINGS

    if args.which == "plaza":
        return run_plaza_bench(args)

    bounds = BOUND_SETTINGS[args.bounds]
    return run_bench(
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


def run_bench(
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
    from rangeslam.app import benchmarking as bm

    plan = bm.plan(
        which, trials, seed, sigmas=sigmas, steps=steps, bounds=bounds, placement=placement
    )
    t0 = time.perf_counter()
    outcomes = bm.run_trials(
        plan, jobs=jobs, scheduler=scheduler, keep_trajectories=tum, progress=sys.stderr.isatty()
    )
    wall = time.perf_counter() - t0
    rows = [o.row for o in outcomes]
    written = _write_trial_csvs(out, which, outcomes)
    header, table, records = bm.summary_table(which, rows, [o.seconds for o in outcomes])
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
    written.append(_plot_bench(out, which, rows))
    if tum:
        written.append(_write_bench_tum(out, which, outcomes))
    print(text)
    print(
        f"\n{len(rows)} trials ({failed} failed) in {wall:.1f} s; seed {seed}; written: "
        + ", ".join(str(p) for p in written)
    )
    return 1 if failed == len(rows) else 0


def _write_trial_csvs(out: Path, which: str, outcomes) -> list[Path]:
    """The per-trial CSV (deterministic values) and the timings CSV (wall times apart)."""
    from rangeslam.app.reports import write_csv

    rows = [o.row for o in outcomes]
    timings = [{"cell": o.row["cell"], "trial": o.row["trial"], **o.seconds} for o in outcomes]
    return [
        write_csv(out / f"{which}_trials.csv", rows),
        write_csv(out / f"{which}_timings.csv", timings),
    ]


def _plot_bench(out: Path, which: str, rows: list[dict]) -> Path:
    """The run's figure: Fig. 3 (error against noise) or Fig. 5 (error against steps)."""
    from rangeslam.app import benchmarking as bm
    from rangeslam.app.plotting import plot_fig3, plot_fig5

    if which == "fig3":
        return plot_fig3(out / "fig3.png", rows)
    names = {m: bm.METHOD_NAMES[m] for m in bm.bench_methods(which)}
    return plot_fig5(out / f"{which}.png", rows, names)


def _write_bench_tum(out: Path, which: str, outcomes) -> Path:
    """Every kept trajectory of the run in the TUM format, in ``out/tum``."""
    from rangeslam.app.reports import write_tum

    folder = out / "tum"
    folder.mkdir(exist_ok=True)
    for o in outcomes:
        for name, x in (o.trajectories or {}).items():
            write_tum(folder / f"{which}_cell{o.row['cell']}_trial{o.row['trial']}_{name}.tum", x)
    return folder


def run_plaza_bench(args: argparse.Namespace) -> int:
    """Every method on a Plaza data set, the cost against length, a plot; CSV, JSON, Markdown."""
    from rangeslam.app import plaza_bench as pb
    from rangeslam.app.plotting import plot_plaza
    from rangeslam.app.reports import markdown, versions, write_csv, write_summary
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
    written = [write_csv(out / f"{stem}_methods.csv", rows)]
    if lengths:
        written.append(write_csv(out / f"{stem}_lengths.csv", lengths))
    text = f"## {dataset.name}: methods\n\n" + markdown(*pb.methods_table(rows))
    if lengths:
        text += "\n\n## Cost against trajectory length\n\n" + markdown(*pb.lengths_table(lengths))
    (out / f"{stem}_summary.md").write_text(text + "\n")
    written.append(
        write_summary(
            out / f"{stem}_summary.json",
            bench="plaza",
            dataset=dataset.name,
            citation=dataset.citation,
            seed=args.seed,
            trials=args.trials,
            wall_seconds=wall,
            versions=versions(),
            methods=rows,
            lengths=lengths,
        )
    )
    evaluations = {name: pb.evaluate(res, dataset) for name, res in kept.items()}
    written.append(plot_plaza(out / f"{stem}.png", dataset, kept, evaluations))
    if args.tum:
        written.append(_write_plaza_tum(out, stem, dataset, kept))
    print(text)
    failed = sum(r["status"] != "ok" for r in rows)
    print(
        f"\n{len(rows)} runs ({failed} failed) in {wall:.1f} s; seed {args.seed}; written: "
        + ", ".join(str(p) for p in written)
    )
    return 1 if failed == len(rows) else 0


def _write_plaza_tum(out: Path, stem: str, dataset, kept: dict) -> Path:
    """The truth and each kept method's positions at its pose times, TUM format, in ``out/tum``."""
    from rangeslam.app.reports import write_tum

    folder = out / "tum"
    folder.mkdir(exist_ok=True)
    truth = dataset.truth_at(dataset.pose_time)
    write_tum(folder / f"{stem}_truth.tum", truth, times=dataset.pose_time)
    for name, res in kept.items():
        write_tum(
            folder / f"{stem}_{name.replace(' ', '_').replace('+', '_')}.tum",
            res.poses[:, :2],
            times=res.pose_time,
        )
    return folder
