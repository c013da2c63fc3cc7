"""Tempotron (Gutig & Sompolinsky 2006; seed 001 eqs. 2-4) with an exact membrane maximum.

One tempotron per class. Membrane potential of class ``c`` (SPEC 4):

    V_c(t) = V_rest + sum_i w_ci sum_{t_i <= t} K(t - t_i),
    K(s) = V0 (exp(-s / tau) - exp(-s / tau_s)),  V0 normalises max_s K(s) to 1.

Exact maximum: after sorting the input spikes, on the interval after spike ``k`` the potential is
``V0 (a_k exp(-s/tau) - b_k exp(-s/tau_s))`` with ``s = t - t_k`` and the *rescaled* state
``a_k = sum_{j: t_j <= t_k} w_j exp(-(t_k - t_j)/tau)`` (and ``b_k`` with ``tau_s``). Every exponent is
<= 0, so nothing overflows in float32 however long the window (a naive ``exp(t/tau_s)`` running sum
overflows after ~88 tau_s). ``V`` has an interior maximum at
``s* = tau tau_s / (tau - tau_s) * ln(tau b_k / (tau_s a_k))`` when ``a_k, b_k > 0`` and the log is
positive; a candidate is kept only if it lies inside its own interval. The other candidates are the
spike times themselves, the window start (``V = V_rest``) and end.

Decision rule: the tempotron of class ``c`` fires if ``max_t V_c >= theta``. The predicted class is
the one with the largest ``V_max``: among fired classes that is the tie-break by largest ``V_max``,
and when none fired it is the class closest to firing (``fired`` tells which actually fired).

Learning rule (seed 001 eq. 4): on an error, ``dw_ci = +-lambda sum_{t_i < t_max} K(t_max - t_i)``,
``+`` when the target class did not fire, ``-`` when a non-target class fired; ``lambda`` = 0.005.

Array contract: ``spike_times`` ``[batch, inputs]`` (one spike per input) or
``[batch, inputs, k]`` (up to ``k`` spikes per input), float, in ms from the window start; ``+inf``
(or any time outside ``[0, duration_ms]``) means no spike. Outputs ``[batch, classes]``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from ..core.device import seeded_normal
from ..schema.models import TempotronConfig
from .base import SpikeModel, register_model


def psp_norm(tau_ms: float, tau_s_ms: float) -> float:
    """V0 such that the peak of ``exp(-s/tau) - exp(-s/tau_s)`` times V0 is exactly 1."""
    if not tau_ms > tau_s_ms > 0:
        raise ValueError(f"need tau > tau_s > 0, got tau={tau_ms}, tau_s={tau_s_ms}")
    s_peak = tau_ms * tau_s_ms / (tau_ms - tau_s_ms) * math.log(tau_ms / tau_s_ms)
    return 1.0 / (math.exp(-s_peak / tau_ms) - math.exp(-s_peak / tau_s_ms))


class Tempotron(nn.Module):
    """Bank of ``n_classes`` tempotrons over ``n_inputs`` afferents; times in ms.

    Args:
        n_inputs: number of afferent neurons.
        n_classes: one tempotron per class.
        duration_ms: window length; spikes outside ``[0, duration_ms]`` are ignored.
        tau_ms / tau_s_ms: membrane and synaptic time constants (tau_s defaults to tau / 4).
        theta: firing threshold (relative to ``v_rest``).
        seed: seeds the weight initialisation.
    """

    def __init__(
        self,
        n_inputs: int,
        n_classes: int,
        duration_ms: float,
        tau_ms: float = 40.0,
        tau_s_ms: float | None = None,
        theta: float = 1.0,
        v_rest: float = 0.0,
        init_std: float | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__()
        if n_inputs < 1 or n_classes < 1:
            raise ValueError(f"need n_inputs >= 1 and n_classes >= 1, got {n_inputs}, {n_classes}")
        if not duration_ms > 0:
            raise ValueError(f"duration_ms must be positive, got {duration_ms}")
        self.n_inputs, self.n_classes = int(n_inputs), int(n_classes)
        self.duration_ms = float(duration_ms)
        self.tau_ms = float(tau_ms)
        self.tau_s_ms = float(tau_s_ms) if tau_s_ms is not None else self.tau_ms / 4
        self.v0 = psp_norm(self.tau_ms, self.tau_s_ms)
        self.theta = float(theta)
        self.v_rest = float(v_rest)
        std = init_std if init_std is not None else 0.5 * self.theta / math.sqrt(self.n_inputs)
        g = torch.Generator().manual_seed(int(seed))
        self.weight = nn.Parameter(seeded_normal(self.n_classes, self.n_inputs, g).mul_(std))
        # the previous rule step (momentum); learned state, so it lives in the state_dict
        self.register_buffer("velocity", torch.zeros(self.n_classes, self.n_inputs))

    # ------------------------------------------------------------------ kernel and potential
    def kernel(self, s: torch.Tensor) -> torch.Tensor:
        """PSP kernel K(s) for lags ``s`` (ms); 0 for s < 0 and for non-finite lags."""
        ok = torch.isfinite(s) & (s >= 0)
        sc = torch.where(ok, s, torch.zeros_like(s))
        k = self.v0 * (torch.exp(-sc / self.tau_ms) - torch.exp(-sc / self.tau_s_ms))
        return torch.where(ok, k, torch.zeros_like(k))

    def _events(
        self, spike_times: torch.Tensor, weight: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Flatten to events: times ``[B, M]`` (invalid -> duration), weights ``[B, C, M]``, valid."""
        if spike_times.ndim == 2:
            spike_times = spike_times.unsqueeze(-1)
        if spike_times.ndim != 3 or spike_times.shape[1] != self.n_inputs:
            raise ValueError(
                f"expected spike times [batch, {self.n_inputs}] or [batch, {self.n_inputs}, k], "
                f"got shape {tuple(spike_times.shape)}"
            )
        if (
            not (torch.jit.is_tracing() or torch.compiler.is_exporting())
            and torch.isnan(spike_times).any()
        ):
            raise ValueError("spike times contain NaN; use +inf for 'no spike'")
        b, n, k = spike_times.shape
        t = spike_times.reshape(b, n * k).to(self.weight.dtype)
        valid = torch.isfinite(t) & (t >= 0) & (t <= self.duration_ms)
        t = torch.where(valid, t, self.duration_ms)
        weight = self.weight if weight is None else weight
        w = weight if k == 1 else weight.repeat_interleave(k, dim=1)  # [C, M]
        w = torch.where(valid.unsqueeze(1), w.unsqueeze(0), torch.zeros(()))  # [B, C, M]
        return t, w, valid

    def potential(self, spike_times: torch.Tensor, t_ms: torch.Tensor) -> torch.Tensor:
        """V at the given times ``t_ms [T]`` -> ``[batch, classes, T]`` (direct sum; for checks)."""
        t, w, _ = self._events(spike_times)
        lag = t_ms.to(t.dtype)[None, None, :] - t[:, :, None]  # [B, M, T]
        return self.v_rest + torch.einsum("bcm,bmt->bct", w, self.kernel(lag))

    # ------------------------------------------------------------------ exact maximum
    def _intervals(
        self, spike_times: torch.Tensor, weight: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        """Sorted events and, per inter-spike interval, the rescaled state and maxima."""
        t, w, _ = self._events(spike_times, weight)
        bsz = t.shape[0]
        # a sentinel at the window end makes V(duration) one of the spike-time candidates
        t = torch.cat([t, torch.full((bsz, 1), self.duration_ms, dtype=t.dtype)], dim=1)
        w = torch.cat([w, torch.zeros(bsz, self.n_classes, 1, dtype=w.dtype)], dim=2)
        t, order = torch.sort(t, dim=1)
        w = torch.gather(w, 2, order.unsqueeze(1).expand_as(w))
        lag = t.unsqueeze(2) - t.unsqueeze(1)  # [B, k, j] = t_k - t_j
        causal = lag >= 0
        lag = torch.where(causal, lag, 0.0)
        e_m = torch.where(causal, torch.exp(-lag / self.tau_ms), 0.0)
        e_s = torch.where(causal, torch.exp(-lag / self.tau_s_ms), 0.0)
        a = torch.einsum("bkj,bcj->bck", e_m, w)  # rescaled state just after spike k
        b = torch.einsum("bkj,bcj->bck", e_s, w)
        v_at = self.v0 * (a - b)
        # interval after spike k (the sentinel's is 0); slicing rather than diff exports to ONNX
        gap = torch.cat([t[:, 1:] - t[:, :-1], torch.zeros_like(t[:, :1])], dim=1).unsqueeze(1)
        # interior maxima, in the rescaled (overflow-free) form
        tau, tau_s = self.tau_ms, self.tau_s_ms
        pos = (a > 0) & (b > 0)
        ratio = torch.where(pos, (tau * b) / (tau_s * a).clamp_min(1e-30), 1.0)
        s_star = tau * tau_s / (tau - tau_s) * torch.log(ratio.clamp_min(1e-30))
        inside = pos & (s_star > 0) & (s_star < gap)
        s_safe = torch.where(inside, s_star, 0.0)
        v_int = self.v0 * (a * torch.exp(-s_safe / tau) - b * torch.exp(-s_safe / tau_s))
        v_int = torch.where(inside, v_int, -math.inf)
        return {"t": t, "a": a, "b": b, "v_at": v_at, "v_int": v_int, "s": s_safe, "gap": gap}

    def forward(self, spike_times: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Exact ``(v_max, t_max)``, each ``[batch, classes]``; t_max in ms."""
        return self._maximum(self._intervals(spike_times))

    #: bytes of intermediates one call of the exact maximum may hold (pairwise lags [M, M])
    BUDGET_BYTES = 1 << 26

    def batched_maximum(
        self, spike_times: torch.Tensor, weight: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(v_max, t_max)`` as :meth:`forward` (with ``weight`` if given), a few samples at a
        time so that the ``[events, events]`` lag matrices stay within :attr:`BUDGET_BYTES`
        (one sample of 2,000 afferents holds ~100 MB; a mini-batch of 32 at once held 7 GB)."""
        b = spike_times.shape[0]
        step = max(1, self.BUDGET_BYTES // maximum_bytes(spike_times[0].numel() if b else 0))
        if step >= b:
            return self._maximum(self._intervals(spike_times, weight))
        parts = [
            self._maximum(self._intervals(spike_times[i : i + step], weight))
            for i in range(0, b, step)
        ]
        return torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])

    def _maximum(self, iv: dict) -> tuple[torch.Tensor, torch.Tensor]:
        v_at, v_int = iv["v_at"], iv["v_int"]
        # the window start comes first so that ties resolve to the earliest time
        cand_v = torch.cat([torch.zeros_like(v_at[..., :1]), v_at, v_int], dim=2)
        tt = iv["t"].unsqueeze(1).expand_as(v_at)
        cand_t = torch.cat([torch.zeros_like(tt[..., :1]), tt, tt + iv["s"]], dim=2)
        v_max, idx = cand_v.max(dim=2)
        t_max = torch.gather(cand_t, 2, idx.unsqueeze(2)).squeeze(2)
        return v_max + self.v_rest, t_max

    @torch.no_grad()
    def decision_times(self, spike_times: torch.Tensor, levels: int = 4) -> torch.Tensor:
        """Exact first threshold-crossing time per class ``[batch, classes]`` (ms; inf = never).

        The first interval whose maximum reaches theta is found from the same closed form; on it
        V rises monotonically up to its maximum, so the crossing is bracketed by ``levels``
        rounds of a 64-point grid (each narrows the bracket 64-fold: 4 rounds, 6e-8 of the
        interval; a grid round is one batched evaluation, which exports to a few ONNX nodes
        where a bisection step per halving would need many).
        """
        return self._first_crossings(self._intervals(spike_times), levels)

    #: grid points per refinement round of :meth:`decision_times`
    GRID = 64

    def _first_crossings(self, iv: dict, levels: int) -> torch.Tensor:
        thr = self.theta  # relative to v_rest
        v_at, v_int, s_hi_int, gap = iv["v_at"], iv["v_int"], iv["s"], iv["gap"]
        v_end = torch.cat([v_at[..., 1:], v_at[..., -1:]], dim=2)  # V at the interval's end
        reaches = (v_int >= thr) | (v_end >= thr)
        any_k = reaches.any(dim=2)
        k = reaches.to(torch.int32).argmax(dim=2, keepdim=True)  # first interval reaching theta

        def pick(x: torch.Tensor) -> torch.Tensor:
            return torch.gather(x.expand_as(v_at), 2, k).squeeze(2)

        a, b = pick(iv["a"]).unsqueeze(-1), pick(iv["b"]).unsqueeze(-1)
        # V rises on [0, hi] and V(hi) >= theta: the crossing is in (lo, lo + width]
        width = torch.where(pick(v_int) >= thr, pick(s_hi_int), pick(gap))
        lo = width * 0.0
        frac = torch.arange(1, self.GRID + 1, dtype=width.dtype) / self.GRID
        for _ in range(levels):
            s = lo.unsqueeze(-1) + width.unsqueeze(-1) * frac
            v = self.v0 * (a * torch.exp(-s / self.tau_ms) - b * torch.exp(-s / self.tau_s_ms))
            below = (v < thr).sum(-1).clamp_max(self.GRID - 1)  # grid points before the crossing
            width = width / self.GRID
            lo = lo + width * below.to(width.dtype)
        start_v = pick(v_at)
        t_k = pick(iv["t"].unsqueeze(1))
        t_cross = torch.where(start_v >= thr, t_k, t_k + lo + width)
        return torch.where(any_k, t_cross, math.inf)

    def predict_early(
        self, spike_times: torch.Tensor, levels: int = 4
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Decide at the first class to fire, skipping the rest of the window.

        Returns ``(classes [batch], decision_ms [batch])``; a sample where no class fires falls
        back to the largest V_max at the window end (``decision_ms`` = duration).
        """
        return self.with_decision(spike_times, levels)[1:]

    @torch.no_grad()
    def with_decision(
        self, spike_times: torch.Tensor, levels: int = 4
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(v_max [batch, classes], early class [batch], decision_ms [batch])`` from one pass
        over the spike intervals (what the exported graph returns, see :meth:`predict_early`)."""
        iv = self._intervals(spike_times)
        v_max = self._maximum(iv)[0]
        first, cls = self._first_crossings(iv, levels).min(dim=1)
        fired = torch.isfinite(first)
        early = torch.where(fired, cls, v_max.argmax(dim=1))
        return v_max, early, torch.where(fired, first, self.duration_ms)

    def fired(self, v_max: torch.Tensor) -> torch.Tensor:
        return v_max >= self.theta + self.v_rest

    def predict(self, spike_times: torch.Tensor) -> torch.Tensor:
        """Class index per sample (largest V_max; see the module docstring)."""
        v_max, _ = self(spike_times)
        return v_max.argmax(dim=1)

    # ------------------------------------------------------------------ learning rule
    @torch.no_grad()
    def rule_update(
        self,
        spike_times: torch.Tensor,
        y: torch.Tensor,
        lr: float = 0.005,
        momentum: float = 0.0,
        margin: float = 0.0,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Apply the tempotron rule for one mini-batch (updates summed over its samples).

        With ``momentum`` mu > 0 the step is ``dw(n) = lr * rule + mu * dw(n - 1)`` (Gutig &
        Sompolinsky 2006 used mu = 0.99 with per-sample updates); the previous step is kept in
        the ``velocity`` buffer. With ``margin`` kappa > 0 the rule also acts on near misses: a target
        tempotron with ``V_max < theta + kappa`` is potentiated and a non-target one with
        ``V_max >= theta - kappa`` is depressed, which keeps decisions away from the threshold
        (kappa = 0 is the seed's rule).

        Returns ``(n_errors, predictions)``: tempotron errors (missed target fires plus false
        fires, over samples x classes) and the predicted classes before the update.
        """
        v_max, t_max = self.batched_maximum(spike_times)
        # a tempotron whose potential never rises above rest has t_max at the window start, where
        # no input has arrived: the rule would give it no update ever again. Its potentiation is
        # taken where its inputs coincide most (the maximum of sum |w_i| K(t - t_i)) instead.
        silent = v_max <= self.v_rest
        if bool(silent.any()):
            _, t_coinc = self.batched_maximum(spike_times, self.weight.abs())
            t_max = torch.where(silent, t_coinc, t_max)
        thr = self.theta + self.v_rest
        target = nn.functional.one_hot(y, self.n_classes).bool()
        fired = self.fired(v_max)
        n_err = ((target & ~fired) | (~target & fired)).sum()
        up = target & (v_max < thr + margin)
        down = ~target & (v_max >= thr - margin)
        sign = up.to(v_max.dtype) - down.to(v_max.dtype)  # [B, C]
        if spike_times.ndim == 2:
            spike_times = spike_times.unsqueeze(-1)
        bsz, n, k = spike_times.shape
        ts = spike_times.reshape(bsz, 1, n * k).to(v_max.dtype)
        lag = t_max.unsqueeze(2) - ts  # [B, C, M]
        ok = torch.isfinite(ts) & (ts >= 0) & (ts <= self.duration_ms) & (lag > 0)
        kern = torch.where(ok, self.kernel(lag), torch.zeros_like(lag))
        dw = lr * torch.einsum("bc,bcm->cm", sign, kern).reshape(self.n_classes, n, k).sum(-1)
        if momentum:
            dw = dw + momentum * self.velocity
            self.velocity.copy_(dw)
        self.weight += dw
        return n_err, v_max.argmax(dim=1)


def maximum_bytes(slots: int) -> int:
    """Peak intermediate bytes of the exact maximum for one sample of ``slots`` spike slots:
    it holds ``[events, events]`` pairwise lags (the slots and the window-end sentinel)."""
    events = slots + 1
    return 4 * 6 * events * events


# ---------------------------------------------------------------------------------- component


@register_model("tempotron", TempotronConfig)
class TempotronClassifier(SpikeModel):
    """Exact tempotrons (one per class); scores are ``V_max`` per class (threshold ``theta``)."""

    score_units = "tempotron V_max per class (fires at theta)"
    decides_early = True

    def __init__(self, config: TempotronConfig, n_afferents: int, max_spikes: int,
                 n_classes: int, duration_ms: float, seed: int = 0) -> None:  # fmt: skip
        super().__init__(config, n_afferents, max_spikes, n_classes, duration_ms, seed)
        self.net = Tempotron(
            n_afferents, n_classes, duration_ms=duration_ms, tau_ms=config.tau_ms,
            tau_s_ms=config.tau_s_ms, theta=config.theta, seed=seed,
        )  # fmt: skip
        self.learns_by_rule = config.learning == "rule"

    def scores(self, spikes: Tensor) -> Tensor:
        return self.net(spikes)[0]

    def bytes_per_sample(self, afferents: int, k: int) -> int:
        return maximum_bytes(afferents * k)

    def early_decision(self, spikes: Tensor) -> tuple[Tensor, Tensor]:
        return self.net.predict_early(spikes)

    def rule_update(self, spikes: Tensor, y: Tensor, epoch: int) -> None:
        c = self.config
        lr = c.lr / (1.0 + c.lr_decay * epoch)
        self.net.rule_update(spikes, y, lr=lr, momentum=c.momentum, margin=c.margin)

    def learning_rate(self) -> float:
        return self.config.adam_lr

    def loss(self, spikes: Tensor, y: Tensor) -> Tensor:
        """Hinge on the exact V_max around theta with the margin (differentiable)."""
        v = self.net(spikes)[0]
        tgt = nn.functional.one_hot(y, self.n_classes).to(v.dtype)
        thr, m = self.config.theta, self.config.margin
        hinge = tgt * torch.relu(thr + m - v) + (1 - tgt) * torch.relu(v - thr + m)
        return hinge.sum(1).mean()

    def onnx_module(self) -> nn.Module:
        return _ScoresAndDecision(self.net)

    def to_nir(self):
        raise ValueError(
            "the exact tempotron has no NIR equivalent (its score is the continuous-time maximum "
            "of a double-exponential PSP sum, not a NIR graph); export it with ONNX"
        )

    def upgrade_state(self, state: dict) -> dict:
        """Runs written before the component layer kept ``weight`` at the top level and the
        momentum outside the state (it restarts at zero)."""
        return super().upgrade_state({"net." + k: v for k, v in state.items()})


class _ScoresAndDecision(nn.Module):
    """``spikes -> (V_max [B, classes], early class [B], decision_ms [B])``.

    Three grid rounds (not the torch default of four) bracket the crossing within 64^-3 = 3.8e-6
    of its interval, inside the export's check (1e-3 ms or 1e-5 of the window); each round left
    out saves ~20 graph nodes.
    """

    LEVELS = 3

    def __init__(self, net: Tempotron) -> None:
        super().__init__()
        self.net = net

    def forward(self, spikes: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        return self.net.with_decision(spikes, self.LEVELS)
