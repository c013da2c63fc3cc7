"""The spike format shared by every stage, and its one binning convention.

Between stages spikes are *times*: ``[N, afferents, k]`` float32, ms from the window start,
ascending along the last axis, ``+inf`` where a slot holds no spike. Models that run in discrete
time see a raster of ``dt_ms`` steps: step ``j`` holds ``[j dt, (j + 1) dt)``, a spike at exactly
the window end falls into the last step, so a window of ``D`` ms has ``ceil(D / dt)`` steps.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor


def raster_steps(duration_ms: float, dt_ms: float) -> int:
    """Steps covering a window of ``duration_ms`` at ``dt_ms``."""
    if not (dt_ms > 0 and duration_ms > 0):
        raise ValueError(f"duration_ms and dt_ms must be positive, got {duration_ms}, {dt_ms}")
    return max(1, math.ceil(duration_ms / dt_ms - 1e-9))


def spike_raster(times: Tensor, dt_ms: float, steps: int) -> Tensor:
    """Spike times ``[N, A]`` or ``[N, A, k]`` (ms; inf = none) -> counts ``[steps, N, A]``.

    Time-major (what the SNN consumes); spikes outside ``[0, steps * dt]`` are dropped. Written
    with broadcasting comparisons so the same function runs inside the exported graphs.
    """
    if times.dim() == 2:
        times = times.unsqueeze(-1)
    idx = torch.floor(times / dt_ms)
    idx = torch.where(idx == float(steps), idx - 1.0, idx)
    grid = torch.arange(steps, dtype=times.dtype, device=times.device).view(-1, 1, 1, 1)
    return (idx.unsqueeze(0) == grid).to(times.dtype).sum(-1)


def clock_times(n: int, k: int, duration_ms: float) -> Tensor:
    """A clock population: ``n`` afferents firing once each at ``j * duration / n`` -> ``[n, k]``.

    Gives a model a time reference (the tempotron's threshold is fixed, so this is its
    time-dependent bias).
    """
    out = torch.full((n, k), math.inf)
    if n:
        out[:, 0] = torch.arange(n, dtype=torch.float32) * (duration_ms / n)
    return out


def first_spike_times(counts: Tensor, dt_ms: float, k: int, t0_ms: float = 0.0) -> Tensor:
    """Spike counts per sample ``[B, A, W]`` -> the first ``k`` spike times ``[B, A, k]`` (ms).

    Sample ``i`` is at ``t0_ms + i dt_ms``; a count of ``n`` is ``n`` spikes at that time;
    ``+inf`` fills slots with no spike. Traceable (cumulative sums and ``argmax``), so encoders use
    it in their exported graphs too; run eagerly, the same times come from one ``searchsorted``
    on the running count (:func:`_first_spike_times_sorted`: one pass, not one per slot).
    """
    exporting = torch.jit.is_tracing() or torch.jit.is_scripting() or torch.compiler.is_exporting()
    if not exporting:
        return _first_spike_times_sorted(counts, dt_ms, k, t0_ms)
    cum = torch.cumsum(counts, dim=-1)
    t = torch.arange(cum.shape[-1], dtype=counts.dtype, device=counts.device)
    t = (t0_ms + t * dt_ms).view(1, 1, -1)
    slots = []
    for j in range(int(k)):
        hit = cum >= float(j + 1)
        first = torch.argmax(hit.to(counts.dtype), dim=-1, keepdim=True)
        time = torch.gather(t.expand_as(cum), -1, first)
        slots.append(torch.where(hit[..., -1:], time, torch.full_like(time, math.inf)))
    return torch.cat(slots, dim=-1)


def _first_spike_times_sorted(counts: Tensor, dt_ms: float, k: int, t0_ms: float = 0.0) -> Tensor:
    """:func:`first_spike_times` eagerly: slot ``j``'s spike is at the first sample whose running
    count reaches ``j + 1`` (``searchsorted`` on the non-decreasing running count of the
    non-negative counts), ``+inf`` past the last sample."""
    cum = torch.cumsum(counts, dim=-1).contiguous()
    targets = torch.arange(1, int(k) + 1, dtype=cum.dtype, device=cum.device)
    idx = torch.searchsorted(cum, targets.expand(*cum.shape[:-1], int(k)).contiguous())
    time = t0_ms + idx.to(counts.dtype) * dt_ms
    return torch.where(idx < cum.shape[-1], time, torch.full_like(time, math.inf))


#: spike counts stay exact in float32 (and the exported graphs) while every x slots <= 2^24
COUNT_LIMIT = 2**24


def keep_every(median_count: np.ndarray, slots: int) -> np.ndarray:
    """Prescaler per afferent: keep every ``m``-th spike, ``m = ceil(median count / slots)`` in
    ``[1, 2^24 / slots]``, so a typical window's spikes fill the slots and span the window
    (float32, as the encoders' buffers)."""
    m = np.ceil(np.asarray(median_count, dtype=np.float64) / slots)
    return np.clip(m, 1, COUNT_LIMIT // slots).astype(np.float32)
