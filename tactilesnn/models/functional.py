"""Neuron arithmetic, once: pure step and scan functions (the Norse ``functional`` pattern).

Every module (:mod:`~tactilesnn.models.snn`), the reference loops the tests compare against, the
exported ONNX graphs (these functions are TorchScript-compatible, so a scripted scan becomes an
ONNX ``Loop``) and the NIR export use these definitions; the fused C++ kernel
(:mod:`~tactilesnn.models._lif_kernel`) is a fast path of :func:`lif_scan` and is tested against it.

Discretisation (exact for input held constant over a step ``dt``): ``beta = exp(-dt / tau_mem)``,

    u_t = beta u_{t-1} + i_t            (integrate; ``i_t`` in units of the threshold)
    s_t = H(u_t - theta)                (spike)
    u_t <- u_t - theta s_t              (reset by subtraction)   or   u_t (1 - s_t)  (to zero)

A leaky integrator (the non-spiking readout) is ``v_t = beta v_{t-1} + i_t``.

Array contract: currents ``[T, batch, units]`` (time-major), states ``[batch, units]``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


def decay_factor(dt_ms: float, tau_ms: float) -> float:
    """``beta = exp(-dt / tau)`` for a step of ``dt_ms`` and a time constant ``tau_ms``."""
    if not (dt_ms > 0 and tau_ms > 0 and math.isfinite(dt_ms) and math.isfinite(tau_ms)):
        raise ValueError(f"dt_ms and tau_ms must be finite and positive, got {dt_ms}, {tau_ms}")
    return math.exp(-dt_ms / tau_ms)


def lif_integrate(u: Tensor, cur: Tensor, beta: float) -> Tensor:
    """Membrane before the threshold test: ``beta u + cur``."""
    return beta * u + cur


def lif_reset(u: Tensor, s: Tensor, theta: float, subtract: bool) -> Tensor:
    """Membrane after the spikes ``s`` (0/1): subtract ``theta`` or set to zero."""
    if subtract:
        return u - s * theta
    return u * (1.0 - s)


def lif_step(u: Tensor, cur: Tensor, beta: float, theta: float, subtract: bool):
    """One LIF step: ``(spikes, membrane after reset, membrane before reset)``."""
    v = lif_integrate(u, cur, beta)
    s = (v >= theta).to(cur.dtype)
    return s, lif_reset(v, s, theta, subtract), v


def li_step(v: Tensor, cur: Tensor, beta: float) -> Tensor:
    """One leaky-integrator step: ``beta v + cur``."""
    return beta * v + cur


def lif_scan(cur: Tensor, u0: Tensor, beta: float, theta: float, subtract: bool):
    """LIF over ``cur [T, B, H]`` from ``u0 [B, H]`` -> ``(spikes [T, B, H], final u)``."""
    u = u0
    out = []
    for t in range(cur.shape[0]):
        s, u, _ = lif_step(u, cur[t], beta, theta, subtract)
        out.append(s)
    return torch.stack(out), u


def lif_rec_scan(
    cur: Tensor, u0: Tensor, s0: Tensor, w_rec: Tensor, beta: float, theta: float, subtract: bool
):
    """Recurrent LIF: the input current adds ``s_{t-1} W_rec^T``; returns ``(spikes, u, s)``."""
    u, s = u0, s0
    w_t = w_rec.t().contiguous()  # once, outside the loop (inside, the ONNX Loop body breaks)
    out = []
    for t in range(cur.shape[0]):
        s, u, _ = lif_step(u, cur[t] + torch.matmul(s, w_t), beta, theta, subtract)
        out.append(s)
    return torch.stack(out), u, s


def li_scan(cur: Tensor, v0: Tensor, beta: float):
    """Leaky integrator over ``cur [T, B, H]`` -> ``(membrane [T, B, H], final v)``."""
    v = v0
    out = []
    for t in range(cur.shape[0]):
        v = li_step(v, cur[t], beta)
        out.append(v)
    return torch.stack(out), v


def reduce_readout(out: Tensor, readout: str) -> Tensor:
    """Output activity ``[T, B, classes]`` -> scores: ``count`` (sum), ``max`` or ``mean``."""
    if readout == "count":
        return out.sum(0)
    if readout == "max":
        return out.amax(0)
    return out.mean(0)
