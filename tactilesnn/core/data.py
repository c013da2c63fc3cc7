"""The data contract between data sources (tasks, recordings) and pipelines.

:class:`WindowDataset` is what every task's ``build()`` and every recordings reader returns:
``X`` ``[N, channels, window]`` float32 in the sensor's readout units at ``fs_hz``, ``y`` ``[N]``
int64 class indices into ``class_names``, ``scan`` ``[N]`` int64 group ids (a scan, trial or
recording: windows of one group never straddle a split).

It is also a map-style dataset as torch's ``DataLoader`` and tonic expect: ``len(ds)`` and
``ds[i] -> (window [channels, window], label)``, with an optional ``transform`` applied to the
window (an encoder's :meth:`~tactilesnn.encoders.base.SpikeEncoder.transform` turns it into
spike times).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np


@dataclass(frozen=True)
class WindowDataset:
    """Windows of one split: ``X [N, C, W]`` float32, ``y [N]`` int64, ``scan [N]`` int64."""

    X: np.ndarray
    y: np.ndarray
    scan: np.ndarray
    fs_hz: float
    class_names: tuple[str, ...]
    channel_names: tuple[str, ...]
    transform: Callable[[np.ndarray], Any] | None = field(default=None, compare=False)

    def __len__(self) -> int:
        return len(self.y)

    def __getitem__(self, index: int) -> tuple[Any, int]:
        """``(window [channels, samples], label)``; the window through ``transform`` if set."""
        x = self.X[index]
        return (x if self.transform is None else self.transform(x)), int(self.y[index])

    @property
    def classes(self) -> tuple[str, ...]:
        """Class names (torchvision / tonic spelling)."""
        return self.class_names

    def subset(self, mask: np.ndarray) -> WindowDataset:
        """The windows selected by a boolean mask or an index array (same rate and names)."""
        return replace(self, X=self.X[mask], y=self.y[mask], scan=self.scan[mask])

    def with_transform(self, transform: Callable[[np.ndarray], Any] | None) -> WindowDataset:
        return replace(self, transform=transform)

    def concat(self, other: WindowDataset) -> WindowDataset:
        """Both splits' windows (same rate, channels and classes required)."""
        if (other.fs_hz, other.channel_names, other.class_names) != (
            self.fs_hz, self.channel_names, self.class_names
        ):  # fmt: skip
            raise ValueError("datasets differ in rate, channels or classes: cannot concatenate")
        return replace(
            self,
            X=np.concatenate([self.X, other.X]),
            y=np.concatenate([self.y, other.y]),
            scan=np.concatenate([self.scan, other.scan]),
        )


def evenly_spaced(n: int, n_max: int) -> np.ndarray:
    """Indices of at most ``n_max`` of ``n`` items, evenly spaced from the first to the last (a
    subsample of training windows that fitting statistics is bounded by)."""
    return np.linspace(0, n - 1, min(n, n_max)).round().astype(int)
