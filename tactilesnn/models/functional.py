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

Exported graphs use two equivalent forms that need no per-step ONNX nodes (each per-step node
costs onnxruntime ~0.3 us, a ``Loop`` iteration ~4 us): the leaky integrator in closed form,
``v = L i`` with ``L[t, s] = beta^(t - s)`` (:func:`li_closed`), and the LIF recurrence as the cell
of one ONNX ``LSTM`` operator (:func:`lif_lstm_parameters`).

Array contract: currents ``[T, batch, units]`` (time-major), states ``[batch, units]``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor, nn


class LIFState(NamedTuple):
    """A LIF layer's state: membrane ``u [batch, units]`` (in units of the threshold) and, for a
    recurrent layer, its last spikes ``s [batch, units]`` (None for a feed-forward layer)."""

    u: Tensor
    s: Tensor | None = None


class LIState(NamedTuple):
    """A leaky integrator's state: membrane ``v [batch, units]``."""

    v: Tensor


class SNNState(NamedTuple):
    """The state of a hidden LIF layer and its readout (LIF spikes or leaky integrator)."""

    hidden: LIFState
    out: LIFState | LIState


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


def lif_scan_op(cur: Tensor, u0: Tensor, beta: float, theta: float, subtract: bool):
    """:func:`lif_scan` as one scan operator (``torch.export`` writes an ONNX ``Scan``; not
    scriptable), the same step."""
    from torch._higher_order_ops.scan import scan

    def step(u: Tensor, c: Tensor) -> tuple[Tensor, Tensor]:
        s, u, _ = lif_step(u, c, beta, theta, subtract)
        return u, s

    u, spikes = scan(step, u0, cur)
    return spikes, u


def li_scan_op(cur: Tensor, v0: Tensor, beta: float):
    """:func:`li_scan` as one scan operator (see :func:`lif_scan_op`)."""
    from torch._higher_order_ops.scan import scan

    def step(v: Tensor, c: Tensor) -> tuple[Tensor, Tensor]:
        v = li_step(v, c, beta)
        return v, v.clone()  # (a scan's carry and output may not alias)

    v, out = scan(step, v0, cur)
    return out, v


def li_decay_matrix(steps: int, beta: float, dtype: torch.dtype = torch.float32) -> Tensor:
    """``L [T, T]`` with ``L[t, s] = beta^(t - s)`` for ``s <= t``, else 0 (computed in float64)."""
    t = torch.arange(int(steps), dtype=torch.float64)
    lag = t.view(-1, 1) - t.view(1, -1)
    decay = torch.exp(lag.clamp_min(0.0) * math.log(beta)) if beta > 0 else (lag == 0).double()
    return torch.where(lag >= 0, decay, torch.zeros_like(decay)).to(dtype)


def li_closed(cur: Tensor, v0: Tensor, beta: float, decay: Tensor) -> Tensor:
    """:func:`li_scan` in closed form: ``v_t = sum_{s<=t} beta^(t-s) i_s + beta^(t+1) v0``.

    ``decay``: :func:`li_decay_matrix` ``(T, beta)``; returns the membrane ``[T, B, H]`` (the
    final state is its last step). One matrix product instead of ``T`` steps; equal to the scan
    up to float rounding (the terms are summed in another order).
    """
    steps, units = cur.shape[0], cur.shape[-1]
    # constant shapes ([T, -1, H]): no run-time size arithmetic in the exported graph
    out = torch.matmul(decay, cur.reshape(steps, -1)).reshape(steps, -1, units)
    # beta^(t+1) v0 = (beta L[t, 0]) v0: v0 one step later (li_step with no input), decayed
    return out + (beta * decay[:, :1]).unsqueeze(-1) * v0


#: an LSTM gate held fully open: the gates' hard sigmoid (slope 1) clips 30 to exactly 1.0
GATE_OPEN = 30.0
#: a gate held shut by a spike: the hard sigmoid clips beta - 1e4 to exactly 0
GATE_SHUT = 1e4


def lif_lstm_parameters(
    hidden: int,
    beta: float,
    theta: float,
    subtract: bool,
    w_rec: Tensor | None = None,
) -> dict[str, Tensor | list]:
    """The LIF recurrence (:func:`lif_scan`, :func:`lif_rec_scan`) as one ONNX ``LSTM`` cell.

    The cell state ``c`` carries the membrane *before* reset ``v_t`` and the output ``h`` the
    spikes ``s_t``; the input ``x_t`` is the layer's current ``i_t [H]`` (gate order i, o, f, c)::

        i = o = hardsigmoid(30) = 1                   (open gates)
        f = hardsigmoid(beta) = beta                  (subtract) or
            hardsigmoid(beta - 1e4 s_{t-1})           (zero: a spike empties the membrane)
        g = affine(i_t + R s_{t-1}),  R = -beta theta I (subtract) [+ W_rec]
        c_t = f c_{t-1} + g = beta u_{t-1} + i_t (+ W_rec s_{t-1})   = v_t
        h_t = hardsigmoid(K c_t + 1 - K theta),  K = 2^24 / theta

    For ``theta = 1`` the last line is the exact step ``H(v_t - theta)``: ``K c`` is exact (a
    power of two), so the sum is an integer <= 0 below the threshold and >= 1 at or above it.
    The gates are hard sigmoids (``hardsigmoid(x) = max(0, min(1, x))``: exact) with the leak
    ``beta`` as the forget gate's bias, not sigmoids of ``logit beta``: onnxruntime's vectorised
    sigmoid is an approximation, and its rounding of ``beta`` made membranes within it of the
    threshold spike a step apart from torch's (141 steps x 64 units x 2,000 windows of random
    currents: 1-5 spikes flipped in 1-3 windows with sigmoid gates, 0-3 in 0-1 with hard ones;
    the rest is the sum's order).
    The streaming state maps as ``c_0 = u_0 + theta s_0`` (subtract; ``u_0`` for zero),
    ``h_0 = s_0``, and back as ``u_T = c_T - theta h_T`` (``c_T (1 - h_T)`` for zero).

    Returns ``W [1, 4H, H]``, ``R [1, 4H, H]``, ``B [1, 8H]`` (float32) and the activation
    attributes (``activations``, ``activation_alpha``, ``activation_beta``) of the node.
    """
    h = int(hidden)
    if not 0.0 < beta < 1.0:
        raise ValueError(f"beta must be in (0, 1) for the LSTM form, got {beta}")
    eye = torch.eye(h, dtype=torch.float64)
    w = torch.zeros(1, 4 * h, h, dtype=torch.float64)
    r = torch.zeros(1, 4 * h, h, dtype=torch.float64)
    b = torch.zeros(1, 8 * h, dtype=torch.float64)
    w[0, 3 * h :] = eye
    b[0, : 2 * h] = GATE_OPEN
    b[0, 2 * h : 3 * h] = beta
    if subtract:
        r[0, 3 * h :] = -beta * theta * eye
    else:
        r[0, 2 * h : 3 * h] = -GATE_SHUT * eye
    if w_rec is not None:
        r[0, 3 * h :] += w_rec.detach().double()
    return {"W": w.float(), "R": r.float(), "B": b.float(), **lif_lstm_activations(theta)}


def lif_lstm_activations(theta: float) -> dict[str, list]:
    """The activation attributes of :func:`lif_lstm_parameters`' node: gates hard-sigmoid of
    slope 1 (a clip to [0, 1]), cell input affine (identity), output hard-sigmoid of slope
    ``K = 2^24 / theta`` (the threshold step)."""
    k = 2.0**24 / theta
    return {
        "activations": ["HardSigmoid", "Affine", "HardSigmoid"],
        "activation_alpha": [1.0, 1.0, k],
        "activation_beta": [0.0, 0.0, 1.0 - k * theta],
    }


def reduce_readout(out: Tensor, readout: str) -> Tensor:
    """Output activity ``[T, B, classes]`` -> scores: ``count`` (sum), ``max`` or ``mean``."""
    if readout == "count":
        return out.sum(0)
    if readout == "max":
        return out.amax(0)
    return out.mean(0)


#: the longest running maximum exported as one max-pool (its work grows with steps squared)
POOLED_MAX_STEPS = 256


def prefix_max(x: Tensor) -> Tensor:
    """Running maximum over the leading (time) axis: ``out[t] = max(x[0..t])``.

    Eager: Hillis-Steele doubling, ``ceil(log2 T)`` elementwise maxima (a max is exact, so this
    equals ``torch.cummax`` bit for bit). Exported (traced) with ``[T, B, C]`` and ``T <=``
    :data:`POOLED_MAX_STEPS`: a causal max-pool, ``-inf`` padded by ``T - 1`` steps and ``T``
    wide (:func:`pooled_prefix_max`), as ONNX has no running maximum: ``Transpose, Pad, MaxPool,
    Transpose`` instead of ~5 nodes per doubling (onnxruntime, 100 steps of 2 classes, the call
    with nothing else: 5.2 vs 16.8 us). Measured slower: a masked maximum over a ``[T, T]`` grid
    (79-88 us)."""
    exporting = torch.jit.is_tracing() or torch.compiler.is_exporting()  # (as the tempotron's)
    if exporting and x.ndim == 3 and x.shape[0] <= POOLED_MAX_STEPS:
        return pooled_prefix_max(x)
    k = 1
    while k < x.shape[0]:
        x = torch.cat([x[:k], torch.maximum(x[k:], x[:-k])], 0)
        k *= 2
    return x


def pooled_prefix_max(x: Tensor) -> Tensor:
    """:func:`prefix_max` of ``x [T, B, C]`` as one max-pool over time (``T`` wide, causal)."""
    steps = x.shape[0]
    y = nn.functional.pad(x.permute(1, 2, 0), (steps - 1, 0), value=float("-inf"))
    return nn.functional.max_pool1d(y, steps, stride=1).permute(2, 0, 1)


def running_readout(out: Tensor, readout: str) -> Tensor:
    """Output activity ``[T, B, classes]`` -> ``[T, B, classes]``: the scores the window would
    have if it ended after step ``t`` (:func:`reduce_readout` of ``out[: t + 1]``; ``mean`` is
    the sum so far over the window's ``T`` steps, so the last step is the window's score)."""
    if readout == "max":
        return prefix_max(out)
    total = torch.cumsum(out, 0)
    return total if readout == "count" else total / out.shape[0]


def class_lead(running: Tensor) -> tuple[Tensor, Tensor]:
    """Scores ``[..., classes]`` (two or more) -> ``(leading score - runner-up's, leading
    class)``, both ``[...]``."""
    top = running.topk(2, dim=-1).values
    return top[..., 0] - top[..., 1], running.argmax(-1)


def decide_by_margin(
    running: Tensor, margin: Tensor, dt_ms: float, duration_ms: float, final: Tensor
) -> tuple[Tensor, Tensor]:
    """Early decision on running scores ``[T, B, classes]``: at the first step whose leading
    class leads the runner-up by ``>= margin`` (score units) -> ``(class [B] int64,
    decision_ms [B])``, the step's end ``(t + 1) dt`` capped at the window; a window that never
    does gets its full-window class ``final [B]`` at ``duration_ms``."""
    if running.shape[-1] < 2:  # one class: nothing to wait for
        return final, torch.full(final.shape, min(dt_ms, duration_ms), dtype=running.dtype)
    lead, leaders = class_lead(running)
    hit = (lead >= margin).to(torch.int32)  # [T, B]
    first = hit.argmax(0)  # the first hit (ties: the first index)
    decided = hit.amax(0) > 0
    leader = leaders.gather(0, first.unsqueeze(0)).squeeze(0)
    # each step's end, capped: a table (a constant in a graph) read at the first hit
    ends = torch.arange(1, running.shape[0] + 1, dtype=running.dtype, device=running.device)
    t_ms = torch.clamp(ends * dt_ms, max=duration_ms)[first]
    return torch.where(decided, leader, final), torch.where(decided, t_ms, duration_ms)


class StreamState(NamedTuple):
    """A stream model's state: hidden membranes ``h [batch, H]`` (and, recurrent, its last
    spikes ``hs``), readout membranes ``v [batch, classes]``, and ``quiet [batch, 1]``: frames
    since the last input spike."""

    h: Tensor
    v: Tensor
    quiet: Tensor
    hs: Tensor | None = None


def quiet_reset(x: Tensor, quiet: Tensor, quiet_frames: float) -> tuple[Tensor, Tensor]:
    """Frames without an input spike counted on ``x [B, A]``: ``(keep [B, 1], quiet [B, 1])``;
    ``keep`` is 0 once ``quiet_frames`` silent frames have passed (release: the stream's state
    returns to rest), else 1."""
    active = torch.clamp(x.amax(-1, keepdim=True), max=1.0)  # spike counts: 0 or 1
    quiet = (quiet + 1.0) * (1.0 - active)
    return (quiet < quiet_frames).to(x.dtype), quiet


def stream_step(
    cur: Tensor,
    x: Tensor,
    state: StreamState,
    w_out: Tensor,
    b_out: Tensor,
    beta_h: float,
    beta_o: float,
    quiet_frames: float,
    w_rec: Tensor | None = None,
    spike_fn=None,
) -> tuple[Tensor, StreamState]:
    """One frame of the stream SNN: the input spikes ``x [B, A]`` and their current ``cur
    [B, H]`` (``x W_in^T + b_in``: dense or a gather of the rows that fired) -> the hidden LIF
    layer (threshold 1, reset by subtraction; ``+ hs W_rec^T`` where recurrent) -> the leaky
    readout ``v <- beta_o v + s W_out^T + b_out``. The state returns to rest after
    ``quiet_frames`` frames with no input spike (:func:`quiet_reset`). Returns ``(hidden
    spikes, next state)``; the scores are ``state.v``. ``spike_fn``: ``u - theta`` -> spikes
    with a surrogate gradient (training; the reset detached), else the step function."""
    keep, quiet = quiet_reset(x, state.quiet, quiet_frames)
    h, v = state.h * keep, state.v * keep
    if w_rec is not None and state.hs is not None:
        cur = cur + torch.matmul(state.hs * keep, w_rec.t())
    if spike_fn is None:
        s, h, _ = lif_step(h, cur, beta_h, 1.0, True)
    else:
        m = lif_integrate(h, cur, beta_h)
        s = spike_fn(m - 1.0)
        h = lif_reset(m, s.detach(), 1.0, True)
    v = li_step(v, torch.matmul(s, w_out.t()) + b_out, beta_o)
    return s, StreamState(h, v, quiet, s if w_rec is not None else None)
