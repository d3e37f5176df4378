"""The xtdoa benchmark as a library: the authors' protocol on their real data.

El Badawy, Larsson, Pollefeys, Dokmanic, "Localizing unsynchronized sensors with unknown sources"
(arXiv 2102.03565): random subsets of K of the 23 clean events (all 12 microphones), each event
its own offset and each microphone its own clock offset
(:func:`rangeslam.mdu.emission.calibrate_unknown_emission` with ``receiver_offsets=True``); the
estimated microphones aligned to the measured ones by a similarity transform (rotation, reflection,
translation, scale: their figure) and rigidly (no scale: the speed of sound fixes it); the mean
per-microphone distance. Also the robust case: all 65 events without the authors' mask.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np

from rangeslam.datasets.xtdoa import XtdoaDataset
from rangeslam.geometry.alignment import align

__all__ = [
    "PUBLISHED_MEDIAN_CM",
    "XTDOA_SIZES",
    "fit_from_reference",
    "microphone_errors",
    "reference_sources",
    "robust_row",
    "robust_table",
    "subset_rows",
    "summary_rows",
    "summary_table",
]

#: Numbers of events K of the authors' protocol.
XTDOA_SIZES = tuple(range(6, 22))
#: The authors' median errors (cm, similarity alignment), from their result files (data README).
PUBLISHED_MEDIAN_CM = {6: 42.0, 7: 16.6, 8: 13.7, 9: 10.8, 10: 9.9, 11: 9.6, 15: 8.5, 21: 7.8}


def microphone_errors(estimate: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """Mean per-microphone distance (metres) after a similarity alignment (reflection allowed,
    the authors' figure) and after a rigid one (reflection allowed, no scale)."""
    similarity = align(estimate, reference, reflection=True, scale=True)
    rigid = align(estimate, reference, reflection=True)
    return float(similarity.errors.mean()), float(rigid.errors.mean())


def reference_sources(data: XtdoaDataset, *, starts: int = 20) -> dict[int, np.ndarray]:
    """Sources fitted to the clean events with the microphones held at their measured positions
    (offsets eliminated as in :class:`rangeslam.mdu.clock_offsets.ProfiledUnfolding`; the lowest
    of ``starts`` random starts around the microphones): {column: (3,) metres}."""
    from scipy.optimize import least_squares

    from rangeslam.mdu.clock_offsets import ProfiledUnfolding

    cols = data.clean_columns
    m, k = len(data.receivers), len(cols)
    model = ProfiledUnfolding(data.arrivals[:, cols], np.ones((m, k), bool), np.arange(k), 3, 1.0)
    x = data.receivers.ravel()
    best = None
    for seed in range(starts):
        start = np.random.default_rng(seed).uniform(-2, 2, (k, 3)) + data.receivers.mean(0)
        fit = least_squares(
            lambda s: model.residuals(np.r_[x, s]),
            start.ravel(),
            jac=lambda s: model.jacobian(np.r_[x, s])[:, x.size :],
            method="lm",
        )
        best = fit if best is None or fit.cost < best.cost else best
    return dict(zip(cols.tolist(), best.x.reshape(-1, 3), strict=True))


def fit_from_reference(data: XtdoaDataset, columns: np.ndarray, sources: dict) -> float:
    """Similarity error (metres) of the least-squares fit to the events ``columns`` started from
    the measured microphones and the :func:`reference_sources`: the accuracy of the right local
    minimum, which a global search can hope to reach."""
    from scipy.optimize import least_squares

    from rangeslam.mdu.clock_offsets import ProfiledUnfolding

    m, k = len(data.receivers), len(columns)
    model = ProfiledUnfolding(
        data.arrivals[:, columns], np.ones((m, k), bool), np.arange(k), 3, 1.0
    )
    start = np.r_[data.receivers.ravel(), np.array([sources[c] for c in columns]).ravel()]
    fit = least_squares(model.residuals, start, jac=model.jacobian, method="lm", xtol=1e-15)
    return microphone_errors(fit.x.reshape(-1, 3)[:m], data.receivers)[0]


def solve_subset(data: XtdoaDataset, columns: np.ndarray, rng: np.random.Generator) -> dict:
    """One solve on the events ``columns`` (each its own offset, microphone offsets on): a row
    with K, the errors (metres), status, runs, residual RMS and seconds."""
    from rangeslam.mdu.emission import calibrate_unknown_emission

    arrivals = data.arrivals[:, columns]
    t0 = time.perf_counter()
    res = calibrate_unknown_emission(
        arrivals, np.arange(len(columns)), receiver_offsets=True, rng=rng
    )
    seconds = time.perf_counter() - t0
    similarity, rigid = microphone_errors(res.receivers, data.receivers)
    return {
        "K": len(columns),
        "columns": " ".join(str(int(c)) for c in columns),
        "similarity_error_m": similarity,
        "rigid_error_m": rigid,
        "status": res.status.name.lower(),
        "runs": res.random_starts,
        "residual_rms_m": res.residual_rms,
        "seconds": seconds,
    }


def subset_rows(
    data: XtdoaDataset,
    sizes: Sequence[int],
    subsets: int,
    *,
    seed: int = 0,
    on_row: Callable[[dict], None] | None = None,
) -> list[dict]:
    """``subsets`` random subsets of K clean events for each K in ``sizes``, one row each
    (:func:`solve_subset`). One generator from ``seed`` draws the subsets and each solve gets its
    own child generator, so the subsets drawn do not depend on how many random starts the solves
    before them used (that count can differ between machines)."""
    root = np.random.SeedSequence(seed)
    draw_rng = np.random.default_rng(root)
    clean = data.clean_columns
    rows = []
    for k in sizes:
        for child in root.spawn(subsets):
            columns = np.sort(draw_rng.choice(clean, k, replace=False))
            rows.append(solve_subset(data, columns, np.random.default_rng(child)))
            if on_row is not None:
                on_row(rows[-1])
    return rows


def summary_rows(rows: Sequence[dict]) -> list[dict]:
    """Per K: subsets, median and mean of the similarity and rigid errors (cm), the published
    median, the fraction with status converged, the median and maximum seconds per solve."""
    out = []
    for k in sorted({r["K"] for r in rows}):
        mine = [r for r in rows if r["K"] == k]
        sim = 100 * np.array([r["similarity_error_m"] for r in mine])
        rig = 100 * np.array([r["rigid_error_m"] for r in mine])
        secs = np.array([r["seconds"] for r in mine])
        out.append(
            {
                "K": k,
                "subsets": len(mine),
                "median_similarity_cm": float(np.median(sim)),
                "mean_similarity_cm": float(np.mean(sim)),
                "median_rigid_cm": float(np.median(rig)),
                "mean_rigid_cm": float(np.mean(rig)),
                "published_median_cm": PUBLISHED_MEDIAN_CM.get(k, float("nan")),
                "converged": float(np.mean([r["status"] == "converged" for r in mine])),
                "median_seconds": float(np.median(secs)),
                "max_seconds": float(np.max(secs)),
            }
        )
    return out


def summary_table(summary: Sequence[dict]) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of the Markdown table of :func:`summary_rows`."""
    header = [
        "K", "subsets", "median sim. [cm]", "mean sim. [cm]", "published median [cm]",
        "median rigid [cm]", "mean rigid [cm]", "converged", "median s/solve", "max s/solve",
    ]  # fmt: skip
    rows = []
    for s in summary:
        pub = s["published_median_cm"]
        rows.append(
            [
                str(s["K"]), str(s["subsets"]), f"{s['median_similarity_cm']:.1f}",
                f"{s['mean_similarity_cm']:.1f}", "-" if np.isnan(pub) else f"{pub:.1f}",
                f"{s['median_rigid_cm']:.1f}", f"{s['mean_rigid_cm']:.1f}",
                f"{100 * s['converged']:.0f}%", f"{s['median_seconds']:.2f}",
                f"{s['max_seconds']:.2f}",
            ]
        )  # fmt: skip
    return header, rows


def robust_row(data: XtdoaDataset, seed: int) -> dict:
    """The robust run on all events without the authors' mask
    (:func:`rangeslam.mdu.emission.calibrate_unknown_emission` with ``receiver_offsets=True,
    robust=True``, generator from ``seed``): its inlier decision against the mask W, as confusion
    counts of arrivals (kept/dropped against clean/outlier) and of whole events (the events W marks
    outlier at every microphone, against the events the run dropped whole), the microphones'
    errors (metres) and seconds."""
    from rangeslam.mdu.emission import calibrate_unknown_emission

    arrivals, clean = data.arrivals, data.clean
    t0 = time.perf_counter()
    res = calibrate_unknown_emission(
        arrivals, np.arange(arrivals.shape[1]), receiver_offsets=True, robust=True, rng=seed
    )
    seconds = time.perf_counter() - t0
    kept = np.asarray(res.inliers)
    bad_event, dropped_event = ~clean.any(axis=0), ~kept.any(axis=0)
    finite = np.all(np.isfinite(res.receivers))
    similarity, rigid = (
        microphone_errors(res.receivers, data.receivers) if finite else (np.nan, np.nan)
    )
    return {
        "seed": seed,
        "kept_clean": int(np.sum(kept & clean)),
        "kept_outlier": int(np.sum(kept & ~clean)),
        "dropped_clean": int(np.sum(~kept & clean)),
        "dropped_outlier": int(np.sum(~kept & ~clean)),
        "events_dropped_outlier": int(np.sum(dropped_event & bad_event)),
        "events_kept_outlier": int(np.sum(~dropped_event & bad_event)),
        "events_dropped_other": int(np.sum(dropped_event & ~bad_event)),
        "similarity_error_m": similarity,
        "rigid_error_m": rigid,
        "status": res.status.name.lower(),
        "subsets": res.random_starts,
        "seconds": seconds,
    }


def robust_table(rows: Sequence[dict]) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of the Markdown table of :func:`robust_row` rows."""
    header = [
        "seed", "arrivals kept: clean / W-outlier", "dropped: clean / W-outlier",
        "W-outlier events dropped / kept", "other events dropped", "sim. [cm]", "rigid [cm]",
        "status", "subsets", "s",
    ]  # fmt: skip
    out = []
    for r in rows:
        out.append(
            [
                str(r["seed"]), f"{r['kept_clean']} / {r['kept_outlier']}",
                f"{r['dropped_clean']} / {r['dropped_outlier']}",
                f"{r['events_dropped_outlier']} / {r['events_kept_outlier']}",
                str(r["events_dropped_other"]), f"{100 * r['similarity_error_m']:.1f}",
                f"{100 * r['rigid_error_m']:.1f}", r["status"], str(r["subsets"]),
                f"{r['seconds']:.0f}",
            ]
        )  # fmt: skip
    return header, out
