"""Pre-spiked input passed through: ``events``.

For event sensors (ON/OFF taxels, a neuromorphic skin) the data are already spikes. Their window
format is the package's usual one, ``[N, channels, bins]`` at ``fs = 1000 / bin_ms``, holding the
number of events per bin (channel = taxel x polarity; :func:`tactilesnn.recordings.load_data_file`
reads ``[N, taxels, polarity, bins]`` event files into it). Each channel is one afferent; bin ``i``
is time ``i * bin_ms``, a count of ``n`` is ``n`` spikes there, and each afferent keeps its first
``max_spikes`` spike times. Nothing is fitted; non-integer or negative counts are refused.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from torch import Tensor, nn

from ..core.checks import check_int
from ..core.spikes import first_spike_times
from .base import SpikeEncoder, register_encoder


@dataclass(frozen=True)
class EventsConfig:
    max_spikes: int = 16

    FLAGS: ClassVar[dict[str, str]] = {"events_max_spikes": "max_spikes"}
    HELP: ClassVar[dict[str, str]] = {"max_spikes": "spike times kept per afferent (channel)"}

    def __post_init__(self) -> None:
        check_int(self.max_spikes, "max_spikes", 1)


class _EventsGraph(nn.Module):
    def __init__(self, dt_ms: float, k: int) -> None:
        super().__init__()
        self.dt, self.k = float(dt_ms), int(k)

    def forward(self, x: Tensor) -> Tensor:
        return first_spike_times(x.clamp(min=0.0).round(), self.dt, self.k)


@register_encoder("events", EventsConfig)
class EventsEncoder(SpikeEncoder):
    """Event counts per bin -> spike times, one afferent per channel; see the module docstring."""

    @property
    def n_afferents(self) -> int:
        return self.n_channels

    @property
    def max_spikes(self) -> int:
        return self.config.max_spikes

    def fit(self, X: np.ndarray) -> EventsEncoder:
        arr = np.asarray(X)
        if arr.size and ((arr < 0).any() or not np.array_equal(arr, np.round(arr))):
            raise ValueError(
                "the events encoder takes event counts per bin (non-negative integers); "
                "use an analog encoder (gwt, stft, lif, delta) for sampled signals"
            )
        return super().fit(X)

    def bytes_per_window(self) -> int:
        return 4 * self.n_channels * self.window * 4

    def encode_batch(self, x: Tensor) -> Tensor:
        return _EventsGraph(1000.0 / self.fs_hz, self.config.max_spikes)(x)

    def onnx_module(self) -> nn.Module:
        return _EventsGraph(1000.0 / self.fs_hz, self.config.max_spikes)
