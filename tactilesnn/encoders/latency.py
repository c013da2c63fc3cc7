"""Latency code (seed 001): one spike per (channel, band) per window, stronger -> earlier.

Input: a scalogram ``[batch, channels, bands, frames]`` of one window. Each band is summarised over
the window's frames by one or more statistics (``stats``): ``"mean"`` (the band's average magnitude,
seed 001's code) and ``"std"`` (its fluctuation over time inside the window: bursts and
stick-slip events raise it; a single-frame STFT has none, so those neurons stay silent). Every
(channel, statistic, band) is one afferent neuron. Normalisation (``normalize``):

* ``"window"`` (default): divide by the window's strongest band mean, per channel. The code then
  carries the spectral (and modulation) shape, independent of the overall gain (force, coupling);
* ``"none"``: use amplitudes as they are (in the scalogram's units; ``reference`` sets full scale).

Mapping (``mapping``) of normalised amplitude ``a`` in (0, 1] to a spike time in ``[0, duration_ms]``:

* ``"log"`` (default): ``t = duration * (-20 log10 a) / dynamic_range_db``: every dB below the
  strongest band delays the spike by the same time; no spike below ``-dynamic_range_db``;
* ``"linear"``: ``t = duration * (1 - a)``; no spike below ``floor``.

Output: spike times ``[batch, channels * stats * bands]`` float32 in ms from the window start,
``+inf`` where a neuron stays silent (neuron index = (channel * n_stats + stat) * bands + band).
:func:`to_dense` converts to a dense ``[batch, neurons, steps]`` 0/1 raster.
"""

from __future__ import annotations

import numpy as np
import torch

from ..core.checks import check_choice, check_positive
from ..schema.encoders import LATENCY_STATS as STATS
from ..schema.encoders import MAPPINGS

NORMALIZATIONS = ("window", "none")


class LatencyCode:
    """Scalogram -> one latency-coded spike per (channel, band)."""

    def __init__(
        self,
        duration_ms: float = 500.0,
        mapping: str = "log",
        normalize: str = "window",
        stats: tuple[str, ...] = ("mean",),
        dynamic_range_db: float = 30.0,
        floor: float = 0.05,
        reference: float = 1.0,
        eps: float = 1e-12,
    ) -> None:
        self.duration_ms = check_positive(duration_ms, "duration_ms")
        self.mapping = check_choice(mapping, "mapping", MAPPINGS)
        self.normalize = check_choice(normalize, "normalize", NORMALIZATIONS)
        if not stats:
            raise ValueError("stats must name at least one statistic")
        self.stats = tuple(check_choice(s, "statistic", STATS) for s in stats)
        self.dynamic_range_db = check_positive(dynamic_range_db, "dynamic_range_db")
        if not 0 <= floor < 1:
            raise ValueError(f"floor must be in [0, 1), got {floor}")
        self.floor = float(floor)
        self.reference = check_positive(reference, "reference")
        self.eps = float(eps)

    def amplitudes(self, scalogram: torch.Tensor, lowest: float = 0.0) -> torch.Tensor:
        """Normalised amplitudes ``[batch, channels, stats, bands]`` in [lowest, 1]."""
        if scalogram.ndim != 4:
            raise ValueError(
                "expected a scalogram [batch, channels, bands, frames], "
                f"got shape {tuple(scalogram.shape)}"
            )
        # keepdim reductions and scalar fills: each avoided Unsqueeze / zeros_like is one node
        # fewer in the exported graph (~0.5 us each on every onnxruntime call)
        mean = scalogram.mean(-1, keepdim=True)  # [B, C, F, 1]
        parts = []
        for s in self.stats:
            if s == "mean":
                parts.append(mean)
            elif s == "std":  # population sd, written out so it exports to ONNX
                dev = scalogram - mean
                parts.append((dev * dev).mean(-1, keepdim=True).sqrt())
            else:
                parts.append(scalogram.amax(-1, keepdim=True))
        amp = torch.cat(parts, -1).transpose(-1, -2)  # [B, C, S, F]
        if self.normalize == "window":
            peak = mean.amax((-2, -1), keepdim=True)  # [B, C, 1, 1]
            # an all-zero channel has no spectral shape: it stays silent instead of dividing 0/0
            amp = torch.where(peak > self.eps, amp / peak.clamp_min(self.eps), 0.0)
        else:
            amp = amp / self.reference
        return amp.clamp(lowest, 1.0)

    def __call__(self, scalogram: torch.Tensor) -> torch.Tensor:
        """Scalogram ``[B, C, F, T]`` -> spike times ``[B, C*S*F]`` in ms (``inf`` = no spike)."""
        if self.mapping == "log":
            # t = duration * dB below the peak / dynamic range, one product of ln a; beyond the
            # range (t > duration) silent, which includes a = 0 (clamped to 1e-30: 600 dB) unless
            # the range is wider than that
            scale = -20.0 / np.log(10.0) * self.duration_ms / self.dynamic_range_db
            if self.dynamic_range_db < 600.0:
                t = scale * torch.log(self.amplitudes(scalogram, lowest=1e-30))
                silent = t > self.duration_ms
            else:
                a = self.amplitudes(scalogram)
                t = scale * torch.log(a.clamp_min(1e-30))
                silent = (t > self.duration_ms) | (a <= 0)
        else:
            a = self.amplitudes(scalogram)
            t = self.duration_ms * (1.0 - a)
            silent = a < max(self.floor, 1e-30)
        t = torch.where(silent, float("inf"), t).flatten(1)
        return t if t.dtype == torch.float32 else t.to(torch.float32)


def to_events(spike_times: torch.Tensor, duration_ms: float):
    """Spike times ``[B, N]`` (ms, inf = none) -> :class:`~tactilesnn.encoders.spiking.SpikeEvents`."""
    from .spiking import SpikeEvents

    t = spike_times.detach().cpu().numpy()
    b, n = np.nonzero(np.isfinite(t))
    return SpikeEvents(
        batch=b.astype(np.int64),
        neuron=n.astype(np.int64),
        time_ms=t[b, n].astype(np.float64),
        polarity=np.ones(b.size, np.int8),
        shape=(t.shape[0], t.shape[1]),
        duration_ms=float(duration_ms),
    )


def to_dense(spike_times: torch.Tensor, duration_ms: float, dt_ms: float) -> torch.Tensor:
    """Spike times ``[B, N]`` (ms, inf = none) -> dense raster ``[B, N, steps]`` float32
    (the package's binning, :func:`tactilesnn.core.spikes.spike_raster`)."""
    from ..core.spikes import raster_steps, spike_raster

    steps = raster_steps(duration_ms, dt_ms)
    return spike_raster(spike_times.float(), dt_ms, steps).permute(1, 2, 0).contiguous()
