"""Causal Gabor scalogram -> latency code as an encoder component: ``cgwt``.

The ``gwt`` encoder's code (one latency spike per channel, statistic and band; the same afferent
layout, band range, statistics, activity gate and band restriction) on the causal recursive
Gabor bank of :mod:`.causal_gabor` instead of the windowed FFT scalogram. Each window is
transformed from the zero state (its first sample as the constant past); a stream carries the
state instead (:class:`~.causal_gabor.CausalGaborStream`), so every input sample is transformed
once. Exported as the bank's own exact form: one strided convolution (the polyphase FIR of every
band) and the frame recursion as block MatMuls, then the code.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch
from torch import Tensor, nn

from ..core.checks import check_int
from .base import register_encoder
from .causal_gabor import CausalGaborScalogram
from .latency import LatencyCode
from .scalogram_latency import ScalogramLatencyEncoder, ScalogramLatencySettings


def auto_hop(fs_hz: float, f_hi_hz: float, window: int) -> int:
    """Frames every ``hop`` samples, fast enough for the highest band's envelope: its magnitude
    varies within ``+- 2 sigma_f`` (``sigma_f`` = 0.184 f_hi), so a frame rate of ``4 sigma_f``
    samples it at twice that; at most an eighth of the window. The largest such hop that divides
    half an even window (a stream step, half a window, is then whole frames: the stream graph
    needs it) unless that is under half the bound (3,250-sample windows would get hop 1 instead of
    3: three times the frames), then the bound."""
    sigma_f = f_hi_hz / (math.pi * math.sqrt(3.0))  # cmor1.5-1.0: f / (pi C sqrt(2 B))
    bound = int(max(1, min(math.floor(fs_hz / (4.0 * sigma_f)), int(window) // 8)))
    if window % 2:
        return bound
    best = max(d for d in range(1, bound + 1) if (window // 2) % d == 0)
    return best if 2 * best >= bound else bound


@dataclass(frozen=True)
class CausalGWTConfig(ScalogramLatencySettings):
    """Causal recursive Gabor bank -> latency code. ``hop``: a frame every ``hop`` samples
    (0 = :func:`auto_hop`: from the highest band's envelope bandwidth); ``order``: poles per band."""

    hop: int = 0
    order: int = 4

    FLAGS: ClassVar[dict[str, str]] = {**ScalogramLatencySettings.FLAGS, "cgwt_hop": "hop",
                                       "cgwt_order": "order"}  # fmt: skip
    HELP: ClassVar[dict[str, str]] = {
        **ScalogramLatencySettings.HELP,
        "hop": "frame every hop samples (0 = from the highest band's envelope bandwidth)",
        "order": "poles per band of the causal Gabor bank (4: gammatone-like)",
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        check_int(self.hop, "hop", 0)
        check_int(self.order, "order", 1)
        if self.order > 16:
            raise ValueError(f"order must be <= 16, got {self.order}")


@register_encoder("cgwt", CausalGWTConfig)
class CausalGWTLatencyEncoder(ScalogramLatencyEncoder):
    """Causal (streamable) Gabor bank -> latency code."""

    def make_scalogram(self, freqs_hz: np.ndarray) -> nn.Module:
        hop = self.config.hop or auto_hop(self.fs_hz, float(np.max(self.freqs_hz)), self.window)
        if hop > self.window:
            raise ValueError(f"cgwt hop ({hop}) exceeds the window ({self.window})")
        return CausalGaborScalogram(self.fs_hz, freqs_hz, hop=hop, order=self.config.order)

    @property
    def hop(self) -> int:
        return self.scalogram.hop

    def bytes_per_window(self) -> int:
        # the strided FIR's output and the recursion's blocks: a few complex values per frame
        nb, f = self.config.n_bands, self.window // self.hop
        return 8 * self.n_channels * (self.window + 8 * nb * f)

    def onnx_module(self) -> nn.Module:
        return self._gated(_ScalogramCode(self.scalogram, self.code))

    def stream_module(self, step: int | None = None) -> CausalStreamCode:
        """The encoder's stream step (``step`` samples per call, default half a window), for the
        stream graph."""
        return CausalStreamCode(self, self.window // 2 if step is None else step)

    def stream_reference(self, x: Tensor, step: int) -> Tensor:
        """What the stream step must give on a whole stream ``x [1, channels, samples]`` (float64
        for a reference): the bank run once over it, each complete window's frames (a window
        ending every ``step`` samples) coded -> spike times ``[windows, afferents, 1]``."""
        mag = self.scalogram(x).float()  # [1, C, bands, frames]
        fs, frames = step // self.hop, self.window // self.hop
        n = x.shape[-1] // step - self.window // step + 1
        t = torch.cat([self.code(mag[..., j * fs : j * fs + frames]) for j in range(n)])
        return (self.band_scatter(t) if self.restricted else t).unsqueeze(-1)


class _ScalogramCode(nn.Module):
    """Window ``[B, C, W]`` -> the bank's magnitudes -> the latency code ``[B, C * stats * bands]``
    (the bank traced as it runs: a strided Conv and block MatMuls)."""

    def __init__(self, scalogram: CausalGaborScalogram, code: LatencyCode) -> None:
        super().__init__()
        self.scalogram, self.code = scalogram, code

    def forward(self, x: Tensor) -> Tensor:
        return self.code(self.scalogram(x))


def _modulus(re: Tensor, im: Tensor) -> Tensor:
    """``|re + i im|`` without squaring a large or tiny value (float32 squares overflow above
    ~1.8e19 and lose precision below ~1e-19): ``m sqrt(1 + (n / m)^2)``, ``m`` the larger part."""
    a, b = re.abs(), im.abs()
    m, n = torch.maximum(a, b), torch.minimum(a, b)
    r = n / m.clamp_min(torch.finfo(m.dtype).tiny)
    return m * torch.sqrt(1.0 + r * r)


class CausalStreamCode(nn.Module):
    """One stream step of the ``cgwt`` encoder: the next ``step`` samples ``chunk [B, C, step]``
    and the encoder's state -> the spike times of the window that ends with them ``[B,
    afferents, 1]`` and the new state. Every sample is transformed once: the bank continues
    from its state, and the window's frames are the earlier ones (kept as state) then the
    chunk's. ``step`` (a whole number of hops dividing the window, at most half of it) sets the
    latency: a sample's frame, and the spikes of the window it ends, exist after the call that
    takes it (one hop: one frame).

    State (``[B, units]`` each, :attr:`state_names`): ``cgwt_tail`` the last ``taps - 1`` samples
    (a fresh stream: its first sample repeated, the bank's constant past), ``cgwt_rec`` the frame
    recursion's values (zeros), ``cgwt_frames`` the window's magnitudes before the chunk's;
    ``stream_prev``, the window's samples before the chunk, only where the pipeline's level code
    reads the window.
    """

    def __init__(self, encoder: CausalGWTLatencyEncoder, step: int) -> None:
        super().__init__()
        if encoder.config.gate > 0:
            raise ValueError(
                "the activity gate skips a window's quiet channels, but a stream's recursion "
                "needs every sample: export the stream graph of a run trained without --gate"
            )
        bank: CausalGaborScalogram = encoder.scalogram
        check_stream_step(step, encoder.window, bank.hop)
        self.bank, self.code = bank, encoder.code
        self.scatter = encoder.band_scatter if encoder.restricted else None
        self.step, self.channels = int(step), encoder.n_channels
        self.f_step = self.step // bank.hop
        self.f_kept = (encoder.window - self.step) // bank.hop  # the window's earlier frames
        nb, k = bank.n_bands, bank.order
        self.state_names = [("cgwt_tail", self.channels * (bank.n_taps - 1)),
                            ("cgwt_rec", self.channels * nb * 2 * k),
                            ("cgwt_frames", self.channels * nb * self.f_kept)]  # fmt: skip
        #: a fresh stream's tail is its first sample repeated (the runtime's rule); others zeros
        self.state_init = {"cgwt_tail": "repeat_first"}

    def initial_state(self, first: np.ndarray) -> dict[str, np.ndarray]:
        """The state of a fresh stream whose first samples are ``first [B, C]`` (float32)."""
        b = first.shape[0]
        tail = np.repeat(first.astype(np.float32)[:, :, None], self.bank.n_taps - 1, axis=2)
        return {"cgwt_tail": tail.reshape(b, -1),
                **{n: np.zeros((b, u), np.float32) for n, u in self.state_names[1:]}}  # fmt: skip

    def forward(
        self, chunk: Tensor, tail: Tensor, rec: Tensor, frames: Tensor
    ) -> tuple[Tensor, ...]:
        b, c, n = chunk.shape
        nb, k, nt = self.bank.n_bands, self.bank.order, self.bank.n_taps
        buf = torch.cat([tail.reshape(b * c, 1, nt - 1), chunk.reshape(b * c, 1, n)], -1)
        re, im, state = self.bank.frames_from(buf, rec.reshape(b * c, nb, 2 * k))
        mag = _modulus(re, im).reshape(b, c, nb, self.f_step)  # [B, C, bands, F step]
        window = torch.cat([frames.reshape(b, c, nb, self.f_kept), mag], -1)
        # the code is scale-free per window and channel; dividing by the window's largest frame
        # keeps its squares in float32 range whatever the sensor's units (the window graph
        # divides the samples by their peak instead: a stream's bank cannot)
        peak = window.amax((-2, -1), keepdim=True).clamp_min(torch.finfo(window.dtype).tiny)
        t = self.code(window / peak)
        if self.scatter is not None:
            t = self.scatter(t)
        new_rec = state.reshape(b, -1)
        kept = window[..., self.f_step :] if self.f_step < self.f_kept else mag
        return (t.unsqueeze(-1), buf[..., -(nt - 1) :].reshape(b, -1), new_rec,
                kept.reshape(b, -1))  # fmt: skip


def check_stream_step(step: int, window: int, hop: int) -> int:
    """``step``: samples per stream call, a whole number of hops (frames) that divides the
    window and is at most half of it (windows overlap; the window's earlier frames are state)."""
    step = int(step)
    if step < 1 or step % hop or window % step or 2 * step > window:
        fits = [s for s in range(hop, window // 2 + 1, hop) if window % s == 0]
        raise ValueError(
            f"a stream step of {step} samples does not fit: it must be a whole number of hops "
            f"({hop}) that divides the window ({window} samples) and is at most half of it"
            + (f" (these fit: {_some(fits)})" if fits else "")
        )
    return step


def _some(values: list[int]) -> str:
    """A list short enough for a message: its first four and last two beyond eight values."""
    if len(values) <= 8:
        return ", ".join(map(str, values))
    return ", ".join(map(str, values[:4])) + ", ..., " + ", ".join(map(str, values[-2:]))
