"""User recordings in the documented ``.npz`` format -> train / test :class:`WindowDataset`.

Format: ``X`` ``[N, channels, samples]`` float (the sensor's units), ``y`` ``[N]`` int, ``fs``
(Hz, scalar), ``class_names`` ``[C]`` str; optional ``channel_names`` ``[channels]`` str and
``split`` ``[N]`` (0 = train, 1 = test). Read with ``allow_pickle=False``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._checks import check_finite
from .datasets_synth import WindowDataset


def load_data_file(path: Path, seed: int, test_fraction: float = 0.2):
    """Real recordings in the documented format -> ``(train, test)`` window datasets.

    ``.npz`` with ``X`` ``[N, channels, samples]`` float, ``y`` ``[N]`` int, ``fs`` (Hz),
    ``class_names`` ``[C]`` str, optionally ``channel_names`` and ``split`` (``[N]``, 0 = train,
    1 = test). Without ``split``, a stratified random ``test_fraction`` is held out (from ``seed``).
    Loaded with ``allow_pickle=False``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"data file {path} does not exist")
    with np.load(path, allow_pickle=False) as f:
        missing = [k for k in ("X", "y", "fs", "class_names") if k not in f.files]
        if missing:
            raise ValueError(
                f"{path}: missing {missing}; expected X [N, channels, samples], y [N], fs, "
                "class_names"
            )
        X = np.asarray(f["X"])
        y = np.asarray(f["y"]).astype(np.int64)
        fs = float(f["fs"])
        names = tuple(str(c) for c in f["class_names"])
        ch = (
            tuple(str(c) for c in f["channel_names"])
            if "channel_names" in f.files
            else tuple(f"ch{i}" for i in range(X.shape[1] if X.ndim == 3 else 0))
        )
        split = np.asarray(f["split"]) if "split" in f.files else None
    if X.ndim != 3:
        raise ValueError(f"{path}: X must be [N, channels, samples], got shape {X.shape}")
    if y.shape != (X.shape[0],):
        raise ValueError(f"{path}: y must be [N={X.shape[0]}], got shape {y.shape}")
    if not np.isfinite(fs) or fs <= 0:
        raise ValueError(f"{path}: fs must be a positive sampling rate in Hz, got {fs}")
    if y.min() < 0 or y.max() >= len(names):
        raise ValueError(f"{path}: labels must index class_names (0..{len(names) - 1})")
    check_finite(X.astype(np.float64, copy=False), f"{path}: X")
    if split is None:
        from sklearn.model_selection import train_test_split

        idx = np.arange(y.size)
        _, te = train_test_split(idx, test_size=test_fraction, random_state=seed, stratify=y)
        split = np.zeros(y.size, np.int64)
        split[te] = 1
    ids = np.arange(y.size)  # each recording is its own group

    def take(m):
        return WindowDataset(X[m].astype(np.float32), y[m], ids[m], fs, names, ch)

    return take(split == 0), take(split == 1)
