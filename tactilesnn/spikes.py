"""The spike format shared by every stage, and its one binning convention.

Between stages spikes are *times*: ``[N, afferents, k]`` float32, ms from the window start,
ascending along the last axis, ``+inf`` where a slot holds no spike. Models that run in discrete
time see a raster of ``dt_ms`` steps: step ``j`` holds ``[j dt, (j + 1) dt)``, a spike at exactly
the window end falls into the last step, so a window of ``D`` ms has ``ceil(D / dt)`` steps.
"""

from __future__ import annotations

import math

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
    grid = torch.arange(steps, dtype=times.dtype).view(-1, 1, 1, 1)
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
