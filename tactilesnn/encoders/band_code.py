"""Transform -> code as two registered stages: ``bands`` (band envelopes coded by an analog code).

``gwt`` and ``stft`` are each a scalogram *and* a latency code (one spike per band and window);
``lif`` and ``delta`` code the raw samples. This component composes the two kinds, so a filter
bank can feed any code of analog channels:

* a **transform** from :data:`TRANSFORMS` (``gwt``: the Gabor scalogram; ``cgwt``: the causal
  Gabor bank, its frame ``i`` at sample ``(i + 1) hop - 1``; ``stft``: the Hann STFT pooled into
  the same bands) turns each channel into ``n_bands`` magnitude envelopes, one frame every
  ``hop = window // frames`` samples (frame ``i`` at sample ``i * hop``);
* a **code** (``code``): any registered encoder that codes analog channels (its class says so
  with ``codes_envelopes``: ``lif``, seed 000's LIF converters on seed 001's scalogram, or
  ``delta``, level crossings) codes the ``channels x bands`` envelope rows as if they were sensor
  channels sampled at the frame rate, with its own defaults, calibrated on the training
  envelopes (the LIF converters' level per row, the delta step per row).

Unlike the latency codes (one spike per band, each window divided by its peak), the composition
keeps when each band is active and how strongly, on the training data's scale. Afferents: the
code's, over envelope rows ``channel * n_bands + band``. Export: the envelopes as two MatMuls and
a modulus (the transform's exact linear map), then the code's own graph (scripted where the
code's is).

Adding a transform: a function ``(fs_hz, freqs_hz, hop, window) -> module`` whose ``forward``
gives magnitudes ``[batch, channels, bands, frames]``, whose ``linear_map(window)`` gives
``(response [window, rows, frames] complex, pool [bands, rows] or None)`` and
``linear_map_shape(window)`` its ``(rows, frames)``, registered with
``@TRANSFORMS.register("name")``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor, nn

from ..core.data import evenly_spaced
from ..core.registry import Registry
from ..schema.encoders import BandCodeConfig
from . import delta, lif_population  # noqa: F401  (codes registered before CHOICES is built)
from .base import ENCODERS, SpikeEncoder, build_encoder, register_encoder
from .causal_gabor import CausalGaborScalogram
from .gwt import GaborScalogram, log_bands
from .stft import STFTScalogram
from .window_graphs import WindowEncoder

TRANSFORMS: Registry = Registry("transform")
#: the exported envelope matrices (float32 real and imaginary parts) at most this large
EXPORT_BUDGET_BYTES = 256 << 20


@TRANSFORMS.register("gwt")
def gabor_envelopes(fs_hz: float, freqs_hz: np.ndarray, hop: int, window: int) -> nn.Module:
    """Gabor (complex Morlet) scalogram magnitudes, every ``hop``-th sample."""
    return GaborScalogram(fs_hz, freqs_hz, hop=hop)


@TRANSFORMS.register("cgwt")
def causal_gabor_envelopes(fs_hz: float, freqs_hz: np.ndarray, hop: int, window: int) -> nn.Module:
    """The causal recursive Gabor bank's magnitudes (:mod:`.causal_gabor`), every ``hop``-th
    sample."""
    return CausalGaborScalogram(fs_hz, freqs_hz, hop=hop)


@TRANSFORMS.register("stft")
def stft_envelopes(fs_hz: float, freqs_hz: np.ndarray, hop: int, window: int) -> nn.Module:
    """Hann STFT magnitudes pooled into the bands: segments of two periods of the lowest band,
    at least 4 samples and at most a quarter of the window (an envelope, not one spectrum), one
    every ``hop`` samples."""
    longest = max(4, int(window) // 4)
    nperseg = int(min(longest, max(4, round(2 * fs_hz / float(np.min(freqs_hz))))))
    return STFTScalogram(fs_hz, freqs_hz, nperseg=nperseg, hop=hop)


def envelope_codes() -> tuple[str, ...]:
    """Registered encoders that code analog channels (``codes_envelopes``)."""
    return tuple(n for n in ENCODERS.names() if ENCODERS.get(n).codes_envelopes)


class _BandCodeGraph(nn.Module):
    """Window ``[B, C, W]`` -> envelopes (the transform's linear map as MatMuls, modulus, band
    pooling) ``[B, C * bands, frames]`` -> the code's graph."""

    def __init__(self, envelopes: WindowEncoder, code: nn.Module, n_bands: int, frames: int):
        super().__init__()
        self.envelopes, self.code = envelopes, code
        self.n_bands, self.frames = int(n_bands), int(frames)

    def forward(self, x: Tensor) -> Tensor:
        env = self.envelopes.scalogram(x)[..., : self.frames]
        return self.code(env.reshape(x.shape[0], x.shape[1] * self.n_bands, self.frames))


@register_encoder("bands", BandCodeConfig)
class BandCodeEncoder(SpikeEncoder):
    """A registered transform's band envelopes coded by a registered analog code (module
    docstring)."""

    needs_fit = True

    def __init__(self, config: BandCodeConfig, fs_hz: float, window: int, n_channels: int):
        super().__init__(config, fs_hz, window, n_channels)
        f_hi = min(config.f_hi_hz, 0.45 * self.fs_hz)
        if not config.f_lo_hz < f_hi:
            raise ValueError(f"bands: f_lo_hz ({config.f_lo_hz}) must lie below 0.45 x the "
                             f"sampling rate ({f_hi:.4g} Hz)")  # fmt: skip
        self.freqs_hz = log_bands(config.f_lo_hz, f_hi, config.n_bands)
        self.hop = max(1, self.window // config.frames)  # at most one frame per sample
        make: Callable[..., nn.Module] = TRANSFORMS.get(config.transform)
        self.filter_bank = make(self.fs_hz, self.freqs_hz, self.hop, self.window)
        frames = self.filter_bank.linear_map_shape(self.window)[1]
        self.frames = min(int(frames), int(config.frames))
        if self.frames < 2:
            raise ValueError(f"bands: the {config.transform} transform gives {self.frames} frame "
                             f"of a {window}-sample window; the code needs at least 2")  # fmt: skip
        self.frame_hz = self.fs_hz / self.hop
        code_config = ENCODERS.config_class(config.code)()
        self.code = build_encoder(code_config, self.frame_hz, self.frames,
                                  self.n_channels * config.n_bands)  # fmt: skip
        self.onnx_scripted = self.code.onnx_scripted
        self.onnx_exportable = self.code.onnx_exportable

    @property
    def n_afferents(self) -> int:
        return self.code.n_afferents

    @property
    def max_spikes(self) -> int:
        return self.code.max_spikes

    @torch.no_grad()
    def envelopes(self, x: Tensor) -> Tensor:
        """Windows ``[B, C, W]`` -> band envelopes ``[B, C * bands, frames]`` (input units)."""
        env = self.filter_bank(x)[..., : self.frames]
        return env.reshape(x.shape[0], -1, self.frames).float()

    def fit(self, X: np.ndarray, n_max: int = 1024) -> BandCodeEncoder:
        """The code calibrated on the envelopes of (up to ``n_max``, evenly spaced) training
        windows."""
        arr = np.asarray(X)
        idx = evenly_spaced(len(arr), n_max)
        batch = max(1, (1 << 27) // max(1, self.bytes_per_window()))
        env = torch.cat([
            self.envelopes(torch.from_numpy(np.ascontiguousarray(arr[idx[i : i + batch]],
                                                                 dtype=np.float32)))
            for i in range(0, len(idx), batch)
        ])  # fmt: skip
        self.code.fit(env.numpy())
        self.fitted.fill_(True)
        return self

    def encode_batch(self, x: Tensor) -> Tensor:
        return self.code.encode_batch(self.envelopes(x))

    def _spectra_bytes(self) -> int:
        # the transform's complex spectra per band (padded window)
        return 16 * self.n_channels * self.config.n_bands * 3 * self.window

    def bytes_per_window(self) -> int:
        return self._spectra_bytes() + self.code.bytes_per_window()

    def graph_bytes_per_window(self) -> int:
        return self._spectra_bytes() + self.code.graph_bytes_per_window()

    def onnx_module(self) -> nn.Module:
        size = 8 * self.window * int(np.prod(self.filter_bank.linear_map_shape(self.window)))
        if size > EXPORT_BUDGET_BYTES:
            raise ValueError(f"bands: the exported envelope matrices would take {size / 2**20:.0f} "
                             f"MiB (limit {EXPORT_BUDGET_BYTES >> 20} MiB): use fewer bands or "
                             "frames, or shorter windows")  # fmt: skip
        envelopes = WindowEncoder(self.filter_bank, nn.Identity(), self.window)  # type: ignore[arg-type]
        return _BandCodeGraph(envelopes, self.code.onnx_module(), self.config.n_bands, self.frames)

    def feature_map(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Band envelopes of the window's channels, summed ``[bands, frames]``."""
        t = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))[None]
        env = self.envelopes(t).reshape(self.n_channels, self.config.n_bands, self.frames)
        return env.sum(0).numpy(), np.asarray(self.freqs_hz)
