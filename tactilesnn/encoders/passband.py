"""The sensor's passband as a band restriction: which band centres need any work."""

from __future__ import annotations

import numpy as np


def passband_mask(
    freqs_hz: np.ndarray, fs_hz: float, passband_hz: tuple[float, float] | None = None
) -> np.ndarray:
    """Which band centres lie inside the sensor's passband (Hz, inclusive) and below 0.45 fs.

    Bands a sensor cannot deliver (above its Nyquist frequency or outside its bandwidth) need no
    work. Raises ValueError if no band is left.
    """
    f = np.asarray(freqs_hz, dtype=np.float64)
    keep = (f > 0) & (f <= 0.45 * fs_hz)
    if passband_hz is not None:
        lo, hi = passband_hz
        keep &= (f >= lo) & (f <= hi)
    if not keep.any():
        raise ValueError(
            f"no band centre of {f.min():.3g}-{f.max():.3g} Hz lies inside the passband "
            f"{passband_hz} Hz and below 0.45 fs = {0.45 * fs_hz:.3g} Hz"
        )
    return keep


def restrict_bands(
    freqs_hz: np.ndarray, fs_hz: float, passband_hz: tuple[float, float] | None = None
) -> np.ndarray:
    """The band centres :func:`passband_mask` keeps."""
    return np.asarray(freqs_hz, dtype=np.float64)[passband_mask(freqs_hz, fs_hz, passband_hz)]
