"""Leaky-integrator readout: exact membrane traces at fixed times -> linear softmax: ``readout``.

Each afferent drives a leaky integrator (time constant ``tau_ms``) that jumps by 1 at each of its
spikes; its membrane ``m_a(t) = sum_k exp(-(t - t_ak) / tau) H(t - t_ak)`` is read, in closed
form, at ``n_times`` instants ``t_j = (j + 1) D / n_times`` across the window. The class scores
are a linear map of ``log1p`` of those ``afferents x n_times`` traces, trained with Adam on
cross-entropy (weight decay ``weight_decay``). Cost per window is ``O(afferents x spikes x
n_times x classes)``: linear in the inputs (the exact tempotron's ``V_max`` holds pairwise lags,
quadratic in them), and the softmax trains 20-50 classes as easily as 2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor, nn

from .._checks import check_int, check_positive, check_range
from .base import SpikeModel, register_model


@dataclass(frozen=True)
class ReadoutConfig:
    tau_ms: float = 100.0
    n_times: int = 8
    lr: float = 0.01
    weight_decay: float = 1e-4

    FLAGS: ClassVar[dict[str, str]] = {
        "readout_tau_ms": "tau_ms",
        "readout_times": "n_times",
        "readout_lr": "lr",
        "readout_weight_decay": "weight_decay",
    }
    HELP: ClassVar[dict[str, str]] = {
        "tau_ms": "leaky-integrator time constant of the readout traces (ms)",
        "n_times": "instants across the window at which the traces are read",
        "lr": "Adam learning rate of the readout",
        "weight_decay": "L2 penalty on the readout weights",
    }

    def __post_init__(self) -> None:
        check_positive(self.tau_ms, "tau_ms")
        check_int(self.n_times, "n_times", 1)
        check_positive(self.lr, "lr")
        check_range(self.weight_decay, "weight_decay", 0.0, 1.0)


def trace_features(spikes: Tensor, times_ms: Tensor, tau_ms: float) -> Tensor:
    """Spike times ``[B, A, k]`` (ms, inf = none) -> traces ``[B, A, n_times]`` at ``times_ms``."""
    lag = times_ms.view(1, 1, 1, -1) - spikes.unsqueeze(-1)  # [B, A, k, T]; inf spikes -> -inf
    live = lag >= 0
    kern = torch.exp(-torch.where(live, lag, torch.zeros_like(lag)) / tau_ms)
    return torch.where(live, kern, torch.zeros_like(kern)).sum(2)


@register_model("readout", ReadoutConfig)
class LIReadout(SpikeModel):
    """Leaky-integrator traces at fixed times -> linear class scores; see the module docstring."""

    score_units = "logits of a softmax over classes"

    def __init__(self, config: ReadoutConfig, n_afferents: int, max_spikes: int, n_classes: int,
                 duration_ms: float, seed: int = 0) -> None:  # fmt: skip
        super().__init__(config, n_afferents, max_spikes, n_classes, duration_ms, seed)
        g = torch.Generator().manual_seed(int(seed))
        n_in = n_afferents * config.n_times
        self.linear = nn.Linear(n_in, n_classes)
        with torch.no_grad():
            self.linear.weight.copy_(torch.randn(n_classes, n_in, generator=g) / math.sqrt(n_in))
            self.linear.bias.zero_()
        times = (torch.arange(config.n_times, dtype=torch.float32) + 1) * (
            duration_ms / config.n_times
        )
        self.register_buffer("times_ms", times)

    def features(self, spikes: Tensor) -> Tensor:
        return torch.log1p(trace_features(spikes, self.times_ms, self.config.tau_ms)).flatten(1)

    def scores(self, spikes: Tensor) -> Tensor:
        return self.linear(self.features(spikes))

    def bytes_per_sample(self, afferents: int, k: int) -> int:
        return 4 * 4 * afferents * k * self.config.n_times

    def loss(self, spikes: Tensor, y: Tensor) -> Tensor:
        ce = nn.functional.cross_entropy(self.scores(spikes), y)
        return ce + self.config.weight_decay * self.linear.weight.pow(2).sum()

    def learning_rate(self) -> float:
        return self.config.lr

    def onnx_module(self) -> nn.Module:
        return self
