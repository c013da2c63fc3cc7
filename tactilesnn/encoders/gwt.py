"""Gabor (complex Morlet) wavelet scalogram, computed in the frequency domain.

Wavelet: PyWavelets' ``cmorB-C`` shape, ``psi(t) = (pi B)^-1/2 exp(-t^2 / B) exp(i 2 pi C t)``,
whose Fourier transform is ``exp(-pi^2 B (f - C)^2)``. At centre frequency ``f_b`` (Hz) the scale is
``s = C / f_b`` (s), giving the analytic band-pass response

    H_b(f) = 2 exp(-pi^2 B (s f - C)^2)   for f > 0,   H_b(0) = exp(-pi^2 B C^2),   0 for f < 0.

Normalisation convention: a unit-amplitude sinusoid at ``f_b`` gives a scalogram magnitude of 1.0 in
its band, at every band (PyWavelets' L2 convention gives ``sqrt(s)/2`` instead), so spike
thresholds do not depend on the band. Relative bandwidth: the response's standard deviation is
``f_b / (pi C sqrt(2 B))`` = 0.184 f_b for cmor1.5-1.0.

Edge handling (``padding``): ``"reflect"`` (default) mirrors the signal by up to ``4 sigma_t`` of
the widest wavelet (at most ``samples - 1``), ``"zero"`` pads with zeros (equals a linear
convolution with the sampled analytic kernel), ``"periodic"`` treats the input as one period.

Array contract: input ``[batch, channels, samples]`` float at ``fs_hz``; output magnitude
``[batch, channels, bands, samples]`` in the input's units (float32 by default).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.fft
import torch
from torch import nn

from .._checks import as_float_array, check_choice, check_finite, check_positive

PADDINGS = ("reflect", "zero", "periodic")


def log_bands(f_lo_hz: float, f_hi_hz: float, n: int) -> np.ndarray:
    """``n`` centre frequencies spaced evenly in log-frequency from ``f_lo_hz`` to ``f_hi_hz``."""
    if not 0 < f_lo_hz < f_hi_hz or n < 1:
        raise ValueError(f"need 0 < f_lo < f_hi and n >= 1, got {f_lo_hz}, {f_hi_hz}, {n}")
    return np.geomspace(f_lo_hz, f_hi_hz, n)


def gabor_response(
    freqs_hz: np.ndarray, fft_freqs_hz: np.ndarray, bandwidth: float, center: float
) -> np.ndarray:
    """Analytic Gabor response ``H[b, k]`` at non-negative FFT frequencies (float64)."""
    s = center / np.asarray(freqs_hz, dtype=np.float64)[:, None]
    h = 2.0 * np.exp(-(np.pi**2) * bandwidth * (s * fft_freqs_hz[None, :] - center) ** 2)
    h[:, fft_freqs_hz == 0] *= 0.5  # DC is not doubled by the analytic signal
    return h


def check_bands(freqs_hz: Sequence[float], fs_hz: float) -> np.ndarray:
    """Validate centre frequencies: finite, positive, strictly below Nyquist."""
    f = np.asarray(freqs_hz, dtype=np.float64).ravel()
    if f.size == 0:
        raise ValueError("freqs_hz must contain at least one band")
    if not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise ValueError(f"freqs_hz must be finite and positive, got {f}")
    if np.any(f >= fs_hz / 2):
        raise ValueError(
            f"band centre {f.max():.3g} Hz is not below the Nyquist frequency {fs_hz / 2:.3g} Hz "
            f"of fs = {fs_hz:.3g} Hz"
        )
    return f


class GaborScalogram(nn.Module):
    """Complex-Morlet (Gabor) scalogram magnitude via one FFT per signal, batched over bands.

    Args:
        fs_hz: sampling rate of the input (Hz).
        freqs_hz: band centre frequencies (Hz), each below Nyquist.
        bandwidth: cmor bandwidth parameter B (1.5 by default, as ``cmor1.5-1.0``).
        center: cmor centre-frequency parameter C (1.0).
        padding: edge handling, one of ``reflect``, ``zero``, ``periodic``.
    """

    def __init__(
        self,
        fs_hz: float,
        freqs_hz: Sequence[float],
        bandwidth: float = 1.5,
        center: float = 1.0,
        padding: str = "reflect",
    ) -> None:
        super().__init__()
        self.fs_hz = check_positive(fs_hz, "fs_hz")
        self.freqs_hz = check_bands(freqs_hz, self.fs_hz)
        self.bandwidth = check_positive(bandwidth, "bandwidth")
        self.center = check_positive(center, "center")
        self.padding = check_choice(padding, "padding", PADDINGS)
        self._cache: dict[tuple[int, torch.dtype], torch.Tensor] = {}

    @property
    def n_bands(self) -> int:
        return self.freqs_hz.size

    def time_sigma_s(self) -> np.ndarray:
        """Standard deviation of each wavelet's envelope |psi| in seconds: s sqrt(B / 2)."""
        return self.center / self.freqs_hz * np.sqrt(self.bandwidth / 2)

    def pad_len(self, n: int) -> int:
        if self.padding == "periodic":
            return 0
        p = int(np.ceil(4 * self.time_sigma_s().max() * self.fs_hz))
        return min(p, n - 1) if self.padding == "reflect" else p

    def _filters(self, n_fft: int, dtype: torch.dtype) -> torch.Tensor:
        key = (n_fft, dtype)
        if key not in self._cache:
            f = np.fft.rfftfreq(n_fft, 1.0 / self.fs_hz)
            h = gabor_response(self.freqs_hz, f, self.bandwidth, self.center)
            self._cache[key] = torch.from_numpy(h).to(dtype)
        return self._cache[key]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``[batch, channels, samples]`` -> magnitude ``[batch, channels, bands, samples]``."""
        if x.ndim != 3:
            raise ValueError(f"expected [batch, channels, samples], got shape {tuple(x.shape)}")
        n = x.shape[-1]
        p = self.pad_len(n)
        if p:
            mode = "reflect" if self.padding == "reflect" else "constant"
            x = nn.functional.pad(x, (p, p), mode=mode)
        n_fft = scipy.fft.next_fast_len(x.shape[-1])
        spec = torch.fft.rfft(x, n=n_fft)  # [B, C, K]
        h = self._filters(n_fft, x.dtype)  # [F, K]
        # zero negative frequencies: ifft of a half spectrum padded with zeros is analytic
        w = torch.fft.ifft(spec.unsqueeze(-2) * h, n=n_fft)
        return w[..., p : p + n].abs()

    def transform(self, x: np.ndarray, dtype: np.dtype | type = np.float32) -> np.ndarray:
        """NumPy entry point with validation: ``[batch, channels, samples]`` -> scalogram."""
        arr = as_float_array(x, "x", ndim=3)
        check_finite(arr, "x")
        if arr.shape[-1] < 2:
            raise ValueError(f"need at least 2 samples per channel, got {arr.shape[-1]}")
        with torch.no_grad():
            return self(torch.from_numpy(np.ascontiguousarray(arr, dtype=dtype))).numpy()
