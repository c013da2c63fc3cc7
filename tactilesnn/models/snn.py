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

import numpy as np
import torch
from torch import Tensor, nn

from ..core.spikes import raster_steps, spike_raster
from ..schema.models import READOUTS, SNNConfig
from .base import SpikeModel, register_model, seeded
from .functional import (
    LIFState,
    LIState,
    SNNState,
    class_lead,
    decay_factor,
    decide_by_margin,
    li_closed,
    li_decay_matrix,
    li_scan,
    lif_integrate,
    lif_reset,
    lif_step,
    reduce_readout,
    running_readout,
)
from .onnx_ops import lif_as_lstm, lif_lstm_buffers, raster_current

SURROGATES = ("fast_sigmoid", "arctan")
RESETS = ("subtract", "zero")


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
        u_all = torch.empty_like(cur) if training else None
        spikes = torch.empty_like(cur)
        post = u0
        for t in range(steps):
            spikes[t], post, u = lif_step(post, cur[t], beta, theta, reset == "subtract")
            if u_all is not None:
                u_all[t] = u
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
    """The fused recurrence for float32 tensors: the compiled C++ one on the CPU, the Triton one
    on a CUDA device; else None (pure torch)."""
    if x.dtype != torch.float32 or x.device.type not in ("cpu", "cuda"):
        return None
    if x.device.type == "cuda":
        from ._lif_triton import kernel as gpu_kernel

        return gpu_kernel()
    from ._lif_kernel import kernel

    return kernel()


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
        self.fc = nn.Linear(n_in, n_out)
        self.rec = nn.Linear(n_out, n_out, bias=False) if recurrent else None
        self.tau_mem_ms, self.dt_ms = float(tau_mem_ms), float(dt_ms)
        self.beta = decay_factor(dt_ms, tau_mem_ms)
        self.theta, self.reset, self.surrogate, self.alpha = theta, reset, surrogate, alpha

    def initial_state(self, batch: int, device=None, dtype=torch.float32) -> LIFState:
        u = torch.zeros(batch, self.fc.out_features, device=device, dtype=dtype)
        return LIFState(u, None if self.rec is None else torch.zeros_like(u))

    def forward(self, x: torch.Tensor, state: LIFState | None = None) -> tuple[Tensor, LIFState]:
        """``x [T, B, n_in]`` -> ``(spikes [T, B, n_out], state)``; pass the returned state
        back to continue a stream where it stopped."""
        if x.ndim != 3 or x.shape[-1] != self.fc.in_features:
            raise ValueError(
                f"expected input [T, batch, {self.fc.in_features}], got shape {tuple(x.shape)}"
            )
        if state is None:
            state = self.initial_state(x.shape[1], x.device, x.dtype)
        cur = self.fc(x)  # all time steps in one matmul
        if self.rec is None:
            spikes, u = _LIFScan.apply(
                cur, state.u, self.beta, self.theta, self.reset, self.surrogate, self.alpha
            )
            return spikes, LIFState(u)
        u = state.u
        s = torch.zeros_like(u) if state.s is None else state.s
        out = []
        for c in cur.unbind(0):
            u = lif_integrate(u, c + self.rec(s), self.beta)
            s = _SpikeFn.apply(u - self.theta, self.surrogate, self.alpha)
            u = lif_reset(u, s.detach(), self.theta, self.reset == "subtract")
            out.append(s)
        return torch.stack(out), LIFState(u, s)


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
        self.tau_mem_ms, self.dt_ms = float(tau_mem_ms), float(dt_ms)
        self.beta = decay_factor(dt_ms, tau_mem_ms)

    def initial_state(self, batch: int, device=None, dtype=torch.float32) -> LIState:
        return LIState(torch.zeros(batch, self.fc.out_features, device=device, dtype=dtype))

    def forward(self, x: torch.Tensor, state: LIState | None = None) -> tuple[Tensor, LIState]:
        """``x [T, B, n_in]`` -> ``(membrane [T, B, n_out], state)``."""
        cur = self.fc(x)
        v = torch.zeros_like(cur[0]) if state is None else state.v
        trace, v = li_scan(cur, v, self.beta)
        return trace, LIState(v)


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

    def trajectory(self, x: torch.Tensor, state: SNNState | None = None
                   ) -> tuple[Tensor, SNNState]:  # fmt: skip
        """``x [T, B, n_in]`` -> ``(output activity [T, B, classes], state)``: the output
        layer's spikes (``count``) or membrane (``max`` / ``mean``) at every step."""
        h_state, o_state = (None, None) if state is None else state
        h, h_state = self.hidden(x, h_state)
        o, o_state = self.out(h, o_state)
        return o, SNNState(h_state, o_state)

    def forward(self, x: torch.Tensor, state: SNNState | None = None
                ) -> tuple[Tensor, SNNState]:  # fmt: skip
        """``x [T, B, n_in]`` -> ``(scores [B, classes], state)``."""
        o, state = self.trajectory(x, state)
        return reduce_readout(o, self.readout), state


# ---------------------------------------------------------------------------------- component


@register_model("snn", SNNConfig)
class SNNModel(SpikeModel):
    """Spike times -> raster at ``dt_ms`` -> LIF hidden layer -> readout; see :class:`SNNConfig`.

    Streaming state (graph I/O of the export, ``[batch, units]``): ``h_state`` (hidden membrane),
    ``o_state`` (output membrane) and, for a recurrent hidden layer, ``hs_state`` (its last spikes).
    """

    score_units = "SNN readout (spike count, or max / mean of the output membrane)"

    #: early decision (:func:`~.functional.decide_by_margin`): at the first step at which the
    #: leading class's score so far leads the runner-up's by ``early_margin``
    decides_early = True
    #: runs saved before the early decision load with it off (decided at the window's end)
    optional_state = ("early_margin",)
    #: training windows the margin is fitted on (evenly spaced; bounds the fit's memory)
    CALIBRATION_WINDOWS = 4096
    #: a margin no lead reaches: the decision waits for the window's end
    NEVER = float(torch.finfo(torch.float32).max)

    def __init__(self, config: SNNConfig, n_afferents: int, max_spikes: int, n_classes: int,
                 duration_ms: float, seed: int = 0) -> None:  # fmt: skip
        super().__init__(config, n_afferents, max_spikes, n_classes, duration_ms, seed)
        with seeded(seed):  # nn.Linear draws its initial weights from the global RNG
            self.net = SNNClassifier(
                n_afferents, config.hidden, n_classes, readout=config.readout,
                recurrent=config.recurrent, tau_mem_ms=config.tau_ms, dt_ms=config.dt_ms,
            )  # fmt: skip
        self.steps = raster_steps(duration_ms, config.dt_ms) + config.extra_steps
        self.register_buffer("early_margin", torch.tensor(self.NEVER))

    def raster(self, spikes: Tensor) -> Tensor:
        """Spike times ``[B, A, k]`` -> counts ``[steps, B, A]``
        (:func:`~tactilesnn.core.spikes.spike_raster`)."""
        return spike_raster(spikes, self.config.dt_ms, self.steps)

    def scores(self, spikes: Tensor) -> Tensor:
        return self.net(self.raster(spikes))[0]

    def running_scores(self, spikes: Tensor) -> tuple[Tensor, Tensor]:
        """``(scores so far [steps, B, classes], window scores [B, classes])``."""
        out, _ = self.net.trajectory(self.raster(spikes))
        readout = self.config.readout
        return running_readout(out, readout), reduce_readout(out, readout)

    @torch.no_grad()
    def early_decision(self, spikes: Tensor) -> tuple[Tensor, Tensor]:
        run, scores = self.running_scores(spikes)
        dt, duration = self.config.dt_ms, self.duration_ms
        return decide_by_margin(run, self.early_margin, dt, duration, scores.argmax(1))

    @torch.no_grad()
    def calibrate_decision(self, spikes: Tensor) -> None:
        """The smallest margin (among 512 quantiles of the leads seen, and :attr:`NEVER`) at
        which the early class agrees with the full-window class on ``early_agreement`` of
        the training windows; found by bisection (agreement grows with the margin, except for
        noise: every margin taken is one measured to agree)."""
        n = spikes.shape[0]
        if n == 0 or self.n_classes < 2:
            return
        pick = torch.linspace(0, n - 1, min(n, self.CALIBRATION_WINDOWS)).round().long().unique()
        sub = spikes[pick]
        batch = self.batch_size(sub)
        leads, same = [], []
        for i in range(0, len(sub), batch):
            run, scores = self.running_scores(sub[i : i + batch])
            lead, leader = class_lead(run)
            leads.append(lead.T)  # [b, steps]
            same.append((leader == scores.argmax(1)).T)
        lead, same = torch.cat(leads), torch.cat(same)

        def agreement(m: float) -> float:
            hit = lead >= torch.tensor(m, dtype=lead.dtype)
            first = hit.to(torch.int32).argmax(1, keepdim=True)
            return float(torch.where(hit.any(1), same.gather(1, first)[:, 0], True).float().mean())

        positive = lead[lead > 0].double().numpy()
        cands = [self.NEVER]  # no class ever leads (e.g. no output spike): wait for the end
        if positive.size:
            q = np.unique(np.quantile(positive, np.linspace(0, 1, 513)).astype(np.float32))
            cands = [float(c) for c in q] + cands
        lo, hi = 0, len(cands) - 1  # the last always agrees
        while lo < hi:
            mid = (lo + hi) // 2
            if agreement(cands[mid]) >= self.config.early_agreement:
                hi = mid
            else:
                lo = mid + 1
        self.early_margin.fill_(cands[lo])

    def bytes_per_sample(self, afferents: int, k: int) -> int:
        units = afferents * (k + 1) + 3 * self.config.hidden + 2 * self.n_classes
        return 4 * self.steps * units

    def loss(self, spikes: Tensor, y: Tensor) -> Tensor:
        return nn.functional.cross_entropy(self.scores(spikes), y)

    def learning_rate(self) -> float:
        return self.config.lr

    @property
    def state_names(self) -> tuple[tuple[str, int], ...]:
        names = [("h_state", self.config.hidden), ("o_state", self.n_classes)]
        if self.config.recurrent:
            names.append(("hs_state", self.config.hidden))
        return tuple(names)

    def onnx_module(self) -> nn.Module:
        return _RecurrentSNNGraph(self) if self.config.recurrent else _SNNGraph(self)

    def upgrade_state(self, state: dict) -> dict:
        """Runs written before the component layer kept the network at the top level."""
        return super().upgrade_state({"net." + k: v for k, v in state.items()})

    def to_nir(self):
        from .snn_nir import snn_to_nir

        return snn_to_nir(self)


class _SNNGraph(nn.Module):
    """Exported SNN: spikes -> input current (one ``ScatterND``) -> LIF hidden layer (one
    ``LSTM`` node) -> output layer (leaky integrator in closed form, one MatMul; or another
    ``LSTM`` for spiking output) -> readout. No per-step nodes (:mod:`.onnx_ops`); traced, with
    the same functional-core arithmetic in torch. Takes and returns the streaming state.
    """

    def __init__(self, model: SNNModel) -> None:
        super().__init__()
        net = model.net
        self.dt, self.steps = float(model.config.dt_ms), int(model.steps)
        self.fc1, self.fc2 = net.hidden.fc, net.out.fc
        hidden = net.hidden.fc.out_features
        rec = net.hidden.rec.weight.detach().clone() if net.hidden.rec is not None else None
        self.register_buffer("w_rec", rec if rec is not None else torch.zeros(0, 0))
        self.register_buffer(
            "updates", self.fc1.weight.detach().t().repeat_interleave(model.max_spikes, 0)
        )
        self.beta1, self.theta1 = float(net.hidden.beta), float(net.hidden.theta)
        self.sub1 = net.hidden.reset == "subtract"
        self.lstm1 = _LSTMWeights(hidden, self.beta1, self.theta1, self.sub1, rec)
        self.beta2 = float(net.out.beta)
        self.spiking_out = isinstance(net.out, LIFLayer)
        if isinstance(net.out, LIFLayer):
            self.theta2, self.sub2 = float(net.out.theta), net.out.reset == "subtract"
            self.lstm2 = _LSTMWeights(net.out.fc.out_features, self.beta2, self.theta2, self.sub2)
        else:
            self.register_buffer("decay", li_decay_matrix(self.steps, self.beta2))
        self.readout = net.readout
        self.duration_ms = float(model.duration_ms)
        self.register_buffer("early_margin", model.early_margin.detach().clone())

    def hidden_layer(
        self, spikes: Tensor, h: Tensor, hs: Tensor | None
    ) -> tuple[Tensor, Tensor, Tensor]:
        cur = raster_current(
            spikes, self.fc1.weight, self.fc1.bias, self.updates, self.dt, self.steps
        )
        return self.lstm1(cur, h, hs, self.w_rec)

    def readout_scan(self, hid: Tensor, o: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """-> ``(scores, new output state, early class, decision_ms)``."""
        cur = self.fc2(hid)
        if self.spiking_out:
            no_rec = self.w_rec[:0, :0]  # an empty W_rec: a feed-forward layer
            out, o_new, _ = self.lstm2(cur, o, None, no_rec)
        else:
            out = li_closed(cur, o, self.beta2, self.decay)
            o_new = out[-1]
        scores = reduce_readout(out, self.readout)
        run = running_readout(out, self.readout)
        cls, t_ms = decide_by_margin(
            run, self.early_margin, self.dt, self.duration_ms, scores.argmax(1)
        )
        return scores, o_new, cls, t_ms

    def forward(self, spikes: Tensor, h: Tensor, o: Tensor):
        """-> ``(scores, h_state, o_state, early class, decision_ms)``."""
        hid, h_new, _ = self.hidden_layer(spikes, h, None)
        scores, o_new, cls, t_ms = self.readout_scan(hid, o)
        return scores, h_new, o_new, cls, t_ms


class _LSTMWeights(nn.Module):
    """The ``LSTM`` weights of one LIF layer (:func:`.onnx_ops.lif_as_lstm`) and its call.

    A feed-forward layer's units are independent, so its ``H`` units run as ``g`` rows of
    ``H / g`` units each (the batch axis grows ``g`` times): the node's per-step ``R`` product
    shrinks ``g^2`` times. onnxruntime, 100 steps of 64 units, batch 1, 1 thread: 150 us as one
    row of 64, 92 us as 4 rows of 16, 120 us as 8 rows of 8 (per-row overhead), so rows keep
    at least :attr:`MIN_UNITS` units.
    """

    MIN_UNITS = 16

    def __init__(self, hidden: int, beta: float, theta: float, subtract: bool,
                 w_rec: Tensor | None = None) -> None:  # fmt: skip
        super().__init__()
        self.hidden = int(hidden)
        self.rows = 1 if w_rec is not None else _unit_rows(self.hidden, self.MIN_UNITS)
        width = self.hidden // self.rows
        for name, value in lif_lstm_buffers(width, beta, theta, subtract, w_rec).items():
            self.register_buffer(name, value)
        self.beta, self.theta, self.subtract = beta, theta, subtract

    def forward(self, cur: Tensor, u0: Tensor, s0: Tensor | None, w_rec: Tensor):
        """``s0`` None: no spike before the first step (a feed-forward layer's state is ``u``)."""
        g = self.rows
        if g > 1:
            t, b, width = cur.shape[0], u0.shape[0], self.hidden // g
            cur = cur.reshape(t, b * g, width)
            u0 = u0.reshape(b * g, width)
            s0 = None if s0 is None else s0.reshape(b * g, width)
        spikes, u, s = lif_as_lstm(
            cur, u0, s0, w_rec, self.W, self.R, self.B, self.beta, self.theta, self.subtract
        )
        if g > 1:
            spikes = spikes.reshape(t, b, self.hidden)
            u, s = u.reshape(b, self.hidden), s.reshape(b, self.hidden)
        return spikes, u, s


def _unit_rows(hidden: int, min_units: int) -> int:
    """The most rows ``g`` dividing ``hidden`` with at least ``min_units`` units per row."""
    return max(
        g for g in range(1, hidden + 1) if hidden % g == 0 and hidden // g >= min(min_units, hidden)
    )


class _RecurrentSNNGraph(_SNNGraph):
    """:class:`_SNNGraph` with a recurrent hidden layer: its last spikes are state too."""

    def forward(self, spikes: Tensor, h: Tensor, o: Tensor, hs: Tensor):  # type: ignore[override]
        """-> ``(scores, h_state, o_state, hs_state, early class, decision_ms)``."""
        hid, h_new, hs_new = self.hidden_layer(spikes, h, hs)
        scores, o_new, cls, t_ms = self.readout_scan(hid, o)
        return scores, h_new, o_new, hs_new, cls, t_ms
