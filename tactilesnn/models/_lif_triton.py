"""Fused LIF recurrence for CUDA tensors (float32) in Triton: the whole time loop in one kernel
launch, one program per block of neurons, with the same interface as the CPU extension
(:mod:`tactilesnn.models._lif_kernel`: ``lif_forward`` / ``lif_backward``).

On a GPU the pure-torch recurrence launches three small kernels per step (500 steps: ~1,500
launches), which bound it at 90.8 ms forward against SpikingJelly's 0.6 ms (H200,
``bench snn --device cuda``). Used when the tensors are on a CUDA device and Triton is
importable (it comes with CUDA builds of torch); otherwise the pure-torch path runs. Tested
against that path on a GPU (``tests/models/test_lif_triton.py``, skipped without one).
"""

from __future__ import annotations

import logging

import torch

log = logging.getLogger("tactilesnn")
BLOCK = 256

try:  # CUDA builds of torch ship Triton; CPU builds do not
    import triton
    import triton.language as tl
except ImportError:  # pragma: no cover - depends on the torch build
    triton = None


if triton is not None:

    @triton.jit
    def _forward(cur, u0, spikes, post, u_all, N, T, beta, theta,
                 SUBTRACT: tl.constexpr, SAVE: tl.constexpr, B: tl.constexpr):  # fmt: skip
        offs = tl.program_id(0).to(tl.int64) * B + tl.arange(0, B)
        mask = offs < N
        p = tl.load(u0 + offs, mask=mask, other=0.0)
        for t in range(T):
            row = t.to(tl.int64) * N + offs
            u = beta * p + tl.load(cur + row, mask=mask, other=0.0)
            if SAVE:
                tl.store(u_all + row, u, mask=mask)
            sp = tl.where(u >= theta, 1.0, 0.0)
            tl.store(spikes + row, sp, mask=mask)
            if SUBTRACT:
                p = u - sp * theta
            else:
                p = tl.where(sp > 0.0, 0.0, u)
        tl.store(post + offs, p, mask=mask)

    @triton.jit
    def _backward(g_spikes, u_all, spikes, g_last, g, N, T, beta, theta, alpha,
                  SUBTRACT: tl.constexpr, KIND: tl.constexpr, B: tl.constexpr):  # fmt: skip
        offs = tl.program_id(0).to(tl.int64) * B + tl.arange(0, B)
        mask = offs < N
        carry = tl.load(g_last + offs, mask=mask, other=0.0)
        for i in range(T):
            row = (T - 1 - i).to(tl.int64) * N + offs
            x = tl.load(u_all + row, mask=mask, other=0.0) - theta
            if KIND == 0:  # fast sigmoid
                d = alpha * tl.abs(x) + 1.0
                sg = 1.0 / (d * d)
            else:  # arctan
                z = 1.5707963267948966 * alpha * x
                sg = 0.5 * alpha / (1.0 + z * z)
            if SUBTRACT:
                keep = 1.0
            else:
                keep = 1.0 - tl.load(spikes + row, mask=mask, other=0.0)
            v = tl.load(g_spikes + row, mask=mask, other=0.0) * sg + carry * keep
            tl.store(g + row, v, mask=mask)
            carry = beta * v


class TritonLIF:
    """``lif_forward`` / ``lif_backward`` as in the CPU extension, for CUDA float32 tensors."""

    @staticmethod
    def lif_forward(cur: torch.Tensor, u0: torch.Tensor, beta: float, theta: float,
                    subtract: bool, save: bool) -> list[torch.Tensor]:  # fmt: skip
        cur = cur.contiguous()
        steps = cur.shape[0]
        n = cur.numel() // steps if steps else 0
        spikes = torch.empty_like(cur)
        u_all = torch.empty_like(cur) if save else torch.empty(0, device=cur.device)
        post = torch.empty_like(cur[0]) if steps else u0.clone()
        u0 = u0.expand_as(cur[0]).contiguous().to(cur.dtype) if steps else u0
        if steps and n:
            _forward[(triton.cdiv(n, BLOCK),)](cur, u0, spikes, post, u_all, n, steps, float(beta),
                                               float(theta), SUBTRACT=bool(subtract),
                                               SAVE=bool(save), B=BLOCK)  # fmt: skip
        return [spikes, post, u_all]

    @staticmethod
    def lif_backward(g_spikes: torch.Tensor, u_all: torch.Tensor, spikes: torch.Tensor,
                     g_last: torch.Tensor, beta: float, theta: float, subtract: bool, kind: int,
                     alpha: float) -> torch.Tensor:  # fmt: skip
        g_spikes = g_spikes.contiguous()
        steps = g_spikes.shape[0]
        n = g_spikes.numel() // steps if steps else 0
        g = torch.empty_like(g_spikes)
        if steps and n:
            _backward[(triton.cdiv(n, BLOCK),)](g_spikes, u_all, spikes,
                                                g_last.expand_as(g_spikes[0]).contiguous(), g, n,
                                                steps, float(beta), float(theta), float(alpha),
                                                SUBTRACT=bool(subtract), KIND=int(kind),
                                                B=BLOCK)  # fmt: skip
        return g


def kernel() -> TritonLIF | None:
    """The Triton recurrence, or None where Triton is missing (pure torch then)."""
    return TritonLIF() if triton is not None else None
