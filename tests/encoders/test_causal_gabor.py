"""The causal recursive Gabor bank against its float64 sample-rate reference (scipy lfilter)."""

import numpy as np
import pytest
import scipy.signal
import torch

from tactilesnn.encoders.causal_gabor import (
    CausalGaborScalogram,
    CausalGaborStream,
    band_poles,
    reference_frames,
)
from tactilesnn.encoders.gwt import log_bands

FS = 2000.0
BANDS = log_bands(5.0, 800.0, 12)


def _signal(n=1500, channels=2, seed=0):
    rng = np.random.default_rng(seed)
    drift = np.cumsum(rng.standard_normal((channels, n)), 1) * 0.05
    return drift + rng.standard_normal((channels, n)) + 7.0  # a static offset too


@pytest.mark.parametrize("hop", [1, 7, 10])
def test_torch_window_path_equals_the_sample_rate_cascade(hop):
    x = _signal(1003)
    ref = reference_frames(x, FS, BANDS, hop)
    bank = CausalGaborScalogram(FS, BANDS, hop=hop)
    re, im = bank.analytic(torch.from_numpy(x[None]))
    got = (re + 1j * im).numpy()[0]
    assert got.shape == ref.shape == (2, len(BANDS), 1003 // hop)
    assert np.abs(got - ref).max() <= 1e-12 * np.abs(ref).max()
    mag32 = bank(torch.from_numpy(x[None]).float()).numpy()[0]  # float32 against float64
    assert np.abs(mag32 - np.abs(ref)).max() <= 2e-6 * np.abs(ref).max()


def test_design_unit_sinusoid_dc_and_frequency_response():
    p, g, tau = band_poles(FS, BANDS, order=4)
    for pb, gb, f in zip(p, g, BANDS, strict=True):
        # the cascade's response, independent of the design's own algebra: freqz of the
        # expanded filter (float64) at the centre and at DC
        b = gb * np.array([1.0, -1.0])
        a = np.poly(np.full(4, pb))
        _, h = scipy.signal.freqz(b, a, worN=[2 * np.pi * f / FS, 0.0])
        assert abs(h[0] - 2.0) < 1e-6 and abs(h[1]) == 0.0
    assert np.all(np.diff(tau) < 0)  # narrower bands (lower) ring longer
    t = np.arange(int(4 * FS)) / FS
    for f in BANDS[BANDS < 0.25 * FS]:
        y = np.abs(reference_frames(np.sin(2 * np.pi * f * t), FS, [f]))[0, -int(FS) :]
        assert np.abs(y - 1.0).max() < 0.03  # unit sinusoid -> 1 (+ the mirror image's ripple)
    const = reference_frames(np.full(3000, 123.0), FS, BANDS)
    assert np.abs(const).max() == 0.0  # a static offset never enters a band


@pytest.mark.parametrize("dtype,tol", [(np.float64, 1e-12), (np.float32, 2e-6)])
def test_stream_any_chunking_equals_one_pass(dtype, tol):
    x = _signal(2000)
    bank = CausalGaborScalogram(FS, BANDS, hop=10)
    ref = np.abs(reference_frames(x, FS, BANDS, 10))
    for sizes in ([2000], [1, 3, 250, 7, 0, 400, 1339], [10] * 200, [999, 1001]):
        st = CausalGaborStream(bank, 2, dtype)
        parts, i = [], 0
        for n in sizes:
            parts.append(st.push(x[:, i : i + n]))
            i += n
        got = np.concatenate(parts, -1)
        assert got.dtype == dtype and got.shape == ref.shape
        assert np.abs(got - ref).max() <= tol * ref.max()


@pytest.mark.slow
def test_long_float32_stream_does_not_drift_and_spans_five_decades():
    rng = np.random.default_rng(1)
    n = 400_000
    x = rng.standard_normal((1, n)) * np.geomspace(1e-3, 1e2, n)  # 5 decades of amplitude
    bank = CausalGaborScalogram(FS, BANDS, hop=8)
    s32, s64 = CausalGaborStream(bank, 1, np.float32), CausalGaborStream(bank, 1, np.float64)
    for i in range(0, n, 65_536):
        a, b = s32.push(x[:, i : i + 65_536]), s64.push(x[:, i : i + 65_536])
        assert np.isfinite(a).all()
        # relative to the frame's own scale: the recursion is contractive, errors do not grow
        scale = np.abs(x[:, max(0, i - 4000) : i + 65_536]).max()
        assert np.abs(a - b).max() <= 2e-6 * scale


def test_bad_input_is_refused_by_name():
    bank = CausalGaborScalogram(FS, BANDS, hop=4)
    st = CausalGaborStream(bank, 2)
    with pytest.raises(ValueError, match="NaN or Inf"):
        st.push(np.array([[0.0, np.nan], [0.0, 0.0]]))
    with pytest.raises(ValueError, match=r"channels=2"):
        st.push(np.zeros((3, 10)))
    with pytest.raises(ValueError, match="float32 or float64"):
        CausalGaborStream(bank, 2, np.int16)
    with pytest.raises(ValueError, match="Nyquist"):
        CausalGaborScalogram(FS, [1500.0])
    with pytest.raises(ValueError, match="hop"):
        CausalGaborScalogram(FS, BANDS, hop=0)
    with pytest.raises(ValueError, match="no frame"):
        bank(torch.zeros(1, 1, 3))


def test_linear_map_is_the_forward_transform():
    bank = CausalGaborScalogram(FS, BANDS[:4], hop=5)
    resp, pool = bank.linear_map(60)
    assert pool is None and resp.shape == (60, 4, 12)
    x = _signal(60, channels=1)
    want = bank(torch.from_numpy(x[None]))[0, 0].numpy()
    got = np.abs(np.einsum("n,nbf->bf", x[0], resp.numpy()))
    assert np.allclose(got, want, rtol=1e-10, atol=1e-12)
