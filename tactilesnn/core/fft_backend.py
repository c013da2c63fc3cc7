"""FFT backends for the full-rate scalogram: scipy's pocketfft (always there), ducc0, pyFFTW.

The two calls the scalogram makes, behind one small contract:

* ``rfft(x, n, workers)``: real ``[rows, samples]`` -> complex ``[rows, n // 2 + 1]``, the
  signal zero-padded (or cut) to ``n`` along the last axis;
* ``ifft(z, axis, workers)``: unnormalised-forward / ``1/n``-inverse complex FFT along ``axis``;
  ``z`` may be overwritten.

``auto`` (the default) takes ducc0 when it is installed (``pip install tactilesnn[fast]``) and
scipy otherwise: ducc0 measured fastest on every workload of ``tactilesnn bench encoders --fft``
(docs/benchmarks.md: 0.55-0.92x of pocketfft's time), pyFFTW slower than pocketfft on most.
``TACTILESNN_FFT`` (``scipy``, ``ducc0``, ``pyfftw``, ``auto``) overrides it for a process.
All backends agree within float32 rounding (tests/encoders/test_fft_backend.py).
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np
import scipy.fft

BACKENDS = ("scipy", "ducc0", "pyfftw")
ENV = "TACTILESNN_FFT"


@dataclass(frozen=True)
class FFTBackend:
    name: str
    rfft: Callable[[np.ndarray, int, int], np.ndarray]
    ifft: Callable[[np.ndarray, int, int], np.ndarray]


def _scipy() -> FFTBackend:
    def rfft(x: np.ndarray, n: int, workers: int) -> np.ndarray:
        return scipy.fft.rfft(x, n=n, axis=-1, workers=workers)

    def ifft(z: np.ndarray, axis: int, workers: int) -> np.ndarray:
        return scipy.fft.ifft(z, axis=axis, workers=workers, overwrite_x=True)

    return FFTBackend("scipy", rfft, ifft)


def _ducc0() -> FFTBackend:
    import ducc0

    def rfft(x: np.ndarray, n: int, workers: int) -> np.ndarray:
        if x.shape[-1] != n:  # ducc0 has no length argument: pad or cut as scipy does
            padded = np.zeros((*x.shape[:-1], n), dtype=x.dtype)
            m = min(n, x.shape[-1])
            padded[..., :m] = x[..., :m]
            x = padded
        return ducc0.fft.r2c(x, axes=(x.ndim - 1,), nthreads=workers)

    def ifft(z: np.ndarray, axis: int, workers: int) -> np.ndarray:
        axis %= z.ndim
        # inorm=2: multiply by 1/n, numpy's inverse convention; out=z computes in place
        return ducc0.fft.c2c(z, axes=(axis,), forward=False, inorm=2, out=z, nthreads=workers)

    return FFTBackend("ducc0", rfft, ifft)


def _pyfftw() -> FFTBackend:
    import pyfftw.interfaces.cache
    import pyfftw.interfaces.scipy_fft as fftw

    pyfftw.interfaces.cache.enable()  # plans kept between calls of the same shape
    pyfftw.interfaces.cache.set_keepalive_time(60.0)

    def rfft(x: np.ndarray, n: int, workers: int) -> np.ndarray:
        return fftw.rfft(x, n=n, axis=-1, workers=workers)

    def ifft(z: np.ndarray, axis: int, workers: int) -> np.ndarray:
        return fftw.ifft(z, axis=axis, workers=workers, overwrite_x=True)

    return FFTBackend("pyfftw", rfft, ifft)


_FACTORIES = {"scipy": _scipy, "ducc0": _ducc0, "pyfftw": _pyfftw}


def available() -> list[str]:
    """The installed backends, in preference order for ``auto``."""
    return [b for b in BACKENDS if b == "scipy" or importlib.util.find_spec(b) is not None]


@cache
def _make(name: str) -> FFTBackend:
    return _FACTORIES[name]()


def get_backend(name: str | None = None) -> FFTBackend:
    """The backend ``name`` (``None``: ``$TACTILESNN_FFT`` or ``auto``).

    ``auto`` is ducc0 where installed, else scipy; naming one that is not installed is an error
    that says how to install it.
    """
    name = (name or os.environ.get(ENV) or "auto").strip().lower()
    if name == "auto":
        name = "ducc0" if "ducc0" in available() else "scipy"
    if name not in _FACTORIES:
        raise ValueError(f"unknown FFT backend {name!r}: choose one of {('auto', *BACKENDS)}")
    if name not in available():
        extra = "pip install 'tactilesnn[fast]'" if name == "ducc0" else f"pip install {name}"
        raise ImportError(f"FFT backend {name!r} is not installed ({extra})")
    return _make(name)
