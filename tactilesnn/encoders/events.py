"""Pre-spiked input passed through: ``events``.

For event sensors (ON/OFF taxels, a neuromorphic skin) the data are already spikes. Their window
format is the package's usual one, ``[N, channels, bins]`` at ``fs = 1000 / bin_ms``, holding the
number of events per bin (channel = taxel x polarity; :func:`tactilesnn.recordings.load_data_file`
reads ``[N, taxels, polarity, bins]`` event files into it). Each channel is one afferent; bin ``i``
is time ``i * bin_ms``, a count of ``n`` is ``n`` spikes there. Non-integer or negative counts are
refused. Which spikes fill an afferent's ``max_spikes`` slots (``keep``):

* ``"spread"`` (default): every ``m``-th event, ``m`` fitted per afferent so that its median count
  over the training windows in which it fires fits the slots (``m = 1`` where it already fits, as on
  ST-MNIST's 100-bin trials). The slots then span the whole trial whatever its length and rate;
* ``"first"``: the first ``max_spikes`` events. A fixed budget fits one data set: on 250-325-bin
  fingertip trials it dropped 62-72 % of the events and kept ~0.6 s of a 5 s touch.

Prescaling keeps the event at which the running count crosses each multiple of ``m``
(``floor(cum / m)`` per bin), so the kept times are exact, and the same arithmetic is the graph.
"""

from __future__ import annotations

import warnings
from typing import ClassVar

import numpy as np
import torch
from torch import Tensor, nn

from ..core.data import evenly_spaced, row_blocks
from ..core.spikes import first_spike_times, keep_every
from ..schema.encoders import EventsConfig
from .base import SpikeEncoder, register_encoder


class _EventsGraph(nn.Module):
    def __init__(self, dt_ms: float, k: int, every: Tensor) -> None:
        super().__init__()
        self.dt, self.k = float(dt_ms), int(k)
        self.register_buffer("every", every.clone().view(1, -1, 1))
        self.prescale = bool((every > 1).any())

    def forward(self, x: Tensor) -> Tensor:
        counts = x.clamp(min=0.0).round()
        if self.prescale:  # events at which the running count passes a multiple of m
            cum = torch.cumsum(counts, dim=-1)
            counts = torch.floor(cum / self.every) - torch.floor((cum - counts) / self.every)
        return first_spike_times(counts, self.dt, self.k)


def _all_counts(X: np.ndarray) -> bool:
    """True if every value of ``X`` is a non-negative whole number, checked a block of windows
    at a time (whole-array tests made three temporaries of the file's size)."""
    for block in row_blocks(X):
        if (block < 0).any() or not np.array_equal(block, np.round(block)):
            return False
    return True


@register_encoder("events", EventsConfig)
class EventsEncoder(SpikeEncoder):
    """Event counts per bin -> spike times, one afferent per channel; see the module docstring."""

    needs_fit = True
    #: runs written before the prescaler load with every = 1 (the first max_spikes events)
    optional_state: ClassVar[tuple[str, ...]] = ("every",)

    def __init__(self, config: EventsConfig, fs_hz: float, window: int, n_channels: int) -> None:
        super().__init__(config, fs_hz, window, n_channels)
        self.register_buffer("every", torch.ones(n_channels))

    @property
    def n_afferents(self) -> int:
        return self.n_channels

    @property
    def max_spikes(self) -> int:
        return self.config.max_spikes

    def fit(self, X: np.ndarray) -> EventsEncoder:
        arr = np.asarray(X)
        if not _all_counts(arr):
            raise ValueError(
                "the events encoder takes event counts per bin (non-negative integers); "
                "use an analog encoder (gwt, stft, lif, delta) for sampled signals"
            )
        if self.config.keep == "spread" and arr.size:
            self.every.copy_(torch.from_numpy(self._fit_every(arr)))
        return super().fit(X)

    def _fit_every(self, X: np.ndarray, n_max: int = 4096) -> np.ndarray:
        """Per afferent: median count over the (up to ``n_max``) training windows in which it
        fires, over the slots, rounded up, in ``[1, 2^24 / max_spikes]``."""
        idx = evenly_spaced(len(X), n_max)
        # a block of windows at a time: no float64 copy of 4,096 windows (655 MB on ST-MNIST)
        counts = np.concatenate([b.sum(-1, dtype=np.float64) for b in row_blocks(X, idx)])  # [n, C]
        active = np.where(counts > 0, counts, np.nan)
        with warnings.catch_warnings():  # an afferent silent in every window: all-NaN, m = 1
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nan_to_num(np.nanmedian(active, axis=0), nan=0.0)
        return keep_every(med, self.config.max_spikes)

    def bytes_per_window(self) -> int:
        # counts, their running sum, the prescaled counts, each slot's hit mask and its float
        # copy, the gathered times: ~12 float32 temporaries per (channel, bin) (measured peak)
        return 48 * self.n_channels * self.window

    def encode_batch(self, x: Tensor) -> Tensor:
        return self.onnx_module()(x)

    def onnx_module(self) -> nn.Module:
        return _EventsGraph(1000.0 / self.fs_hz, self.config.max_spikes, self.every)
