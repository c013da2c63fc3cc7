"""Send-on-delta (level-crossing) encoder, SPEC 3's "delta coding": ``delta``.

Each channel is quantised to levels ``q_t = round(x_t / delta)``; a rise of the level by ``n``
emits ``n`` spikes on the channel's ON afferent at the sample's time, a fall ``n`` spikes on its
OFF afferent (afferent ``2 c`` = ON, ``2 c + 1`` = OFF of channel ``c``). The first sample sets
the reference level and emits nothing, so a constant offset costs no spikes. ``delta`` is
``threshold`` times the channel's median RMS sample-to-sample change on the training windows
(fitted, a buffer), so the code adapts to any sensor's units. Each afferent keeps its first
``max_spikes`` spike times (ms from the window start, sample ``i`` at ``i / fs``).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from ..core.data import row_blocks
from ..core.spikes import first_spike_times
from ..schema.encoders import DeltaConfig
from .base import SpikeEncoder, register_encoder


class _DeltaGraph(nn.Module):
    """Levels -> ON/OFF crossings per sample -> first ``k`` spike times (traceable)."""

    def __init__(self, inv_delta: Tensor, dt_ms: float, k: int) -> None:
        super().__init__()
        self.register_buffer("inv_delta", inv_delta.clone())
        self.dt, self.k = float(dt_ms), int(k)

    def forward(self, x: Tensor) -> Tensor:
        q = torch.round(x * self.inv_delta.view(1, -1, 1))
        d = q[..., 1:] - q[..., :-1]  # [B, C, W - 1]: crossings arriving at samples 1..W-1
        counts = torch.stack([d.clamp(min=0.0), (-d).clamp(min=0.0)], dim=2).flatten(1, 2)
        # crossings between samples i-1 and i arrive at sample i: times start at one step
        return first_spike_times(counts, self.dt, self.k, t0_ms=self.dt)


@register_encoder("delta", DeltaConfig)
class DeltaEncoder(SpikeEncoder):
    """Send-on-delta ON/OFF afferents per channel; see the module docstring."""

    needs_fit = True
    codes_envelopes = True

    def __init__(self, config: DeltaConfig, fs_hz: float, window: int, n_channels: int) -> None:
        super().__init__(config, fs_hz, window, n_channels)
        if self.window < 2:
            raise ValueError(f"the delta encoder needs windows of >= 2 samples, got {window}")
        self.register_buffer("delta", torch.ones(n_channels))  # level step, input units

    @property
    def n_afferents(self) -> int:
        return 2 * self.n_channels

    @property
    def max_spikes(self) -> int:
        return self.config.max_spikes

    def fit(self, X: np.ndarray) -> DeltaEncoder:
        arr = np.asarray(X)
        # a block of windows at a time in float64 (no float64 copy of the whole training set)
        change, peak = [], []
        for rows in row_blocks(arr):
            block = np.asarray(rows, dtype=np.float64)
            change.append(np.sqrt((np.diff(block, axis=-1) ** 2).mean(-1)))  # [n, C]
            peak.append(np.abs(block).max(axis=(0, 2)))
        rms = np.median(np.concatenate(change), axis=0)  # [C]
        scale = np.max(peak, axis=0)
        # a channel that never changes keeps a level step that cannot be crossed by its noise
        floor = np.maximum(1e-6 * scale, np.finfo(np.float64).tiny)
        self.delta.copy_(torch.from_numpy(self.config.threshold * np.maximum(rms, floor)))
        self.fitted.fill_(True)
        return self

    def bytes_per_window(self) -> int:
        return 4 * self.n_afferents * self.window * 4

    def graph(self) -> _DeltaGraph:
        return _DeltaGraph(1.0 / self.delta, 1000.0 / self.fs_hz, self.config.max_spikes)

    def encode_batch(self, x: Tensor) -> Tensor:
        return self.graph()(x)

    def onnx_module(self) -> nn.Module:
        return self.graph()
