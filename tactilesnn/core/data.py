"""The data contract between data sources (tasks, recordings) and pipelines.

:class:`WindowDataset` is what every task's ``build()`` and every recordings reader returns:
``X`` ``[N, channels, window]`` float32 in the sensor's readout units at ``fs_hz``, ``y`` ``[N]``
int64 class indices into ``class_names``, ``scan`` ``[N]`` int64 group ids (a scan, trial or
recording: windows of one group never straddle a split); optionally ``confidence`` ``[N]``
float32 in [0, 1], how much of its class's own signal each window holds (known where a renderer
drew it: a synthetic slide's windows before its letter hold none; None: every window all), which
training turns into soft targets (:func:`~tactilesnn.models.softmax_fit.soft_targets`).

It is also a map-style dataset as torch's ``DataLoader`` and tonic expect: ``len(ds)`` and
``ds[i] -> (window [channels, window], label)``, with an optional ``transform`` applied to the
window (an encoder's :meth:`~tactilesnn.encoders.base.SpikeEncoder.transform` turns it into
spike times).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

#: an npz array ``group_<name> [N]`` holds each recording's value of condition ``<name>``
#: (recording run, day, force, speed, sensor unit): ``--hold-out`` tests on unseen values
GROUP_PREFIX = "group_"


def condition_text(v: Any) -> str:
    """A condition value as text, as ``--hold-out`` names it and the run reports it (``150.0``,
    ``150`` and ``"150"`` alike: ``150``; names as they are)."""
    try:
        return f"{float(v):g}"
    except (TypeError, ValueError):
        return str(v).strip()


@dataclass(frozen=True)
class DataFacts:
    """What the defaults of ``train --data`` follow, read once per run from a file's headers
    (:func:`~tactilesnn.recordings.data_facts`) or kept by the windows loaded from it
    (:attr:`WindowDataset.facts`): whether it holds events (``X [N, taxels, polarity, bins]``),
    their taxels' ``grid`` (``"ROWSxCOLS"``) and ``cells``
    (:func:`~tactilesnn.recordings.event_layout`), and the window its recordings are cut into
    when none is set (``auto_cut``: ``(window_s, hop_s)`` or None)."""

    events: bool
    grid: str | None = None
    cells: tuple[int, ...] = ()
    auto_cut: tuple[float, float] | None = None


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
    confidence: np.ndarray | None = field(default=None, compare=False)
    #: the facts of the file the windows were read from (None: not read from a file), which
    #: the defaults of ``train --data`` and ``SpikeClassifier`` follow alike
    facts: DataFacts | None = field(default=None, compare=False)
    #: conditions the file states per recording (run, day, force, speed...): ``{name:
    #: {recording id (scan): value}}``, so any subset of windows keeps them; None: none stated
    conditions: dict[str, dict[int, Any]] | None = field(default=None, compare=False)

    def condition(self, name: str) -> np.ndarray:
        """Each window's value of condition ``name`` ``[N]`` (KeyError naming the conditions
        the data states)."""
        table = (self.conditions or {}).get(name)
        if table is None:
            raise KeyError(f"no condition {name!r}; the data states "
                           f"{sorted(self.conditions or {}) or 'none'}")  # fmt: skip
        return np.asarray([table[int(s)] for s in self.scan])

    def __post_init__(self) -> None:
        c = self.confidence
        if c is not None and (np.shape(c) != np.shape(self.y) or not np.all(np.isfinite(c))
                              or np.any((np.asarray(c) < 0) | (np.asarray(c) > 1))):  # fmt: skip
            raise ValueError(f"confidence must be [N={len(self.y)}] in [0, 1], got shape "
                             f"{np.shape(c)}")  # fmt: skip

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
        c = None if self.confidence is None else self.confidence[mask]
        return replace(self, X=self.X[mask], y=self.y[mask], scan=self.scan[mask], confidence=c)

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
            confidence=None
            if self.confidence is None and other.confidence is None
            else np.concatenate([_confidence(self), _confidence(other)]),
        )


def confidence_summary(c: np.ndarray) -> dict[str, float]:
    """Window confidences ``[N]`` in a report: their mean and the shares at 0 (no share of the
    class's signal) and at 1 (a full share)."""
    c = np.asarray(c)
    return {"mean": float(c.mean()), "none": float((c == 0).mean()), "full": float((c == 1).mean())}


def _confidence(ds: WindowDataset) -> np.ndarray:
    """``ds``'s window confidences, all 1 where it has none."""
    return np.ones(len(ds.y), np.float32) if ds.confidence is None else ds.confidence


#: windows a fit statistic reads at a time (bounded temporaries, whatever the data's size)
BLOCK_ROWS = 256


def row_blocks(X: np.ndarray, index: np.ndarray | None = None) -> Iterator[np.ndarray]:
    """``X``'s rows (or ``X[index]``'s) a block of :data:`BLOCK_ROWS` at a time, so a statistic
    of a whole training set never makes a temporary (or a float64 copy) of its size."""
    n = len(X) if index is None else len(index)
    for i in range(0, n, BLOCK_ROWS):
        yield X[i : i + BLOCK_ROWS] if index is None else X[index[i : i + BLOCK_ROWS]]


def evenly_spaced(n: int, n_max: int) -> np.ndarray:
    """Indices of at most ``n_max`` of ``n`` items, evenly spaced from the first to the last (a
    subsample of training windows that fitting statistics is bounded by)."""
    return np.linspace(0, n - 1, min(n, n_max)).round().astype(int)


def recording_runs(X: np.ndarray, scan: np.ndarray) -> list[tuple[np.ndarray, int]]:
    """Windows ``X [N, channels, window]`` that tile a recording: within each group of ``scan``
    (in the order they come), every maximal run of consecutive windows each of which is the one
    before it shifted by one constant number of samples ``shift`` (``0 < shift < window``,
    checked sample for sample). Returns ``(indices, shift)`` per run of at least two windows;
    windows that tile nothing (independent trials, gaps) are in no run. A run's recording is
    :func:`join_run`."""
    arr, groups = np.asarray(X), np.asarray(scan)
    if arr.ndim != 3 or groups.shape != (len(arr),):
        raise ValueError(f"need X [N, channels, window] and scan [N], got {arr.shape}, "
                         f"{groups.shape}")  # fmt: skip
    w = arr.shape[-1]
    runs: list[tuple[np.ndarray, int]] = []
    for g in np.unique(groups):
        idx = np.flatnonzero(groups == g)
        seg, shift = [int(idx[0])], 0
        for j in (int(i) for i in idx[1:]):
            a, b = arr[seg[-1]], arr[j]
            if shift and np.array_equal(a[:, shift:], b[:, : w - shift]):
                seg.append(j)
                continue
            if len(seg) >= 2:
                runs.append((np.asarray(seg), shift))
            d = _tiling_shift(a, b) if len(seg) == 1 else 0
            seg, shift = ([seg[-1], j], d) if d else ([j], 0)
        if len(seg) >= 2:
            runs.append((np.asarray(seg), shift))
    return runs


def _tiling_shift(a: np.ndarray, b: np.ndarray) -> int:
    """The smallest ``d`` with ``b[:, :w - d] == a[:, d:]`` (windows ``[channels, w]``), or 0.
    Candidates are where ``a``'s most varied channel equals ``b``'s first sample there (one
    pass), so independent windows cost ``O(w)``."""
    w = a.shape[-1]
    row = int(np.argmax(a.std(-1))) if a.shape[0] > 1 else 0
    for d in np.flatnonzero(a[row, 1:] == b[row, 0]) + 1:
        if np.array_equal(a[:, d:], b[:, : w - d]):
            return int(d)
    return 0


def join_run(X: np.ndarray, indices: np.ndarray, shift: int) -> np.ndarray:
    """The recording ``[channels, samples]`` that the windows ``X[indices]`` tile (see
    :func:`recording_runs`)."""
    first = np.asarray(X[indices[0]])
    return np.concatenate([first, *(np.asarray(X[i])[:, -shift:] for i in indices[1:])], axis=1)
