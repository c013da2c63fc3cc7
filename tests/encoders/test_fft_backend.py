"""Every installed FFT backend gives the scalogram of scipy's pocketfft within float32 rounding."""

from __future__ import annotations

import numpy as np
import pytest

from tactilesnn.core import fft_backend
from tactilesnn.encoders.gwt import GaborScalogram, log_bands


@pytest.mark.parametrize("backend", fft_backend.available())
@pytest.mark.parametrize("padding", ["reflect", "zero", "periodic"])
def test_backends_agree_with_float64(backend: str, padding: str) -> None:
    rng = np.random.default_rng(3)
    x = rng.standard_normal((3, 2, 500)) * np.array([1e-3, 1e2])[None, :, None]
    g = GaborScalogram(200.0, log_bands(2.0, 90.0, 12), padding=padding, hop=4)
    ref = g.transform(x, np.float64, fft="scipy")
    peak = np.abs(ref).max(axis=(-2, -1))  # per channel: the channels are 5 decades apart
    for dtype, tol in ((np.float32, 2e-6), (np.float64, 1e-13)):
        got = g.transform(x, dtype, fft=backend, workers=2)
        assert got.dtype == dtype and got.shape == ref.shape
        assert (np.abs(got - ref).max(axis=(-2, -1)) / peak).max() < tol


def test_ducc0_is_installed_with_dev_and_chosen_by_auto() -> None:
    # the dev extra installs ducc0, so CI runs the fast path, not only the fallback
    assert "ducc0" in fft_backend.available()
    assert fft_backend.get_backend().name == "ducc0"
    assert fft_backend.get_backend("auto").name == "ducc0"


def test_environment_override_and_errors(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(fft_backend.ENV, "scipy")
    assert fft_backend.get_backend().name == "scipy"
    with pytest.raises(ValueError, match="unknown FFT backend 'mkl'"):
        fft_backend.get_backend("mkl")
    monkeypatch.setattr(fft_backend, "available", lambda: ["scipy"])
    assert fft_backend.get_backend("auto").name == "scipy"
    with pytest.raises(ImportError, match=r"tactilesnn\[fast\]"):
        fft_backend.get_backend("ducc0")


def test_ducc0_pads_and_cuts_like_scipy() -> None:
    x = np.random.default_rng(0).standard_normal((4, 37)).astype(np.float32)
    s, d = fft_backend.get_backend("scipy"), fft_backend.get_backend("ducc0")
    for n in (30, 37, 64):
        np.testing.assert_allclose(d.rfft(x, n, 1), s.rfft(x, n, 1), rtol=0, atol=1e-5)
    z = (x[:, :, None] + 1j * x[:, None, :5]).astype(np.complex64)
    np.testing.assert_allclose(d.ifft(z.copy(), 1, 1), s.ifft(z.copy(), 1, 1), atol=1e-6)


@pytest.mark.parametrize("hop", [1, 2, 4])
@pytest.mark.parametrize("padding", ["reflect", "periodic"])
def test_placed_band_rows_equal_the_sparse_folding(hop: int, padding: str) -> None:
    # the direct placement (no band wider than the folded length) and the sparse folding are
    # two layouts of one computation: identical magnitudes; hop 4 folds the 90 Hz band's support
    # onto fewer bins than it spans, which only the sparse folding can do
    x = np.random.default_rng(5).standard_normal((2, 3, 800))
    g = GaborScalogram(200.0, log_bands(2.0, 90.0, 16), hop=hop, padding=padding)
    got = g.transform(x, np.float64)
    plans = [v for k, v in g._cache.items() if k[0] == "plan"]
    assert len(plans) == 1 and (plans[0]["place"] is None) == (hop == 4)
    if hop == 4:
        return
    plans[0]["place"] = None  # force the sparse path on the same plan
    np.testing.assert_allclose(g.transform(x, np.float64), got, rtol=0, atol=1e-12)
