"""Encoder selection on held-out training recordings (for a user's file, when the settings
name no encoder): each candidate with its defaults for the data's rate, window and spectrum."""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from typing import Any

import numpy as np

from .config import PipelineConfig
from .core.data import WindowDataset, evenly_spaced
from .encoders import ENCODERS
from .training import fit_and_evaluate, split_validation

log = logging.getLogger("tactilesnn")


def median_power_frequency(X: np.ndarray, fs_hz: float, n_max: int = 256) -> float:
    """Frequency (Hz) below which half the power of (up to ``n_max``) windows lies, each
    channel's mean removed, summed over channels and windows."""
    idx = evenly_spaced(len(X), n_max)
    x = np.asarray(X[idx], dtype=np.float64)
    x = x - x.mean(-1, keepdims=True)
    power = (np.abs(np.fft.rfft(x, axis=-1)) ** 2).sum(axis=(0, 1))
    cum = np.cumsum(power)
    if not cum[-1] > 0:
        return float(fs_hz) / 4
    k = int(np.searchsorted(cum, 0.5 * cum[-1]))
    return float(np.fft.rfftfreq(x.shape[-1], 1.0 / fs_hz)[k])


#: windows the candidates are fitted on at least (small files: all of them); beyond, a share of the
#: training windows that keeps the whole selection near one final training's cost
SELECT_MIN_WINDOWS = 1500


def selection_subset(data: WindowDataset, cap: int, seed: int) -> WindowDataset:
    """Whole recordings of ``data`` (classes in turn, each class's in random order) up to ``cap``
    windows; all of ``data`` when it fits."""
    if data.y.size <= cap:
        return data
    rng = np.random.default_rng([seed, 104729])
    groups, first, sizes = np.unique(data.scan, return_index=True, return_counts=True)
    queues = [list(rng.permutation(np.flatnonzero(data.y[first] == c))) for c in np.unique(data.y)]
    keep, total = [], 0
    while any(queues):
        for q in queues:
            if q and total + sizes[q[0]] <= cap:
                total += sizes[q[0]]
                keep.append(groups[q.pop(0)])
            elif q:
                q.clear()
    return data.subset(np.isin(data.scan, keep))


#: the first round fits every candidate on this share of the selection windows (when that is at
#: least FIRST_ROUND_MIN_WINDOWS); a candidate further below the round's best than
#: HOPELESS_POINTS, or three standard errors of the difference if that is more, stops there
FIRST_ROUND_SHARE = 0.25
FIRST_ROUND_MIN_WINDOWS = 300
HOPELESS_POINTS = 0.05


def hopeless(acc: float, best: float, n: int) -> bool:
    """Whether held-out accuracy ``acc`` is too far below ``best`` (same windows, from ``n``
    recordings) to win with more training windows (see :data:`HOPELESS_POINTS`). The standard
    error counts recordings, not windows: a recording's windows err together."""
    se = np.sqrt((acc * (1 - acc) + best * (1 - best)) / max(n, 1))
    return best - acc > max(HOPELESS_POINTS, 3 * se)


def select_encoder(
    config: PipelineConfig,
    train: WindowDataset,
    candidates: tuple[str, ...],
    fraction: float = 0.25,
) -> tuple[PipelineConfig, dict[str, Any]]:
    """The candidate encoder (each with its default settings for the data's rate and window:
    see ``data_defaults`` of its config; the rest of ``config`` unchanged) that scores best on
    ``fraction`` of the training recordings held out (whole recordings).

    Ranked by held-out accuracy per window, ties by per recording, then the earlier candidate
    (per window: many more samples than the quarter of the recordings held out, where one
    recording is several points). Bounded in time: the candidates are fitted on at most
    ``max(SELECT_MIN_WINDOWS, training windows / candidates)`` windows of whole recordings, so the
    selection costs about one final training; where that is large, a first round on a quarter of
    them stops the hopeless candidates early (:func:`hopeless`). Returns the chosen config and a
    report (``scores`` per candidate, with ``stopped_early`` and ``first_round`` where that
    applies, ``ranked_by``, windows used, ``seconds``)."""
    if not candidates:
        raise ValueError("encoder selection needs at least one candidate encoder")
    t0 = time.perf_counter()
    fit_set, val_set = split_validation(train, fraction, config.seed + 1)
    assert val_set is not None
    cap = max(SELECT_MIN_WINDOWS, train.y.size // max(1, len(candidates)))
    fit_set = selection_subset(fit_set, cap, config.seed)
    val_set = selection_subset(val_set, cap, config.seed + 1)
    median = median_power_frequency(fit_set.X, train.fs_hz)
    # the model as a component asks to be fitted while encoders are compared (e.g. without its
    # own cross-validation); the chosen config keeps the model as configured
    quick = replace(config.model, **getattr(type(config.model), "WHILE_SELECTING", {}))
    configs = {}
    for name in candidates:
        cls = ENCODERS.config_class(name)
        defaults = getattr(cls, "data_defaults", None)
        fitted = defaults(train.fs_hz, train.X.shape[-1], median) if defaults else {}
        configs[name] = config.replace(encoder=cls(**fitted))

    def scored(name: str, fit: WindowDataset, val: WindowDataset) -> tuple[float, float | None]:
        m = fit_and_evaluate(configs[name].replace(model=quick), fit, val, progress=False).metrics
        per_rec = m.get("test_accuracy_per_recording")
        log.info("encoder selection: %s scores %.2f %% per window%s on %d held-out windows "
                 "(fitted on %d)", name, 100 * m["test_accuracy"],
                 f", {100 * per_rec:.2f} % per recording" if per_rec is not None else "",
                 val.y.size, fit.y.size)  # fmt: skip
        return float(m["test_accuracy"]), None if per_rec is None else float(per_rec)

    scores: dict[str, dict[str, Any]] = {name: {} for name in candidates}
    alive = list(candidates)
    first = int(FIRST_ROUND_SHARE * fit_set.y.size)
    ran_first = len(alive) > 1 and first >= FIRST_ROUND_MIN_WINDOWS
    if ran_first:
        small_fit = selection_subset(fit_set, first, config.seed + 2)
        small_val = selection_subset(val_set, int(FIRST_ROUND_SHARE * val_set.y.size),
                                     config.seed + 3)  # fmt: skip
        for name in alive:
            scores[name]["first_round"] = scored(name, small_fit, small_val)[0]
        top = max(scores[name]["first_round"] for name in alive)
        for name in alive:
            acc = scores[name]["first_round"]
            if hopeless(acc, top, np.unique(small_val.scan).size):
                scores[name].update(per_window=acc, stopped_early=True)
                log.info("encoder selection: %s stops after the first round (%.2f %% against "
                         "%.2f %%)", name, 100 * acc, 100 * top)  # fmt: skip
        alive = [n for n in alive if not scores[n].get("stopped_early")]
    best, best_key = alive[0], (-1.0, -1.0)
    for name in alive:
        if ran_first and len(alive) == 1:  # the only one left: its final training follows
            acc, per_rec = scores[name]["first_round"], None
        else:
            acc, per_rec = scored(name, fit_set, val_set)
        scores[name]["per_window"] = acc
        if per_rec is not None:
            scores[name]["per_recording"] = per_rec
        key = (acc, acc if per_rec is None else per_rec)
        if key > best_key:
            best, best_key = name, key
    seconds = time.perf_counter() - t0
    log.info("encoder selection: %s (%.0f s)", best, seconds)
    report = {"chosen": best, "ranked_by": "per window, then per recording",
              "scores": scores, "fit_windows": int(fit_set.y.size),
              "val_windows": int(val_set.y.size), "seconds": seconds,
              "first_round_windows": first if ran_first else 0}  # fmt: skip
    return configs[best], report
