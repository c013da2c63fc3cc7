"""Calibrated level code: each channel's window level as a population of latency spikes.

The scalogram latency codes divide each window by its own peak (gain invariance), and the LIF
converters resolve a level only to within one of their graded thresholds, so what a linear model
reads from a window's channel means (absolute level: contact force, a fabric's thickness, a
taxel's baseline; event rate for event sensors) is gone before the model sees it. This stage puts
it back, for any encoder, calibrated on the training windows so it follows the data's own scale:

* per channel and window two statistics (``STATS``): ``mean`` (the level, in the sensor's units)
  and ``log_sd`` (``ln`` of the standard deviation over the window's samples: activity, over any
  number of decades); with ``share`` a third, the channel's share of the window's total level
  across channels (``(mean - centre) / (sum |mean - centre| + floor)``: the spatial pattern of a
  press without its force);
* each statistic through the channel's empirical distribution function on the training windows
  (``quantiles`` knots, piecewise linear between them): ``u`` in [0, 1], the value's rank among
  the training windows. Ranks make the code independent of units and offsets; a value outside the
  training range clamps to 0 or 1. ``scale = "linear"`` codes the value's linear position between
  the training minimum and maximum instead, ``"rank+linear"`` both (a second ON / OFF pair),
  ``"wide"`` the linear position in the training range widened by its own span on each side
  (:data:`WIDEN`): where test conditions lie beyond the training ones (a harder press raises
  every level), the value still codes instead of clamping. FabricSlide, trained at F120-F150 and
  tested at F180-F250, a logistic regression on each channel's mean: 88.0 % per window as it
  is, 40.0 % clamped to the training range, 88.0 % clamped to the widened range (85 % of the
  test windows lie above the training maximum on some channel);
* ``u`` into ``neurons`` latency neurons: an ON / OFF pair, ``t = duration * (1 - u)`` and
  ``t = duration * u`` ms (the higher the value the earlier ON fires, the later OFF; both always
  fire, so a linear readout of their traces can weigh channels' levels against each other), and
  beyond the pair ``neurons - 2`` Gaussian receptive fields (Bohte et al. 2002), centres evenly
  over [0, 1], width one spacing: response ``r = exp(-((u - c) / w)^2 / 2)``, spike at
  ``t = duration * (1 - r)``, silent below ``r = 0.1``.

Why the pair first (LIF + readout, seed 0, per window, fields only -> pair only): a synthetic
22-channel file whose classes differ in a pattern of levels 98.00 -> 99.50 % (the amplitude-only
baseline: 100 %; four fields resolve each channel too coarsely for the differences between
channels), FabricSlide 99.41 -> 99.68 % (baseline 99.63 %); iCub Braille, seeds 0-2, 97.88 ->
96.83 % (+-4 points on 63 windows). Pair plus two fields: 99.71 / 99.36 / 96.30 % at 2.5x the
afferents.

Output: spike times ``[batch, channels * S * per]`` float32 (``S`` statistics), ms from the
window start (neuron index = (channel * S + statistic) * per + j, ``per = neurons``, plus 2 with
``rank+linear``: ON, OFF, then the linear ON, OFF, then the fields), ``+inf`` = silent. The
pipeline appends them after the encoder's afferents (one slot each) when ``level_neurons > 0``.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor, nn

from ..core.data import evenly_spaced
from ..schema.encoders import LEVEL_SCALES as SCALES

STATS = ("mean", "log_sd")
#: with ``share``: the level's share of the window's total across channels (scale-free)
SHARE_STATS = ("mean", "log_sd", "share")
#: what the ON / OFF pair codes: the training rank, the linear position in the training range, or
#: a pair of each (the readout weighs them)
#: ``scale = "wide"``: the training range widened by this many spans on each side
WIDEN = 1.0
#: a receptive field's response below this is no spike
SILENT_BELOW = 0.1
#: the log_sd floor, relative to the channel's scale (median training sd + median |level|): a flat
#: window's log sd is finite
SD_FLOOR = 1e-6
#: the least knot spacing, as a fraction of the statistic's training range
MIN_GAP = 1e-3


def window_stats(
    x: Tensor, centre: Tensor, sd_floor: Tensor, share_floor: Tensor | None = None
) -> Tensor:
    """Window ``[B, C, W]`` -> ``[B, C, 2]``: mean - centre, ln(sd + floor) (``centre`` and
    ``sd_floor`` ``[C]``); with ``share_floor`` (a scalar) ``[B, C, 3]``: the third is the
    channel's share, (mean - centre) / (sum over channels of |mean - centre| + share_floor).
    The centre (a channel's typical level) comes off first, so the sums are of small deviations
    (raw counts sit near 20,000 where level differences are thousandths)."""
    x = x - centre.view(1, -1, 1)
    mean = x.mean(-1, keepdim=True)
    dev = x - mean
    sd = (dev * dev).mean(-1, keepdim=True).sqrt()
    out = [mean, torch.log(sd + sd_floor.view(1, -1, 1))]
    if share_floor is not None:
        out.append(mean / (mean.abs().sum(1, keepdim=True) + share_floor))
    return torch.cat(out, -1)


class LevelCode(nn.Module):
    """Channels' window statistics -> calibrated population latency code (module docstring)."""

    #: buffers a saved run may lack (added later); they keep their constructed value
    optional_state = ("share_floor",)

    def __init__(self, n_channels: int, neurons: int, duration_ms: float, quantiles: int = 32,
                 scale: str = "rank", share: bool = False) -> None:  # fmt: skip
        super().__init__()
        if neurons < 2:
            raise ValueError(f"level_neurons must be 0 (off) or at least 2, got {neurons}")
        if scale not in SCALES:
            raise ValueError(f"level_scale must be one of {', '.join(SCALES)}, got {scale!r}")
        self.n_channels, self.neurons = int(n_channels), int(neurons)
        self.scale, self.share = scale, bool(share)
        self.stats = SHARE_STATS if self.share else STATS
        #: ON / OFF pairs per statistic: the rank's, the linear position's, or both
        self.pairs = 2 if scale == "rank+linear" else 1
        #: spans the linear position's range is widened by on each side
        self.widen = WIDEN if scale == "wide" else 0.0
        self.duration_ms = float(duration_ms)
        # float64 state and arithmetic: a window at a value many training windows share (a silent
        # channel at the sd floor) sits on a steep stretch of the rank function, where float32
        # rounding in another runtime moved spikes by whole knot intervals (26 ms, measured)
        f64 = torch.float64
        n_stats = len(self.stats)
        self.register_buffer("knots", torch.zeros(n_channels, n_stats, quantiles + 1, dtype=f64))
        self.register_buffer("sd_floor", torch.ones(n_channels, dtype=f64))
        self.register_buffer("centre", torch.zeros(n_channels, dtype=f64))
        self.register_buffer("share_floor", torch.ones((), dtype=f64))
        fields = neurons - 2
        centres = torch.full((fields,), 0.5, dtype=f64)  # one field: in the middle
        if fields > 1:
            centres = torch.linspace(0.0, 1.0, fields, dtype=f64)
        self.register_buffer("centres", centres)
        self.fields = fields
        self.width = 1.0 / (fields - 1) if fields > 1 else 0.5
        self.silent_below = SILENT_BELOW
        #: afferents of the code (a plain attribute: the module is scripted inside LIF graphs)
        self.n_afferents = self.n_channels * n_stats * (self.neurons + 2 * (self.pairs - 1))

    @torch.jit.unused
    def fit(self, X: np.ndarray, n_max: int = 4096) -> LevelCode:
        """Knots from (up to ``n_max``, evenly spaced) training windows ``[N, C, W]``."""
        arr = np.asarray(X)
        idx = evenly_spaced(len(arr), n_max)
        # per window, ~32 MB of float64 at a time (a copy of every window would double a large
        # file): each chunk is read twice, for the floors and then for the statistics
        step = max(1, (1 << 25) // max(1, 8 * int(np.prod(arr.shape[1:]))))

        def chunks():
            for i in range(0, len(idx), step):
                yield np.asarray(arr[idx[i : i + step]], dtype=np.float64)

        means, sd = (np.concatenate(v) for v in zip(*((c.mean(-1), c.std(-1)) for c in chunks()),
                                                  strict=True))  # fmt: skip
        centre = np.median(means, axis=0)  # [C]
        mean = means - centre
        scale = np.median(sd, axis=0) + np.median(np.abs(mean), axis=0) + np.abs(centre)
        floor = np.where(scale > 0, SD_FLOOR * scale, 1e-30)
        # the share's floor: the channels' typical deviations summed (windows at rest, whose
        # deviations are noise, get small shares rather than noise magnified to +-1)
        typical = float((np.median(sd, axis=0) + np.median(np.abs(mean), axis=0)).sum())
        self.share_floor.fill_(typical if typical > 0 else 1e-30)
        self.sd_floor.copy_(torch.from_numpy(floor))
        self.centre.copy_(torch.from_numpy(centre))
        stats = np.concatenate([self.stats_of(torch.from_numpy(c)).numpy()
                                for c in chunks()])  # [n, C, stats]  # fmt: skip
        q = np.linspace(0.0, 1.0, self.knots.shape[-1])
        knots = np.quantile(stats, q, axis=0).transpose(1, 2, 0)  # [C, 2, K+1]
        # knots at least MIN_GAP of the range apart: where many windows share a value (silent
        # channels at the sd floor) tied knots make a step at that value, and a float32 rounding
        # of it in another runtime would jump a whole knot interval
        span = knots[..., -1:] - knots[..., :1]
        gap = np.maximum(
            np.maximum(MIN_GAP * span, 1e-6 * np.abs(knots).max(-1, keepdims=True)), 1e-30
        )
        steps = np.maximum(np.diff(knots, axis=-1), gap)
        knots = np.concatenate([knots[..., :1], knots[..., :1] + np.cumsum(steps, -1)], -1)
        self.knots.copy_(torch.from_numpy(knots))
        return self

    def stats_of(self, x: Tensor) -> Tensor:
        """Window ``[B, C, W]`` (float64) -> its statistics ``[B, C, S]``."""
        return window_stats(x, self.centre, self.sd_floor, self.share_floor if self.share else None)

    def rank_of(self, v: Tensor) -> Tensor:
        """Statistics ``[B, C, S]`` -> their training ranks in [0, 1] (float64)."""
        v = v.unsqueeze(-1)
        lo, hi = self.knots[..., :-1], self.knots[..., 1:]
        return ((v - lo) / (hi - lo)).clamp(0.0, 1.0).mean(-1)

    def position_of(self, v: Tensor) -> Tensor:
        """Statistics ``[B, C, S]`` -> their linear positions in the training range, in [0, 1]
        (float64): proportional to the value, so a linear readout can form weighted sums of
        levels (a centroid, a total force) that ranks distort."""
        lo, hi = self.knots[..., 0], self.knots[..., -1]
        lo, hi = lo - self.widen * (hi - lo), hi + self.widen * (hi - lo)
        return ((v - lo) / (hi - lo)).clamp(0.0, 1.0)

    def ranks(self, x: Tensor) -> Tensor:
        """Window ``[B, C, W]`` -> each statistic's training rank ``[B, C, S]`` in [0, 1]."""
        return self.rank_of(self.stats_of(x.double()))

    def forward(self, x: Tensor) -> Tensor:
        """Window ``[B, C, W]`` -> spike times ``[B, n_afferents]`` (ms, inf = silent)."""
        v = self.stats_of(x.double())
        first = self.rank_of(v) if self.scale.startswith("rank") else self.position_of(v)
        u = first.unsqueeze(-1)  # [B, C, S, 1]
        t = torch.cat([self.duration_ms * (1.0 - u), self.duration_ms * u], -1)  # ON, OFF
        if self.pairs == 2:
            p = self.position_of(v).unsqueeze(-1)
            t = torch.cat([t, self.duration_ms * (1.0 - p), self.duration_ms * p], -1)
        if self.fields > 0:
            z = (u - self.centres) / self.width
            r = torch.exp(-0.5 * z * z)
            fields = torch.where(r < self.silent_below, math.inf, self.duration_ms * (1.0 - r))
            t = torch.cat([t, fields], -1)
        return t.flatten(1).float()
