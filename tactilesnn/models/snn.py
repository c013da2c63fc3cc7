"""Surrogate-gradient spiking networks: LIF layers trained by back-propagation through time.

Discretisation (exact for input held constant over a step of ``dt_ms``): the membrane decays by
``beta = exp(-dt / tau_mem)`` per step, ``u_t = beta u_{t-1} + i_t - r_t`` where ``i_t`` is the
input current (the layer's weighted input, in units of the threshold) and ``r_t`` the reset:
``"subtract"`` removes ``theta`` after a spike, ``"zero"`` sets ``u`` to 0. A spike is
``s_t = H(u_t - theta)``; in the backward pass ``H'`` is replaced by a surrogate (fast sigmoid or
arctan, slope ``alpha``).

Speed: the input projection ``W x_t`` of a feed-forward layer is computed for all time steps in one
matmul; only the elementwise recurrence runs in the time loop, inside a custom autograd function
whose backward is the linear reverse scan ``g_u[t] = g_s[t] surrogate'(u[t]) + beta g_u[t+1]``
(the reset is detached, as in snnTorch's default), saving only ``u``. Recurrent layers add
``W_rec s_{t-1}`` inside the loop.

Array contract: inputs ``[T, batch, features]`` float32 (time-major), spikes out
``[T, batch, units]``. State is explicit: every layer takes and returns its state
(``u`` for feed-forward, ``(u, s)`` for recurrent), so a model can run chunk by chunk on a stream.
"""

from __future__ import annotations

import math

import torch
from torch import nn

SURROGATES = ("fast_sigmoid", "arctan")
RESETS = ("subtract", "zero")
READOUTS = ("count", "max", "mean")


def reduce_readout(out: torch.Tensor, readout: str) -> torch.Tensor:
    """Output layer activity ``[T, B, classes]`` -> scores: spike count, max or mean over time."""
    if readout == "count":
        return out.sum(0)
    if readout == "max":
        return out.amax(0)
    return out.mean(0)


def surrogate_grad(x: torch.Tensor, kind: str, alpha: float) -> torch.Tensor:
    """Derivative of the smooth stand-in for H(x) (x = u - theta)."""
    if kind == "fast_sigmoid":
        return 1.0 / (alpha * x.abs() + 1.0) ** 2
    # arctan: d/dx [atan(pi alpha x / 2) / pi]
    return (alpha / 2) / (1.0 + (math.pi * alpha * x / 2) ** 2)


class _LIFScan(torch.autograd.Function):
    """Feed-forward LIF recurrence over T steps with a hand-written reverse-scan backward.

    Each step is three fused ``out=`` kernels (decay + input, threshold into a bool buffer, reset);
    each backward step is one (``g[t] = A[t] + beta g[t+1]``, ``A = g_s * surrogate'`` computed for
    all steps at once). Per-step kernel launches, not flops, bound this workload on a CPU.
    """

    @staticmethod
    def forward(ctx, cur, u0, beta, theta, reset, kind, alpha):  # type: ignore[override]
        steps = cur.shape[0]
        training = ctx.needs_input_grad[0] or ctx.needs_input_grad[1]
        ext = _fused(cur)
        if ext is not None:
            spikes, post, u_all = ext.lif_forward(
                cur.contiguous(), u0, beta, theta, reset == "subtract", training
            )
            if training:
                ctx.save_for_backward(u_all, spikes)
            ctx.cfg = (beta, theta, kind, alpha, reset, steps)
            return spikes, post
        # membrane before reset: kept for every step only when a backward pass will need it
        u_all = torch.empty_like(cur) if training else torch.empty_like(cur[:1]).expand_as(cur)
        spikes = torch.empty_like(cur)
        post = u0.clone()  # membrane after reset
        zero = torch.zeros((), dtype=cur.dtype)
        u_buf = torch.empty_like(u0)
        for t in range(steps):
            u, s = (u_all[t] if training else u_buf), spikes[t]
            torch.add(cur[t], post, alpha=beta, out=u)
            torch.ge(u, theta, out=s)  # written as 0.0 / 1.0 into the float buffer
            if reset == "subtract":
                torch.sub(u, s, alpha=theta, out=post)
            else:
                torch.where(s > 0, zero, u, out=post)
        if training:
            ctx.save_for_backward(u_all, spikes)
        ctx.cfg = (beta, theta, kind, alpha, reset, steps)
        return spikes, post

    @staticmethod
    def backward(ctx, g_spikes, g_u_last):  # type: ignore[override]
        u_all, spikes = ctx.saved_tensors
        beta, theta, kind, alpha, reset, steps = ctx.cfg
        ext = _fused(u_all)
        if ext is not None:  # surrogate and reverse scan fused in one pass
            g_last = g_u_last if g_u_last is not None else torch.zeros_like(u_all[0])
            g_cur = ext.lif_backward(
                g_spikes.contiguous(),
                u_all,
                spikes,
                g_last.contiguous(),
                beta,
                theta,
                reset == "subtract",
                SURROGATES.index(kind),
                alpha,
            )
            return g_cur, g_cur[0] * beta, None, None, None, None, None
        a = g_spikes * surrogate_grad(u_all - theta, kind, alpha)  # [T, B, H]
        g_cur = torch.empty_like(a)
        g = g_u_last if g_u_last is not None else torch.zeros_like(a[0])
        if reset == "subtract":
            for t in range(steps - 1, -1, -1):
                # dL/du_t = A_t + beta dL/du_{t+1} (reset detached); g holds dL/du_{t+1}
                g = torch.add(a[t], g, alpha=beta if t < steps - 1 else 1.0, out=g_cur[t])
        else:
            # reset to zero: u_{t+1} depends on u_t only where no spike
            keep = 1.0 - spikes
            carry = keep * beta
            for t in range(steps - 1, -1, -1):
                scale = carry[t] if t < steps - 1 else keep[t]
                g = torch.addcmul(a[t], g, scale, out=g_cur[t])
        return g_cur, g_cur[0] * beta, None, None, None, None, None


def _fused(x: torch.Tensor):
    """The compiled recurrence for float32 CPU tensors, else None (pure torch)."""
    if x.dtype != torch.float32 or x.device.type != "cpu":
        return None
    from ._lif_kernel import kernel

    return kernel()


def lif_scan_reference(cur, u0, beta, theta, reset="subtract"):
    """Plain autograd-free reference loop (for tests): spikes ``[T, B, H]`` and final ``u``."""
    u = u0.clone()
    out = []
    for c in cur.unbind(0):
        u = beta * u + c
        s = (u >= theta).to(cur.dtype)
        u = u - s * theta if reset == "subtract" else u * (1 - s)
        out.append(s)
    return torch.stack(out), u


class LIFLayer(nn.Module):
    """Linear projection -> LIF neurons (optionally recurrent), time-major.

    Args:
        n_in, n_out: sizes; tau_mem_ms / dt_ms give beta = exp(-dt / tau_mem).
        recurrent: add ``W_rec s_{t-1}`` to the input current.
        reset: "subtract" (theta is removed) or "zero"; theta: threshold.
        surrogate / alpha: surrogate derivative and its slope.
    """

    def __init__(
        self,
        n_in: int,
        n_out: int,
        tau_mem_ms: float = 20.0,
        dt_ms: float = 1.0,
        theta: float = 1.0,
        reset: str = "subtract",
        surrogate: str = "fast_sigmoid",
        alpha: float = 10.0,
        recurrent: bool = False,
    ) -> None:
        super().__init__()
        if reset not in RESETS:
            raise ValueError(f"unknown reset {reset!r}; choose one of: {', '.join(RESETS)}")
        if surrogate not in SURROGATES:
            raise ValueError(
                f"unknown surrogate {surrogate!r}; choose one of: {', '.join(SURROGATES)}"
            )
        if not tau_mem_ms > 0 or not dt_ms > 0:
            raise ValueError(f"tau_mem_ms and dt_ms must be positive, got {tau_mem_ms}, {dt_ms}")
        self.fc = nn.Linear(n_in, n_out)
        self.rec = nn.Linear(n_out, n_out, bias=False) if recurrent else None
        self.beta = math.exp(-dt_ms / tau_mem_ms)
        self.theta, self.reset, self.surrogate, self.alpha = theta, reset, surrogate, alpha

    def initial_state(self, batch: int, device=None, dtype=torch.float32):
        u = torch.zeros(batch, self.fc.out_features, device=device, dtype=dtype)
        return u if self.rec is None else (u, torch.zeros_like(u))

    def forward(self, x: torch.Tensor, state=None):
        """``x [T, B, n_in]`` -> ``(spikes [T, B, n_out], state)``."""
        if x.ndim != 3 or x.shape[-1] != self.fc.in_features:
            raise ValueError(
                f"expected input [T, batch, {self.fc.in_features}], got shape {tuple(x.shape)}"
            )
        if state is None:
            state = self.initial_state(x.shape[1], x.device, x.dtype)
        cur = self.fc(x)  # all time steps in one matmul
        if self.rec is None:
            spikes, u = _LIFScan.apply(
                cur, state, self.beta, self.theta, self.reset, self.surrogate, self.alpha
            )
            return spikes, u
        u, s = state
        out = []
        for c in cur.unbind(0):
            u = self.beta * u + c + self.rec(s)
            s = _SpikeFn.apply(u - self.theta, self.surrogate, self.alpha)
            u = u - s.detach() * self.theta if self.reset == "subtract" else u * (1 - s.detach())
            out.append(s)
        return torch.stack(out), (u, s)


class _SpikeFn(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x, kind, alpha):  # type: ignore[override]
        ctx.save_for_backward(x)
        ctx.cfg = (kind, alpha)
        return (x >= 0).to(x.dtype)

    @staticmethod
    def backward(ctx, g):  # type: ignore[override]
        (x,) = ctx.saved_tensors
        return g * surrogate_grad(x, *ctx.cfg), None, None


class LeakyReadout(nn.Module):
    """Linear -> leaky integrator (no spikes): ``v_t = beta v_{t-1} + W x_t``; membrane out."""

    def __init__(self, n_in: int, n_out: int, tau_mem_ms: float = 20.0, dt_ms: float = 1.0) -> None:
        super().__init__()
        self.fc = nn.Linear(n_in, n_out)
        self.beta = math.exp(-dt_ms / tau_mem_ms)

    def forward(self, x: torch.Tensor, state: torch.Tensor | None = None):
        cur = self.fc(x)
        v = torch.zeros_like(cur[0]) if state is None else state
        # a linear recurrence: v_t = sum_k beta^(t-k) cur_k, written as a causal filter over T
        out = []
        for c in cur.unbind(0):
            v = self.beta * v + c
            out.append(v)
        return torch.stack(out), v


class SNNClassifier(nn.Module):
    """Spikes ``[T, B, n_in]`` -> class scores ``[B, classes]``.

    ``readout``: "count" (spike counts of an output LIF layer), "max" or "mean" (over time of a
    leaky-integrator output membrane).
    """

    def __init__(
        self,
        n_in: int,
        n_hidden: int,
        n_classes: int,
        readout: str = "max",
        recurrent: bool = False,
        tau_mem_ms: float = 20.0,
        dt_ms: float = 1.0,
        reset: str = "subtract",
        surrogate: str = "fast_sigmoid",
        alpha: float = 10.0,
    ) -> None:
        super().__init__()
        if readout not in READOUTS:
            raise ValueError(f"unknown readout {readout!r}; choose one of: {', '.join(READOUTS)}")
        kw = {"tau_mem_ms": tau_mem_ms, "dt_ms": dt_ms}
        self.hidden = LIFLayer(
            n_in, n_hidden, reset=reset, surrogate=surrogate, alpha=alpha, recurrent=recurrent, **kw
        )
        self.readout = readout
        if readout == "count":
            self.out = LIFLayer(
                n_hidden, n_classes, reset=reset, surrogate=surrogate, alpha=alpha, **kw
            )
        else:
            self.out = LeakyReadout(n_hidden, n_classes, **kw)

    def forward(self, x: torch.Tensor, state=None):
        """``x [T, B, n_in]`` -> ``(scores [B, classes], state)`` (state: (hidden, out))."""
        h_state, o_state = (None, None) if state is None else state
        h, h_state = self.hidden(x, h_state)
        o, o_state = self.out(h, o_state)
        return reduce_readout(o, self.readout), (h_state, o_state)
