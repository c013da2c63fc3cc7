"""Scalogram -> latency code (seed 001) as encoder components: ``gwt`` and ``stft``.

Per window: a Gabor-wavelet (``gwt``) or STFT (``stft``) scalogram on log-spaced bands, then one
latency-coded spike per (channel, statistic, band) (:class:`~tactilesnn.encoders.latency.LatencyCode`).
Afferent index = (channel * n_stats + stat) * n_bands + band; one spike slot per afferent.
The exported graph is the scalogram as two MatMuls + modulus (+ band pooling) + the code.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable
from typing import ClassVar

import numpy as np
import torch
from torch import Tensor, nn

from ..core.gate import active_channels, thresholds
from ..schema.encoders import GWTConfig, STFTConfig
from .base import SpikeEncoder, register_encoder
from .gwt import GaborScalogram, log_bands
from .latency import LatencyCode
from .passband import passband_mask
from .stft import STFTScalogram
from .window_graphs import FactoredGaborEncoder, GaborConvEncoder, WindowEncoder


class ScalogramLatencyEncoder(SpikeEncoder):
    """Scalogram of the window -> one latency spike per (channel, statistic, band)."""

    #: runs saved before the activity gate load with it off
    optional_state: ClassVar[tuple[str, ...]] = ("gate_rms",)
    #: the transform in float64 in torch and in the exported graph (the STFT's setting)
    float64_transform: ClassVar[bool] = False

    def __init__(self, config, fs_hz: float, window: int, n_channels: int) -> None:
        super().__init__(config, fs_hz, window, n_channels)
        f_hi = min(config.f_hi_hz, 0.45 * self.fs_hz)
        self.freqs_hz = log_bands(min(config.f_lo_hz, f_hi / 2), f_hi, config.n_bands)
        # band restriction: only the bands inside the sensor's passband are transformed; the
        # others keep their afferents (same layout) and stay silent
        keep = passband_mask(self.freqs_hz, self.fs_hz, config.passband_hz)
        self.kept_bands = np.flatnonzero(keep)
        self.restricted = not keep.all()
        self.band_scatter = _BandScatter(self.kept_bands, config.n_bands, len(config.stats))
        self.scalogram = self.make_scalogram(self.freqs_hz[keep])
        # every band's scalogram, built on demand for skipping(False); in a list, so it is not
        # a submodule (its buffers stay out of the saved weights)
        self._all_bands: list[nn.Module] = []
        self.code = LatencyCode(
            duration_ms=self.duration_ms,
            mapping=config.mapping,
            stats=config.stats,
            dynamic_range_db=config.dynamic_range_db,
        )
        # activity gate: per-channel RMS (input units) at or below which a window's channel is
        # skipped; learnt by fit() (gate x the median training RMS)
        self.register_buffer("gate_rms", torch.zeros(n_channels))
        if config.gate > 0:
            self.fitted.fill_(False)
        self.skip_enabled = True  # gate and band restriction; off within skipping(False)
        self.gate_counts = [0, 0]  # (window, channel) pairs seen, skipped

    def fit(self, X: np.ndarray) -> ScalogramLatencyEncoder:
        if self.config.gate > 0:
            self.gate_rms.copy_(torch.from_numpy(thresholds(np.asarray(X), self.config.gate)))
        self.fitted.fill_(True)
        return self

    def skip_stats(self) -> dict | None:
        out = {}
        if self.config.gate > 0:
            seen, skipped = self.gate_counts
            out["activity_gate"] = {"gate": self.config.gate, "channel_windows": seen,
                                    "skipped_fraction": skipped / max(seen, 1)}  # fmt: skip
        if self.restricted:
            lo, hi = self.config.passband_hz
            dropped = np.setdiff1d(np.arange(self.config.n_bands), self.kept_bands)
            out["band_restriction"] = {
                "passband_hz": [lo, hi if math.isfinite(hi) else None],
                "bands": self.config.n_bands,
                "bands_skipped": int(dropped.size),
                "skipped_bands_hz": [round(float(self.freqs_hz[b]), 3) for b in dropped],
            }
        return out or None

    @contextlib.contextmanager
    def skipping(self, enabled: bool):
        old, self.skip_enabled = self.skip_enabled, enabled
        try:
            yield
        finally:
            self.skip_enabled = old

    def export_metadata(self) -> dict[str, tuple]:
        out: dict[str, tuple] = {}
        if self.config.gate > 0:
            out["gate_rms"] = tuple(float(v) for v in self.gate_rms)
        if self.restricted:
            out["bands_hz"] = tuple(float(f) for f in self.freqs_hz)
            out["bands_transformed"] = tuple(int(i) for i in self.kept_bands)
        return out

    def make_scalogram(self, freqs_hz: np.ndarray) -> nn.Module:
        """The scalogram module of this encoder on bands centred at ``freqs_hz`` (each subclass
        provides its own)."""
        raise NotImplementedError(f"{type(self).__name__} does not define its scalogram")

    @property
    def n_afferents(self) -> int:
        return self.n_channels * len(self.config.stats) * self.config.n_bands

    def bytes_per_window(self) -> int:
        # complex spectra of the padded window for every band, plus the magnitudes
        return 48 * self.n_channels * (self.config.n_bands + 1) * 3 * self.window

    def _code_rows(self, x: Tensor) -> Tensor:
        """``[n, c, samples]`` -> spike times ``[n, c * stats * bands]``: only the bands inside
        the passband are transformed and coded (the others silent), unless skipping is off."""
        if not self.restricted:
            return self.code(self.scalogram(self.scaled(x)))
        if not self.skip_enabled:
            if not self._all_bands:
                self._all_bands.append(self.make_scalogram(self.freqs_hz))
            return self.code(self._all_bands[0](self.scaled(x)))
        return self.band_scatter(self.code(self.scalogram(self.scaled(x))))

    @staticmethod
    def scaled(x: Tensor) -> Tensor:
        """The windows as the scalogram takes them: :func:`unit_peak` (the code is scale-free;
        this keeps float32 in range)."""
        return unit_peak(x)

    def encode_batch(self, x: Tensor) -> Tensor:
        if self.config.gate <= 0 or not self.skip_enabled:
            return self._code_rows(x).unsqueeze(-1)
        n, c = x.shape[0], x.shape[1]
        active = active_channels(x, self.gate_rms.to(x.dtype))  # [n, C]
        per = len(self.config.stats) * self.config.n_bands
        out = torch.full((n, c, per), math.inf, dtype=torch.float32, device=x.device)
        b, ch = active.nonzero(as_tuple=True)
        if b.numel():  # only the active (window, channel) pairs are transformed
            sub = x[b, ch].unsqueeze(1)
            out[b, ch] = self._code_rows(sub).to(torch.float32)
        self.gate_counts[0] += n * c
        self.gate_counts[1] += n * c - int(b.numel())
        return out.reshape(n, c * per, 1)

    def onnx_module(self) -> nn.Module:
        return self._gated(WindowEncoder(self.scalogram, self.code, self.window,
                                         float64=self.float64_transform))  # fmt: skip

    def _gated(self, graph: nn.Module) -> nn.Module:
        """The exported encoder (``graph``: window -> codes of the transformed bands) with the
        band restriction (the other bands' afferents silent) and the activity gate: the graph
        encodes only the active (window, channel) rows, as :meth:`encode_batch` does (the
        service also answers wholly silent windows of a stateless model from a cache, see
        :mod:`tactilesnn.service.runtime`)."""
        inner = nn.Sequential(graph, self.band_scatter) if self.restricted else graph
        graph = _WithSlot(inner, self.scaled)
        if self.config.gate <= 0:
            return graph
        return _GateMask(graph, self.gate_rms, len(self.config.stats) * self.config.n_bands)

    @torch.no_grad()
    def feature_map(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scalogram magnitude of the window's channels, summed ``[bands, frames]``."""
        t = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))[None]
        freqs = np.asarray(self.freqs_hz)[self.kept_bands]  # the bands transformed
        return self.scalogram(self.scaled(t))[0].sum(0).numpy(), freqs


@register_encoder("gwt", GWTConfig)
class GWTLatencyEncoder(ScalogramLatencyEncoder):
    """Gabor-wavelet scalogram -> latency code (seed 001's winning encoder)."""

    #: above this, the exported scalogram is one FIR convolution of every band (size bands x
    #: the longest wavelet) instead of its per-band forms; the graph is loaded by three
    #: onnxruntime sessions while the export is verified, each with copies of the weights
    FACTORED_BUDGET_BYTES: ClassVar[int] = 32 << 20

    def make_scalogram(self, freqs_hz: np.ndarray) -> nn.Module:
        if self.config.hop > self.window:
            raise ValueError(f"gwt hop ({self.config.hop}) exceeds the window ({self.window})")
        return GaborScalogram(self.fs_hz, freqs_hz, hop=self.config.hop)

    def onnx_module(self) -> nn.Module:
        # each band in its cheapest exact form (low rank, short FIR, dense); the FIR form of every
        # band (size bands x the longest wavelet) is the fallback when that is too large (a
        # 13,000-sample window's dense columns would need GBs)
        try:
            graph = FactoredGaborEncoder(
                self.scalogram, self.code, self.window, self.FACTORED_BUDGET_BYTES
            )
            size = sum(b.numel() * b.element_size() for b in graph.buffers())
        except ValueError:
            size = np.inf
        if size > self.FACTORED_BUDGET_BYTES:
            graph = GaborConvEncoder(self.scalogram, self.code, self.window)
        return self._gated(graph)


def unit_peak(x: Tensor) -> Tensor:
    """Each (window, channel) divided by its peak ``|x|`` (all-zero rows stay zero).

    The scalogram is linear and the latency code is normalised per window and channel, so this
    changes no spike time; it keeps float32 arithmetic in range for any finite float32 input
    (1e-30 farads and 1e30 pascals alike; the squared modulus would overflow above ~1e19).
    """
    peak = x.abs().amax(-1, keepdim=True)
    # an all-zero row stays zero (0 / tiny); a row whose peak is subnormal is scaled by
    # 1 / tiny instead of 1 / peak (the code is scale-free): one Clip instead of a where
    return x / peak.clamp_min(torch.finfo(x.dtype).tiny)


def level_off(x: Tensor) -> Tensor:
    """Each (window, channel) of ``x [..., samples]`` less its first sample, divided by the
    peak of that (:func:`unit_peak`; a constant row: exact zeros). Halved first (exact), so that
    no difference of float32 values overflows.

    A transform blind to a constant (the causal bank's DC gain is exactly zero, and a window's
    past is its first sample; the STFT removes each frame's mean) gives the same output but
    scaled, and the latency code is scale-free: no spike time changes. Without the level,
    float32 rounding is relative to what varies instead of to the level: a status column stuck
    at 65,535 gives exact zeros (silent) instead of rounding noise coded as spikes (which torch,
    onnxruntime and float64 coded differently), and a ripple on a large level is coded to the
    precision float32 holds it with."""
    h = 0.5 * x
    return unit_peak(h - h[..., :1])


@register_encoder("stft", STFTConfig)
class STFTLatencyEncoder(ScalogramLatencyEncoder):
    """STFT scalogram pooled into the same bands -> latency code (seed 001's comparison). The
    transform runs in float64, in torch and in the exported graph: a 60 dB code of a band
    resolves what float32 products of a whole window cannot (FabricSlide, 141-sample windows,
    test pressed harder than training: spike times 44 ms apart and one spike missing between
    torch's FFT and the graph's float32 MatMuls; in float64 they agree)."""

    @property
    def float64_transform(self) -> bool:  # type: ignore[override]
        return bool(self.config.float64)

    def scaled(self, x: Tensor) -> Tensor:
        """:func:`level_off` (the STFT removes each frame's mean: the spikes are the same, and
        float32 rounds relative to what varies, not to the level: a channel stuck at 65,535
        is exact zeros and silent instead of rounding noise that torch and onnxruntime code
        differently); a run saved before that: :func:`unit_peak`."""
        return level_off(x) if self.config.level_off else unit_peak(x)

    def make_scalogram(self, freqs_hz: np.ndarray) -> nn.Module:
        frame = self.config.frame_samples or self.window
        if frame > self.window:
            raise ValueError(f"frame_samples ({frame}) exceeds the window ({self.window})")
        return STFTScalogram(self.fs_hz, freqs_hz, nperseg=frame, float64=self.float64_transform)


class _GateMask(nn.Module):
    """Spike times ``[B, C * per, 1]``, inf where the window's channel RMS <= ``gate_rms``.

    Only the active (window, channel) rows go through ``inner`` (a ``[rows, 1, samples]`` ->
    ``[rows, per, 1]`` encoder): the exported graph gathers them (``NonZero``, ``Gather``) and
    scatters their spikes back, so onnxruntime's work scales with the touched taxels, as the
    torch path's does (:meth:`ScalogramLatencyEncoder.encode_batch`).
    """

    def __init__(self, inner: nn.Module, gate_rms: Tensor, per: int) -> None:
        super().__init__()
        self.inner, self.per = inner, int(per)
        self.register_buffer("gate_rms", gate_rms.clone().float())

    def forward(self, x: Tensor) -> Tensor:
        c, n = x.shape[1:]
        active = active_channels(x, self.gate_rms).reshape(-1)  # [B * C]
        rows = torch.nonzero(active).reshape(-1)
        flat = x.reshape(-1, 1, n)
        t = self.inner(flat.index_select(0, rows))  # [rows, per, 1]
        out = torch.full((flat.shape[0], self.per, 1), math.inf, dtype=t.dtype)
        return out.index_put((rows,), t).reshape(-1, c * self.per, 1)


class _BandScatter(nn.Module):
    """Codes of the transformed bands ``[B, C * stats * kept]`` -> the full afferent layout
    ``[B, C * stats * bands]``, the bands outside the passband silent (inf). One gather with a
    constant index (an inf column appended), in torch and in the exported graph alike."""

    def __init__(self, kept: np.ndarray, n_bands: int, n_stats: int) -> None:
        super().__init__()
        kept = np.asarray(kept, dtype=np.int64)
        index = np.full(n_bands, kept.size)  # the appended inf column
        index[kept] = np.arange(kept.size)
        self.kept, self.n_bands = int(kept.size), int(n_bands)
        self.register_buffer("index", torch.from_numpy(index), persistent=False)

    def forward(self, t: Tensor) -> Tensor:
        b = t.shape[0]
        rows = t.reshape(b, -1, self.kept)
        pad = torch.full_like(rows[..., :1], math.inf)
        return torch.cat([rows, pad], -1).index_select(-1, self.index).reshape(b, -1)


class _WithSlot(nn.Module):
    """Windows as the scalogram takes them (``scaled``: the encoder's, as in
    :meth:`ScalogramLatencyEncoder.encode_batch`) -> ``inner`` -> ``[B, A]`` one-spike times ->
    ``[B, A, 1]`` (the package's spike format)."""

    def __init__(self, inner: nn.Module, scaled: Callable[[Tensor], Tensor] = unit_peak) -> None:
        super().__init__()
        self.inner, self.scaled = inner, scaled

    def forward(self, x: Tensor) -> Tensor:
        return self.inner(self.scaled(x)).unsqueeze(-1)
