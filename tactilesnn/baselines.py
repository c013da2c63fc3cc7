"""Trivial baselines that show a task is not solvable from amplitude alone."""

from __future__ import annotations

import numpy as np
from sklearn.linear_model import LogisticRegression
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler


def amplitude_stats(X: np.ndarray) -> np.ndarray:
    """Per-window mean and RMS of every channel: ``[N, C, W]`` -> ``[N, 2C]`` (float64,
    computed in slices of 64 windows, so the memory used does not grow with ``N``)."""
    X = np.asarray(X)
    out = np.empty((X.shape[0], 2 * X.shape[1]))
    for i in range(0, X.shape[0], 64):
        x = np.asarray(X[i : i + 64], dtype=np.float64)
        out[i : i + 64] = np.concatenate([x.mean(-1), np.sqrt((x**2).mean(-1))], axis=1)
    return out


def fit_amplitude_baseline(X_train: np.ndarray, y_train: np.ndarray):
    """A standardised logistic regression fitted on :func:`amplitude_stats` of ``X_train``
    (predict with ``clf.predict(amplitude_stats(X))``)."""
    clf = make_pipeline(StandardScaler(), LogisticRegression(max_iter=5000))
    return clf.fit(amplitude_stats(X_train), y_train)


def linear_amplitude_baseline(
    X_train: np.ndarray, y_train: np.ndarray, X_test: np.ndarray, y_test: np.ndarray
) -> float:
    """Test accuracy of :func:`fit_amplitude_baseline`."""
    clf = fit_amplitude_baseline(X_train, y_train)
    return float(clf.score(amplitude_stats(X_test), y_test))
