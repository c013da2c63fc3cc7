"""Encoding long streams offline: sliding windows, chunked processing, and the activity gate.

Array contract of :meth:`SlidingEncoder.encode`: ``x`` ``[batch, channels, samples]`` at the
scalogram's rate -> spike times ``[batch, windows, channels * stats * bands]`` (ms from each
window's start, ``+inf`` = silent); window ``k`` covers samples ``[k * hop, k * hop + window)``.
Each window is transformed on its own (reflect edges), exactly as a trained pipeline sees it, so
processing the stream in chunks of windows gives the one-shot result.

Activity gate (skip what a scene does not need; the rule of :mod:`tactilesnn.core.gate`, with
``noise_floor`` in the input's units as every channel's threshold): a (batch, channel, window)
at or below it is not transformed and emits no spikes. Active parts are computed exactly as
without the gate. :attr:`SlidingEncoder.last_stats` reports the fraction of work skipped.
"""

from __future__ import annotations

import numpy as np
import torch

from ..core.checks import as_float_array, check_finite
from ..core.gate import active_channels
from .gwt import GaborScalogram
from .latency import LatencyCode
from .stft import STFTScalogram


class SlidingEncoder:
    """Sliding-window scalogram + latency code over a long stream, optionally gated."""

    def __init__(
        self,
        scalogram: GaborScalogram | STFTScalogram,
        code: LatencyCode,
        window: int,
        hop: int,
        noise_floor: float | None = None,
        chunk_windows: int = 4096,
    ) -> None:
        if window < 2 or hop < 1:
            raise ValueError(f"need window >= 2 and hop >= 1, got {window}, {hop}")
        if noise_floor is not None and not noise_floor >= 0:
            raise ValueError(f"noise_floor must be >= 0, got {noise_floor}")
        self.scalogram = scalogram
        self.code = code
        self.window = int(window)
        self.hop = int(hop)
        self.noise_floor = noise_floor
        self.chunk_windows = int(chunk_windows)
        self.last_stats: dict[str, float] = {}

    def n_windows(self, samples: int) -> int:
        return 0 if samples < self.window else 1 + (samples - self.window) // self.hop

    def active(self, windows: np.ndarray) -> np.ndarray:
        """``[..., window]`` -> bool mask of windows whose RMS about the mean exceeds the floor."""
        if self.noise_floor is None:
            return np.ones(windows.shape[:-1], dtype=bool)
        return active_channels(windows, self.noise_floor)

    def encode(self, x: np.ndarray) -> np.ndarray:
        arr = as_float_array(x, "x", ndim=3)
        check_finite(arr, "x")
        b, c, n = arr.shape
        nw = self.n_windows(n)
        views = np.lib.stride_tricks.sliding_window_view(arr, self.window, axis=-1)[
            :, :, :: self.hop
        ][:, :, :nw]  # [B, C, nW, window], no copy
        mask = self.active(views)
        n_stats, n_bands = len(self.code.stats), self.scalogram.n_bands
        out = np.full((b, nw, c, n_stats * n_bands), np.inf, dtype=np.float32)
        bi, ci, wi = np.nonzero(mask)
        for s in range(0, bi.size, self.chunk_windows):
            sl = slice(s, s + self.chunk_windows)
            chunk = np.ascontiguousarray(views[bi[sl], ci[sl], wi[sl]], dtype=np.float32)
            with torch.no_grad():
                scal = self.scalogram(torch.from_numpy(chunk[:, None, :]))
                spikes = self.code(scal).numpy()  # [n, stats * bands]
            out[bi[sl], wi[sl], ci[sl]] = spikes
        total = max(mask.size, 1)
        self.last_stats = {
            "windows": float(mask.size),
            "transformed": float(mask.sum()),
            "skipped_fraction": 1.0 - float(mask.sum()) / total,
        }
        return out.reshape(b, nw, c * n_stats * n_bands)
