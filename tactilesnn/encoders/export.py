"""Window encoders as plain matrix products, for ONNX export (opset >= 17).

For a fixed window length a scalogram is a fixed linear map of the window followed by a modulus
(and, for the STFT, a band pooling): the map is the scalogram's own :meth:`linear_map` (built by
transforming unit impulses with the FFT implementation itself, edges included), expressed as two
MatMuls (real and imaginary parts). Array contract of :class:`WindowEncoder`: ``[batch, channels,
window]`` float32 -> spike times ``[batch, neurons]`` float32 (ms, ``+inf`` = silent).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch
from torch import nn

from .latency import LatencyCode


class WindowEncoder(nn.Module):
    """(Channel selection ->) scalogram as MatMuls -> latency code, for one window length.

    ``scalogram``: any module with ``linear_map(window) -> (response, pool or None)``.
    """

    def __init__(
        self,
        scalogram: nn.Module,
        code: LatencyCode,
        window: int,
        channel_idx: Sequence[int] | None = None,
    ) -> None:
        super().__init__()
        self.code = code
        self.window = int(window)
        idx = torch.as_tensor(
            list(channel_idx) if channel_idx is not None else [], dtype=torch.long
        )
        self.select = channel_idx is not None
        self.register_buffer("channel_idx", idx)
        resp, pool = scalogram.linear_map(self.window)
        self.rows, self.frames = resp.shape[1], resp.shape[2]
        flat = resp.reshape(self.window, -1)
        self.register_buffer("re", flat.real.float().contiguous())
        self.register_buffer("im", flat.imag.float().contiguous())
        self.pooled = pool is not None
        self.register_buffer("pool", pool.float() if pool is not None else torch.empty(0))

    def scalogram(self, x: torch.Tensor) -> torch.Tensor:
        if self.select:
            x = torch.index_select(x, 1, self.channel_idx)
        re, im = x @ self.re, x @ self.im  # [B, C, rows * frames]
        mag = torch.sqrt(re * re + im * im).reshape(x.shape[0], x.shape[1], self.rows, self.frames)
        if self.pooled:
            mag = torch.einsum("fk,bckt->bcft", self.pool, mag)
        return mag

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.code(self.scalogram(x))


class GaborConvEncoder(nn.Module):
    """Gabor scalogram as an edge pad + 1-D convolution (real and imaginary FIR kernels) ->
    modulus -> latency code. Its size is ``bands x taps``, independent of the window, so long
    windows export where the ``window^2`` matrices of :class:`WindowEncoder` would not fit.
    """

    def __init__(self, scalogram: nn.Module, code: LatencyCode, window: int) -> None:
        super().__init__()
        self.code = code
        self.window = int(window)
        self.pad = scalogram.pad_len(self.window)
        self.reflect = scalogram.padding == "reflect"
        self.hop = int(scalogram.hop)
        k = scalogram.conv_kernels(self.window)  # [F, 2L + 1], lag -L..L
        self.taps = (k.shape[1] - 1) // 2
        self.bands = k.shape[0]
        # conv1d correlates: output t = sum_u in[t + u] w[u], so the kernel is flipped
        w = torch.cat([k.real, k.imag]).flip(1).unsqueeze(1).float()  # [2F, 1, 2L + 1]
        self.register_buffer("weight", w.contiguous())

    def scalogram(self, x: torch.Tensor) -> torch.Tensor:
        b, c, n = x.shape
        flat = x.reshape(b * c, 1, n)
        if self.pad:
            mode = "reflect" if self.reflect else "constant"
            flat = nn.functional.pad(flat, (self.pad, self.pad), mode=mode)
        # output j is centred on padded sample pad + j * hop and needs taps samples either side
        extra = self.taps - self.pad
        if extra > 0:
            flat = nn.functional.pad(flat, (extra, extra))
        elif extra < 0:
            flat = flat[..., -extra : flat.shape[-1] + extra]
        out = nn.functional.conv1d(flat, self.weight, stride=self.hop)
        re, im = out[:, : self.bands], out[:, self.bands :]
        return torch.sqrt(re * re + im * im).reshape(b, c, self.bands, -1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.code(self.scalogram(x))


def export_window_encoder(
    encoder: WindowEncoder, n_channels: int, path: str | Path, opset: int = 17
) -> Path:
    """Write ``encoder`` as ONNX with a dynamic batch axis; returns the path."""
    from ..export.graph import torch_to_onnx

    path = Path(path)
    dummy = torch.zeros(1, n_channels, encoder.window)
    torch_to_onnx(encoder, (dummy,), path, ["window"], ["spike_times_ms"], opset=opset)
    return path
