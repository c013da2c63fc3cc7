"""Convolutional surrogate-gradient SNN for taxel arrays: ``csnn``.

A tactile array is an image: neighbouring taxels see the same contact. The spike raster's grid
afferents ``[steps, B, taxels x polarity]`` (taxel-major, row-major taxels: the events file layout,
``<taxel>:on``, ``<taxel>:off``) are arranged as ``[B, polarity, rows, cols]`` at every step and go
through two 3 x 3 convolutions, each into LIF neurons (``u_t = beta u_{t-1} + i_t``, threshold 1,
subtractive reset, ``beta = exp(-dt / tau)``; the same :mod:`~tactilesnn.models.functional` step as
the dense SNN), with 2 x 2 average pooling between them; their spikes (plus any afferents beyond
the grid, e.g. clock afferents) drive a leaky-integrator readout whose maximum over time is the
class score. The convolutions are applied to all steps at once; only the membranes recur.

``grid = "auto"``: a square grid of ``n x n`` taxels with 2 or 1 polarities, the one that leaves
the fewest afferents over (at most 16, e.g. clock afferents; ties: 2 polarities); otherwise set
``"ROWSxCOLS"``. Taxels that do not fill a grid in row-major order (an irregular layout, a subset,
any order) give ``cells``: taxel ``i`` sits in row-major cell ``cells[i]`` of the grid, the other
cells stay at zero (:func:`~tactilesnn.core.layout.place_on_grid` derives both from the taxels'
positions; ``train --data`` does so for an event file with ``taxel_xy``).
"""

from __future__ import annotations

import math
from typing import ClassVar

import torch
from torch import Tensor, nn

from ..core.spikes import raster_steps, spike_raster
from ..schema.models import ConvSNNConfig, parse_grid
from .base import SpikeModel, register_model, seeded
from .functional import decay_factor, li_scan, li_scan_op, lif_scan, lif_scan_op, reduce_readout
from .snn import _LIFScan

#: afferents beyond an inferred grid (clock afferents) that ``grid = "auto"`` accepts
MAX_EXTRA = 16


def grid_layout(n_afferents: int, grid: str, taxels: int = 0) -> tuple[int, int, int, int]:
    """``(polarities, rows, cols, extra afferents)`` of the spike input (``taxels``: how many
    afferent taxels sit on the grid; 0 = every cell); ValueError if none fits."""
    if grid != "auto":
        rows, cols = parse_grid(grid)
        taxels = taxels or rows * cols
        for pol in (2, 1):
            if pol * taxels <= n_afferents and n_afferents - pol * taxels <= MAX_EXTRA:
                return pol, rows, cols, n_afferents - pol * taxels
        raise ValueError(f"{taxels} taxels on a {rows}x{cols} grid do not match {n_afferents} "
                         f"afferents (at most {MAX_EXTRA} beyond the grid, e.g. clock afferents; "
                         "set level_neurons 0)")  # fmt: skip
    fits = []
    for pol in (2, 1):
        side = math.isqrt(n_afferents // pol)
        if side >= 2 and n_afferents - pol * side * side <= MAX_EXTRA:
            fits.append((n_afferents - pol * side * side, pol, side))
    if fits:  # the fewest afferents left over, then 2 polarities
        extra, pol, side = min(fits, key=lambda f: (f[0], -f[1]))
        return pol, side, side, extra
    raise ValueError(
        f"{n_afferents} afferents do not form a square taxel grid (at most {MAX_EXTRA} beyond it, "
        "e.g. clock afferents; level-code afferents need level_neurons 0); set --csnn-grid ROWSxCOLS"
    )


def random_shift(g: Tensor, shift: int) -> Tensor:
    """Move each sample's grid ``g [T, B, P, R, C]`` by a random whole number of taxels in
    ``[-shift, shift]`` along rows and columns (zeros shifted in): a contact a taxel or two away
    is the same contact (training augmentation; global torch RNG, seeded by the trainer)."""
    rows, cols, batch = g.shape[3], g.shape[4], g.shape[1]
    pad = nn.functional.pad(g, (shift, shift, shift, shift))
    off = torch.randint(0, 2 * shift + 1, (2, batch))
    out = torch.empty_like(g)
    for dr in range(2 * shift + 1):
        for dc in range(2 * shift + 1):
            sel = (off[0] == dr) & (off[1] == dc)
            if bool(sel.any()):
                out[:, sel] = pad[:, sel, :, dr : dr + rows, dc : dc + cols]
    return out


def halves_pool(x: Tensor) -> Tensor:
    """``avg_pool2d(x, 2)`` of ``x [N, C, H, W]`` with even ``H``, ``W``, as two sums of strided
    halves (the pooling op took a sixth of a csnn training step on CPU; these 10 % less)."""
    n, c, h, w = x.shape
    y = x.reshape(n, c, h // 2, 2, w)
    y = (y[:, :, :, 0] + y[:, :, :, 1]).reshape(n, c, h // 2, w // 2, 2)
    return (y[..., 0] + y[..., 1]) * 0.25


class _ConvSNNCore(nn.Module):
    """The network on a raster ``[steps, B, A]``; ``scan`` is the membrane recurrence."""

    __constants__: ClassVar[list[str]] = [
        "halves"
    ]  # a constant of the scripted graph, not a branch in it

    def __init__(self, layout: tuple[int, int, int, int], channels: int, n_classes: int,
                 beta: float, cells: tuple[int, ...] = ()) -> None:  # fmt: skip
        super().__init__()
        self.pol, self.rows, self.cols, self.extra = layout
        self.taxels = len(cells) or self.rows * self.cols
        # cell -> its taxel, or the appended zero taxel for an empty cell (one Gather in ONNX)
        index = torch.full((self.rows * self.cols,), self.taxels, dtype=torch.long)
        if cells:
            index[torch.as_tensor(cells, dtype=torch.long)] = torch.arange(len(cells))
        self.register_buffer("cell_taxel", index, persistent=False)
        self.scatter = bool(cells)
        self.conv1 = nn.Conv2d(self.pol, channels, 3, padding=1)
        self.conv2 = nn.Conv2d(channels, 2 * channels, 3, padding=1)
        self.pool = (min(2, self.rows), min(2, self.cols))
        self.halves = self.pool == (2, 2) and self.rows % 2 == 0 and self.cols % 2 == 0
        r2, c2 = -(-self.rows // self.pool[0]), -(-self.cols // self.pool[1])
        self.n1 = channels * self.rows * self.cols
        self.n2 = 2 * channels * r2 * c2
        self.out = nn.Linear(self.n2 + self.extra, n_classes)
        self.beta = float(beta)

    def conv_input(self, raster: Tensor, shift: int = 0) -> Tensor:
        steps, batch = raster.shape[0], raster.shape[1]
        g = raster[:, :, : self.pol * self.taxels]
        if self.scatter:
            g = g.reshape(steps, batch, self.taxels, self.pol)
            g = torch.cat([g, g.new_zeros(steps, batch, 1, self.pol)], dim=2)
            g = torch.index_select(g, 2, self.cell_taxel)
        g = g.reshape(steps, batch, self.rows, self.cols, self.pol).permute(0, 1, 4, 2, 3)
        if shift:
            g = random_shift(g, shift)
        return g.reshape(steps * batch, self.pol, self.rows, self.cols)

    def layer2_input(self, s1: Tensor) -> Tensor:
        steps, batch = s1.shape[0], s1.shape[1]
        x = s1.reshape(steps * batch, self.conv1.out_channels, self.rows, self.cols)
        if self.halves:
            x = halves_pool(x)
        else:
            x = nn.functional.avg_pool2d(x, self.pool, ceil_mode=True)
        return self.conv2(x).reshape(steps, batch, self.n2)

    def readout_input(self, s2: Tensor, raster: Tensor) -> Tensor:
        extra = raster[:, :, self.pol * self.taxels :]
        return self.out(torch.cat([s2, extra], dim=-1))


@register_model("csnn", ConvSNNConfig)
class ConvSNNModel(SpikeModel):
    """Spike times -> raster -> conv LIF -> pool -> conv LIF -> LI readout; see the module doc.

    Streaming state (``[batch, units]``): ``h1_state``, ``h2_state`` (the two layers' membranes)
    and ``o_state`` (the readout membrane).
    """

    onnx_scripted = True
    score_units = "max (or mean) over time of the leaky-integrator output membrane"

    def __init__(self, config: ConvSNNConfig, n_afferents: int, max_spikes: int, n_classes: int,
                 duration_ms: float, seed: int = 0) -> None:  # fmt: skip
        super().__init__(config, n_afferents, max_spikes, n_classes, duration_ms, seed)
        layout = grid_layout(n_afferents, config.grid, len(config.cells))
        self.dt_ms, tau_ms = config.times_ms(duration_ms)
        beta = decay_factor(self.dt_ms, tau_ms)
        with seeded(seed):  # the layers draw their initial weights from the global RNG
            self.core = _ConvSNNCore(layout, config.channels, n_classes, beta, config.cells)
        self.steps = raster_steps(duration_ms, self.dt_ms)

    def raster(self, spikes: Tensor) -> Tensor:
        return spike_raster(spikes, self.dt_ms, self.steps)

    def scores(self, spikes: Tensor, training: bool = False) -> Tensor:
        """Class scores; ``training`` adds the shift augmentation and dropout."""
        c, raster = self.core, self.raster(spikes)
        steps, batch = raster.shape[0], raster.shape[1]
        shift = self.config.shift if training else 0
        cur1 = c.conv1(c.conv_input(raster, shift)).reshape(steps, batch, c.n1)
        zero = cur1.new_zeros(batch, c.n1)
        s1, _ = _LIFScan.apply(cur1, zero, c.beta, 1.0, "subtract", "fast_sigmoid", 10.0)
        cur2 = c.layer2_input(s1)
        s2, _ = _LIFScan.apply(cur2, cur2.new_zeros(batch, c.n2), c.beta, 1.0, "subtract",
                               "fast_sigmoid", 10.0)  # fmt: skip
        if training and self.config.dropout > 0:
            # one mask per sample and neuron, held over the time steps (a dropped neuron is
            # silent for the window): 1/steps the random numbers of per-step dropout, whose
            # Bernoulli draws took a fifth of a training step on CPU
            p = self.config.dropout
            keep = (torch.rand(1, batch, s2.shape[-1], device=s2.device) >= p).to(s2.dtype) / (
                1.0 - p
            )
            s2 = s2 * keep
        out, _ = li_scan(c.readout_input(s2, raster), cur2.new_zeros(batch, self.n_classes), c.beta)
        return reduce_readout(out, self.config.readout)

    def bytes_per_sample(self, afferents: int, k: int) -> int:
        c = self.core
        return 4 * self.steps * (afferents * (k + 1) + 4 * c.n1 + 4 * c.n2 + 2 * self.n_classes)

    def loss(self, spikes: Tensor, y: Tensor) -> Tensor:
        return nn.functional.cross_entropy(self.scores(spikes, training=True), y)

    def learning_rate(self) -> float:
        return self.config.lr

    @property
    def state_names(self) -> tuple[tuple[str, int], ...]:
        return (("h1_state", self.core.n1), ("h2_state", self.core.n2),
                ("o_state", self.n_classes))  # fmt: skip

    def onnx_module(self) -> nn.Module:
        return _ConvSNNGraph(self)


class _ConvSNNGraph(nn.Module):
    """Exported network: the same layers, :func:`~tactilesnn.models.functional.lif_scan` /
    ``li_scan`` as ONNX ``Loop``s (scripted, the TorchScript-based exporter) or as ``Scan``s
    (their scan-operator forms, ``torch.export``), streaming state in and out."""

    def __init__(self, model: ConvSNNModel) -> None:
        super().__init__()
        self.core = model.core
        self.dt, self.steps = float(model.dt_ms), int(model.steps)
        self.readout = model.config.readout

    def forward(self, spikes: Tensor, h1: Tensor, h2: Tensor, o: Tensor):
        c = self.core
        raster = spike_raster(spikes, self.dt, self.steps)
        steps, batch = raster.shape[0], raster.shape[1]
        cur1 = c.conv1(c.conv_input(raster)).reshape(steps, batch, c.n1)
        if not torch.jit.is_scripting():  # (TorchScript compiles nothing inside this branch)
            if torch.compiler.is_exporting():
                s1, h1_new = lif_scan_op(cur1, h1, c.beta, 1.0, True)
                s2, h2_new = lif_scan_op(c.layer2_input(s1), h2, c.beta, 1.0, True)
                out, o_new = li_scan_op(c.readout_input(s2, raster), o, c.beta)
                return reduce_readout(out, self.readout), h1_new, h2_new, o_new
        s1, h1_new = lif_scan(cur1, h1, c.beta, 1.0, True)
        s2, h2_new = lif_scan(c.layer2_input(s1), h2, c.beta, 1.0, True)
        out, o_new = li_scan(c.readout_input(s2, raster), o, c.beta)
        return reduce_readout(out, self.readout), h1_new, h2_new, o_new
