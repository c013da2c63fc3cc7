"""Window encoders as plain matrix products, for ONNX export (opset >= 17).

For a fixed window length the scalogram is a fixed linear map of the window followed by a modulus:
the map is built by transforming unit impulses with the FFT implementation itself, so it is the
same transform (edge handling included), expressed as two MatMuls (real and imaginary parts).
Array contract of :class:`WindowEncoder`: ``[batch, channels, window]`` float32 -> spike times
``[batch, neurons]`` float32 (ms, ``+inf`` = silent), identical in layout to
``SpikePipeline.encode``.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path

import torch
from torch import nn

from .gwt import GaborScalogram
from .latency import LatencyCode
from .stft import STFTScalogram


class WindowEncoder(nn.Module):
    """Channel selection -> scalogram (as MatMuls) -> latency code, for one window length."""

    def __init__(
        self,
        scalogram: GaborScalogram | STFTScalogram,
        code: LatencyCode,
        window: int,
        channel_idx: Sequence[int],
    ) -> None:
        super().__init__()
        self.code = code
        self.window = int(window)
        self.register_buffer("channel_idx", torch.as_tensor(list(channel_idx), dtype=torch.long))
        eye = torch.eye(self.window, dtype=torch.float64).unsqueeze(1)  # [N impulses, 1, N]
        with torch.no_grad():
            if isinstance(scalogram, GaborScalogram):
                resp = scalogram.analytic(eye)[:, 0]  # [N, F, T]
                self.register_buffer("bands", torch.empty(0), persistent=False)
            else:
                resp = scalogram.spectrum(eye)[:, 0]  # [N, K, T]
                self.register_buffer("bands", scalogram.bands.float())
        self.rows, self.frames = resp.shape[1], resp.shape[2]
        flat = resp.reshape(self.window, -1)
        self.register_buffer("re", flat.real.float().contiguous())
        self.register_buffer("im", flat.imag.float().contiguous())
        self.is_stft = isinstance(scalogram, STFTScalogram)

    def scalogram(self, x: torch.Tensor) -> torch.Tensor:
        x = torch.index_select(x, 1, self.channel_idx)
        re, im = x @ self.re, x @ self.im  # [B, C, rows * frames]
        mag = torch.sqrt(re * re + im * im).reshape(x.shape[0], x.shape[1], self.rows, self.frames)
        if self.is_stft:
            mag = torch.einsum("fk,bckt->bcft", self.bands, 2.0 * mag)
        return mag

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.code(self.scalogram(x))


def export_window_encoder(
    encoder: WindowEncoder, n_channels: int, path: str | Path, opset: int = 17
) -> Path:
    """Write ``encoder`` as ONNX with a dynamic batch axis; returns the path."""
    path = Path(path)
    dummy = torch.zeros(1, n_channels, encoder.window)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(
            encoder,
            (dummy,),
            str(path),
            input_names=["window"],
            output_names=["spike_times_ms"],
            dynamic_axes={"window": {0: "batch"}, "spike_times_ms": {0: "batch"}},
            opset_version=opset,
            dynamo=False,
        )
    return path
