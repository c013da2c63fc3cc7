"""Summaries over draws and seeds, and the calibration optimisers compared."""

from __future__ import annotations

import logging
import time

import numpy as np

from ...core.data import WindowDataset
from .protocol import few_shot_split, slides

log = logging.getLogger("tactilesnn")


def compare_optimisers(real: WindowDataset, shots: tuple[int, ...], optimisers: tuple[str, ...],
                       seeds: int = 2, budget_s: float = 900.0) -> list[dict]:  # fmt: skip
    """The calibration's optimisers side by side: the objective each reaches in the same number
    of evaluations on the training slides of each ``k``'s first draw, per seed."""
    from ...datasets_synth.tasks.braille import BrailleTask

    rows = []
    for k in shots:
        tr, _ = few_shot_split(real, k, np.random.default_rng([31, k, 0]))
        sub = slides(real, tr)
        for name in optimisers:
            for seed in range(seeds):
                t0 = time.perf_counter()
                fit = BrailleTask.calibrate(np.asarray(sub.X, np.float64), sub.y, real.fs_hz,
                                            real.class_names, budget_s=budget_s, seed=seed,
                                            optimiser=name)  # fmt: skip
                rows.append({"k": k, "optimiser": name, "seed": seed,
                             "objective": fit.objective["value"],
                             "evaluations": fit.objective["evaluations"],
                             "seconds": time.perf_counter() - t0,
                             "history": fit.objective["history"]})  # fmt: skip
                log.info("optimiser %s, k=%d, seed %d: objective %.4f (%.0f s)", name, k, seed,
                         rows[-1]["objective"], rows[-1]["seconds"])  # fmt: skip
    return rows


def draw_means(rows: list[dict], key: str | None = None, fn=None) -> list[float]:
    """Per few-shot draw (rows of one ``k`` grouped by their ``draw``; a row without one is its
    own), the mean over its training seeds of ``row[key]`` (or of ``fn(row)``): the draws are
    the independent samples an interval is taken over, the seeds of a draw are not."""
    groups: dict = {}
    for i, r in enumerate(rows):
        groups.setdefault((r.get("k"), r.get("draw", f"row {i}")), []).append(
            r[key] if fn is None else fn(r)
        )
    return [float(np.mean(v)) for v in groups.values()]


def count_draws(rows: list[dict]) -> int:
    """How many few-shot draws ``rows`` hold (the groups of :func:`draw_means`)."""
    return len(draw_means(rows, "k"))


#: the arms :func:`calibrated_draw` splits by recording run (``row["by_run"]``)
RUN_ARMS = ("real_only", "pretrained", "pretrained_labels", "pretrained_letter", "synthetic_only")


def by_run_summary(rows: list[dict]) -> dict:
    """Each arm's per-window accuracy on the test windows of recording runs the training slides
    come from (``seen``) and of the others (``unseen``): means over draws (NaN parts skipped:
    at k = 5 a draw may cover every run), with the test windows' seen fraction."""
    out: dict = {"seen_fraction": float(np.mean(draw_means(
        rows, fn=lambda r: r["by_run"]["seen_fraction"])))}  # fmt: skip
    for arm in RUN_ARMS:
        for i, part in enumerate(("seen", "unseen")):
            v = np.asarray(draw_means(rows, fn=lambda r, a=arm, i=i: r["by_run"][a][i]))
            out[f"{arm}_{part}"] = float(np.nanmean(v)) if np.isfinite(v).any() else None
    return out


def by_letter_summary(rows: list[dict]) -> dict:
    """Each arm's per-window accuracy on each part of :func:`letter_parts` (``{arm: {part:
    mean over draws}}``, NaN parts skipped, None where every draw's is empty), with the test
    windows' letter fraction."""
    out: dict = {"letter_fraction": float(np.mean(draw_means(
        rows, fn=lambda r: r["by_letter"]["letter_fraction"])))}  # fmt: skip
    for arm in RUN_ARMS:
        names = rows[0]["by_letter"][arm]
        out[arm] = {}
        for name in names:
            v = np.asarray(draw_means(rows, fn=lambda r, a=arm, n=name: r["by_letter"][a][n]))
            out[arm][name] = float(np.nanmean(v)) if np.isfinite(v).any() else None
    return out


def summarise_calibrated(rows: list[dict]) -> dict:
    """The calibrated section's summary: means (fractions) over draws (each draw the mean over
    its training seeds), per ``k``; over every ``k`` for the synthetic-only figures."""
    out: dict = {"synthetic_only_per_slide": float(np.mean(draw_means(rows,
                                                                      "synthetic_only_per_slide"))),
                 "synthetic_only_per_window": float(np.mean(draw_means(rows, "synthetic_only"))),
                 "shots": {}}  # fmt: skip
    if all("synthetic_only_unadapted_per_slide" in r for r in rows):
        out["synthetic_only_unadapted_per_slide"] = float(
            np.mean(draw_means(rows, "synthetic_only_unadapted_per_slide"))
        )
    for k in sorted({r["k"] for r in rows}):
        sel = [r for r in rows if r["k"] == k]
        out["shots"][str(k)] = {
            name: float(np.mean(draw_means(sel, key)))
            for name, key in (("real_only_per_window", "real_only"),
                              ("pretrained_per_window", "pretrained"),
                              ("synthetic_only_per_window", "synthetic_only"),
                              ("real_only_per_slide", "real_only_per_slide"),
                              ("pretrained_per_slide", "pretrained_per_slide"),
                              ("synthetic_only_per_slide", "synthetic_only_per_slide"),
                              ("synthetic_only_unadapted_per_slide",
                               "synthetic_only_unadapted_per_slide"),
                              ("pretrained_letter_per_window", "pretrained_letter"),
                              ("pretrained_letter_per_slide", "pretrained_letter_per_slide"),
                              ("pretrained_labels_per_window", "pretrained_labels"),
                              ("pretrained_labels_per_slide", "pretrained_labels_per_slide"))
            if all(key in r for r in sel)
        }  # fmt: skip
        if all("by_run" in r for r in sel):
            out["shots"][str(k)]["by_run"] = by_run_summary(sel)
        if all("by_letter" in r for r in sel):
            out["shots"][str(k)]["by_letter"] = by_letter_summary(sel)
        out["shots"][str(k)]["draws"] = count_draws(sel)
        out["shots"][str(k)]["runs"] = len(sel)
    return out
