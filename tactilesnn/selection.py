"""Encoder selection on held-out training recordings (for a user's file, when the settings
name no encoder): each candidate with its defaults for the data's rate, window and spectrum."""

from __future__ import annotations

import logging

import numpy as np

from .config import PipelineConfig
from .core.data import WindowDataset
from .encoders import ENCODERS
from .training import fit_and_evaluate, split_validation

log = logging.getLogger("tactilesnn")


def median_power_frequency(X: np.ndarray, fs_hz: float, n_max: int = 256) -> float:
    """Frequency (Hz) below which half the power of (up to ``n_max``) windows lies, each
    channel's mean removed, summed over channels and windows."""
    idx = np.linspace(0, len(X) - 1, min(len(X), n_max)).round().astype(int)
    x = np.asarray(X[idx], dtype=np.float64)
    x = x - x.mean(-1, keepdims=True)
    power = (np.abs(np.fft.rfft(x, axis=-1)) ** 2).sum(axis=(0, 1))
    cum = np.cumsum(power)
    if not cum[-1] > 0:
        return float(fs_hz) / 4
    k = int(np.searchsorted(cum, 0.5 * cum[-1]))
    return float(np.fft.rfftfreq(x.shape[-1], 1.0 / fs_hz)[k])


def select_encoder(
    config: PipelineConfig,
    train: WindowDataset,
    candidates: tuple[str, ...],
    fraction: float = 0.25,
) -> tuple[PipelineConfig, dict[str, float]]:
    """The candidate encoder (each with its default settings for the data's rate and window:
    see ``data_defaults`` of its config; the rest of ``config`` unchanged) that scores best on
    ``fraction`` of the training recordings held out (whole recordings; per-recording accuracy
    first where recordings hold several windows, then per window; ties go to the earlier
    candidate). Returns the chosen config and each candidate's score."""
    fit_set, val_set = split_validation(train, fraction, config.seed + 1)
    assert val_set is not None
    median = median_power_frequency(fit_set.X, train.fs_hz)
    scores: dict[str, float] = {}
    best, best_key = config, (-1.0, -1.0)
    for name in candidates:
        cls = ENCODERS.config_class(name)
        defaults = getattr(cls, "data_defaults", None)
        fitted = defaults(train.fs_hz, train.X.shape[-1], median) if defaults else {}
        cfg = config.replace(encoder=cls(**fitted))
        m = fit_and_evaluate(cfg, fit_set, val_set, progress=False).metrics
        key = (m.get("test_accuracy_per_recording", m["test_accuracy"]), m["test_accuracy"])
        scores[name] = float(key[1])
        log.info("encoder selection: %s scores %.2f %% on %d held-out windows", name,
                 100 * key[1], val_set.y.size)  # fmt: skip
        if key > best_key:
            best, best_key = cfg, key
    log.info("encoder selection: %s", best.encoder_type)
    return best, scores
