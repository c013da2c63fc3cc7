"""LIF-population encoder (seed 000's analog-to-spike converters as a population code): ``lif``.

Each channel drives ``neurons`` LIF converters whose thresholds are graded geometrically from
``lo`` to ``hi`` times a reference level; converter ``j`` of channel ``c`` is afferent
``c * neurons + j`` and keeps ``max_spikes`` spike times. The reference level is
(``norm``):

* ``"train"``: each channel's median RMS over the training windows (fitted, a buffer);
* ``"window"``: the peak ``|x|`` of each window over all channels (gain-invariant level
  crossings that keep the channels' relative levels).

With ``keep = "spread"`` (default) each converter keeps every ``m``-th spike, ``m`` fitted so that
its median spike count over the training windows fills the ``max_spikes`` slots (``m = 1`` where
they already fit, which is ``keep = "first"``): the kept spikes span the whole window (keeping the
first spikes put 90 % of them in the first 130 ms of a 6 s recording). Since the closed-form
converter both cost the same; accuracy, seed 0, first -> spread: Braille LIF + readout 92.59 ->
92.59 % (1 s windows 95.68 -> 96.30 %), hook_loop LIF + SNN 86.61 -> 87.17 %, material 64.44 ->
65.00 %, stiffness x curvature 87.22 -> 84.44 % (within its +-5 point interval).

Converters integrate exactly for sample-and-hold input (:func:`~tactilesnn.encoders.spiking.
lif_first_spikes`: every crossing of a sample in closed form, so the cost does not grow with the
firing rate; the same arithmetic in the exported graph, where the sample loop is an ONNX ``Scan``
carrying the potentials, the kept slots read after it, or a ``Loop`` from the older exporter).
"""

from __future__ import annotations

import logging
from typing import ClassVar

import numpy as np
import torch
from torch import Tensor, nn

from ..core.data import evenly_spaced
from ..core.spikes import keep_every
from ..schema.encoders import LIFPopulationConfig
from .base import SpikeEncoder, register_encoder
from .spiking import lif_first_spikes, lif_first_spikes_op, lif_first_spikes_sparse

log = logging.getLogger("tactilesnn")


#: one window's bytes above which the exported LIF loop keeps its slots in the loop: the faster
#: form holds ~14 eight-byte values per afferent and sample, the slow one the slots alone (a
#: whole 60 s recording at 2 kHz on 12 channels x 8 converters would need 1.5 GB per window)
GRAPH_HISTOGRAM_BYTES = 64 << 20


class _LIFPopulationGraph(nn.Module):
    """Scaling + converters; the sample loop becomes an ONNX ``Loop`` (scripted, for the
    TorchScript-based exporter) or ``Scan`` (``torch.export``; ``slots_in_loop``: see
    :func:`~.spiking.lif_first_spikes_op`)."""

    def __init__(self, ref: Tensor, inv_thr: Tensor, every: Tensor, dt_ms: float, tau_ms: float,
                 k: int, window_norm: bool, slots_in_loop: bool = False) -> None:  # fmt: skip
        super().__init__()
        self.register_buffer("ref", ref.clone())
        self.register_buffer("inv_thr", inv_thr.clone())
        self.register_buffer("every", every.clone())
        self.dt, self.tau, self.k = float(dt_ms), float(tau_ms), int(k)
        self.window_norm = bool(window_norm)
        self.slots_in_loop = bool(slots_in_loop)

    def scaled(self, x: Tensor) -> Tensor:
        """Window ``[N, C, W]`` -> each channel in units of its reference level ``[N, C, W]``;
        converter ``j`` of a channel sees it times ``inv_thr[j]`` (threshold 1)."""
        if self.window_norm:
            return x / x.abs().amax(dim=(1, 2), keepdim=True).clamp_min(1e-30)
        return x / self.ref.view(1, -1, 1)

    def spikes(self, x: Tensor, k: int, every: Tensor) -> tuple[Tensor, Tensor]:
        """Spike times ``[N, C * neurons, k]`` (ms) and counts ``[N, C * neurons]``: the sample
        loop scripted (an ONNX ``Loop``), as a scan operator (``torch.export``: a ``Scan``), or
        eager on the CPU with only the firing converters' slots updated (the same figures bit for
        bit)."""
        gain = self.inv_thr.to(x.dtype)
        if not torch.jit.is_scripting():  # (TorchScript compiles nothing inside this branch)
            if torch.compiler.is_exporting():
                return self._scanned(x, k, every, gain)
            return self._eager(x, k, every, gain)
        return lif_first_spikes(self.scaled(x), self.dt, self.tau, k, every.to(x.dtype), gain)

    @torch.jit.unused
    def _eager(self, x: Tensor, k: int, every: Tensor, gain: Tensor) -> tuple[Tensor, Tensor]:
        # the firing converters' rows found on the CPU only: on a GPU each sample's search
        # would wait for the device, and a device without values (meta) has none to search
        fn = lif_first_spikes_sparse if x.device.type == "cpu" else lif_first_spikes
        return fn(self.scaled(x), self.dt, self.tau, k, every.to(x.dtype), gain)

    @torch.jit.unused
    def _scanned(self, x: Tensor, k: int, every: Tensor, gain: Tensor) -> tuple[Tensor, Tensor]:
        return lif_first_spikes_op(self.scaled(x), self.dt, self.tau, k, every.to(x.dtype), gain,
                                   self.slots_in_loop)  # fmt: skip

    def forward(self, x: Tensor) -> Tensor:
        return self.spikes(x, self.k, self.every)[0]


class _Float64Graph(nn.Module):
    """float32 in and out, float64 inside: with ``keep = "spread"`` a slot holds the converter's
    ``m``-th, ``2m``-th ... spike, so one crossing counted differently in float32 over a long
    window moves every later slot by a whole inter-spike interval; in float64, as in
    :meth:`LIFPopulationEncoder.encode_batch`, the graph and torch count alike."""

    def __init__(self, graph: _LIFPopulationGraph) -> None:
        super().__init__()
        self.graph = graph

    def forward(self, x: Tensor) -> Tensor:
        return self.graph(x.double()).float()


@register_encoder("lif", LIFPopulationConfig)
class LIFPopulationEncoder(SpikeEncoder):
    """Population of LIF analog-to-spike converters per channel; see the module docstring."""

    onnx_scripted = True
    needs_fit = True
    codes_envelopes = True
    #: runs written before the prescaler existed load with every = 1 (their first-k behaviour)
    optional_state: ClassVar[tuple[str, ...]] = ("every",)

    def __init__(self, config: LIFPopulationConfig, fs_hz: float, window: int, n_channels: int):
        super().__init__(config, fs_hz, window, n_channels)
        thr = np.geomspace(config.lo, config.hi, config.neurons)
        self.register_buffer("inv_thr", torch.as_tensor(1.0 / thr, dtype=torch.float32))
        self.register_buffer("ref", torch.zeros(n_channels))  # per-channel RMS level
        # prescaler per afferent: keep every m-th spike (1 = the first max_spikes)
        self.register_buffer("every", torch.ones(self.n_afferents))
        if config.norm == "window":  # nothing to learn
            self.fitted.fill_(True)

    @property
    def n_afferents(self) -> int:
        return self.n_channels * self.config.neurons

    @property
    def max_spikes(self) -> int:
        return self.config.max_spikes

    def fit(self, X: np.ndarray) -> LIFPopulationEncoder:
        level = np.median(np.sqrt((np.asarray(X, dtype=np.float64) ** 2).mean(-1)), axis=0)  # [C]
        if not (level > 0).any():
            raise ValueError("every channel is zero in the training windows: nothing to encode")
        # a channel silent in most training windows would otherwise be scaled by ~1e12, turning
        # its noise at test time into saturated spike trains: floor it at 1e-3 of the loudest
        floor = 1e-3 * level.max()
        quiet = np.flatnonzero(level < floor)
        if quiet.size:
            log.warning("LIF encoder: channel(s) %s nearly silent in training; level floored at "
                        "1e-3 of the loudest channel", quiet.tolist())  # fmt: skip
        self.ref.copy_(torch.from_numpy(np.maximum(level, floor)))
        if self.config.keep == "spread":
            self.every.copy_(self._fit_every(np.asarray(X)))
        self.fitted.fill_(True)
        return self

    def _fit_every(self, X: np.ndarray, n_max: int = 64) -> Tensor:
        """Prescaler per afferent: median spike count over (up to ``n_max``) training windows
        divided by the slots, rounded up, in ``[1, 2^24 / max_spikes]``."""
        idx = evenly_spaced(len(X), n_max)
        ones = torch.ones(self.n_afferents, dtype=torch.float64)
        x = torch.from_numpy(np.asarray(X[idx], dtype=np.float64))
        _, count = self.graph().double().spikes(x, 1, ones)
        return torch.from_numpy(
            keep_every(count.median(dim=0).values.numpy(), self.config.max_spikes)
        )

    def upgrade_state(self, state: dict) -> dict:
        if "lif_ref" in state:  # the pipeline's attribute before this class existed
            state = {**state, "ref": state["lif_ref"]}
            del state["lif_ref"]
        return super().upgrade_state(state)

    def bytes_per_window(self) -> int:
        # float64: the window and its scaled copy, and per afferent the slots and loop state
        return 8 * (
            2 * self.n_channels * self.window + self.n_afferents * (4 * self.max_spikes + 8)
        )

    def _histogram_bytes(self) -> int:
        # the Scan form (spiking.lif_first_spikes_op) also holds per afferent and sample the
        # drive's constants, each sample's counts and first times, their running sums and the
        # slots' histogram indices: onnxruntime's peak RSS, 8 channels x 8 converters x 1,500
        # samples, batches of 24 and 120: 9.5 and 10.7 MB per window, 12.4 and 14.0 eight-byte
        # values per afferent and sample
        return 8 * 16 * self.n_afferents * self.window

    @property
    def graph_slots_in_loop(self) -> bool:
        """Whether the exported loop keeps the slots in it (memory of the slots alone) instead of
        reading them after it: when one window's samples would need more than
        :data:`GRAPH_HISTOGRAM_BYTES` (12 channels x 8 converters: windows over ~5,500 samples)."""
        return self._histogram_bytes() > GRAPH_HISTOGRAM_BYTES

    def graph_bytes_per_window(self) -> int:
        extra = 0 if self.graph_slots_in_loop else self._histogram_bytes()
        return self.bytes_per_window() + extra

    def graph(self) -> _LIFPopulationGraph:
        return _LIFPopulationGraph(self.ref, self.inv_thr, self.every, 1000.0 / self.fs_hz,
                                   self.config.tau_ms, self.config.max_spikes,
                                   self.config.norm == "window", self.graph_slots_in_loop)  # fmt: skip

    def encode_batch(self, x: Tensor) -> Tensor:
        # float64 for the exact crossing times, as in the exported graph (_Float64Graph)
        return self.graph().double()(x.double()).float()

    def onnx_module(self) -> nn.Module:
        return _Float64Graph(self.graph().double())
