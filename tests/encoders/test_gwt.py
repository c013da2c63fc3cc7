"""Gabor scalogram against PyWavelets' cwt (cmor) and a float64 direct convolution."""

import numpy as np
import pytest
import pywt
import torch

from tactilesnn.encoders.gwt import GaborScalogram, log_bands

FS = 200.0


def direct_reference(x: np.ndarray, freqs: np.ndarray, b: float = 1.5, c: float = 1.0):
    """|x * h_b| with the sampled analytic Gabor kernel, float64, zero padding."""
    out = []
    for fb in freqs:
        s = c / fb
        half = int(np.ceil(6 * s * np.sqrt(b / 2) * FS))
        t = np.arange(-half, half + 1) / FS
        h = (2 / FS) / (s * np.sqrt(np.pi * b)) * np.exp(-(t**2) / (b * s**2))
        out.append(np.abs(np.convolve(x, h * np.exp(2j * np.pi * fb * t), mode="same")))
    return np.array(out)


def test_matches_direct_convolution_float64():
    x = np.random.default_rng(0).standard_normal(1500)
    freqs = np.geomspace(3, 40, 8)  # below 0.2 fs neither the Nyquist taper nor spill matter
    ours = GaborScalogram(FS, freqs, padding="zero").transform(x[None, None], np.float64)[0, 0]
    ref = direct_reference(x, freqs)
    err = np.abs(ours - ref).max(axis=1) / ref.max(axis=1)
    assert err.max() < 1e-6


def test_float32_close_to_float64():
    x = np.random.default_rng(1).standard_normal((3, 2, 700))
    g = GaborScalogram(FS, log_bands(3, 90, 20))
    a32, a64 = g.transform(x, np.float32), g.transform(x, np.float64)
    assert a32.dtype == np.float32
    assert np.abs(a32 - a64).max() <= 1e-4 * a64.max()


def test_shape_agrees_with_pywavelets_cmor():
    # PyWavelets is L2-normalised (sqrt(s)/2 for a unit sinusoid) and its integrated-wavelet
    # discretisation errs at high frequency, so compare shapes per scale, at precision 16,
    # on bands below 0.075 fs (its error reaches 5 % by 0.13 fs), away from the edges.
    x = np.random.default_rng(2).standard_normal(2000)
    freqs = np.geomspace(3, 15, 5)
    scales = 1.0 * FS / freqs
    coef, _ = pywt.cwt(x, scales, "cmor1.5-1.0", sampling_period=1 / FS, method="fft", precision=16)
    ref = np.abs(coef)[:, 300:-300]
    ours = GaborScalogram(FS, freqs).transform(x[None, None], np.float64)[0, 0, :, 300:-300]
    gain = np.median(ours / ref, axis=1)
    np.testing.assert_allclose(gain * np.sqrt(scales) / 2, 1.0, rtol=0.03)
    shape_err = np.abs(ours - gain[:, None] * ref).max(axis=1) / ours.max(axis=1)
    assert shape_err.max() < 0.03


@pytest.mark.parametrize(("f", "tol"), [(3.0, 1e-6), (10.0, 1e-6), (40.0, 1e-6), (90.0, 1e-5)])
def test_unit_sinusoid_gives_one_at_its_band(f, tol):
    t = np.arange(4000) / FS
    s = GaborScalogram(FS, [f]).transform(np.cos(2 * np.pi * f * t)[None, None], np.float64)
    assert s[0, 0, 0, 1000:3000] == pytest.approx(1.0, abs=tol)


@pytest.mark.parametrize("padding", ["reflect", "zero", "periodic"])
@pytest.mark.parametrize("hop", [2, 3, 10])
def test_decimated_frames_are_exact(padding, hop):
    # folding the band spectra modulo L / hop is exact decimation, not interpolation
    x = np.random.default_rng(3).standard_normal((2, 3, 1000))
    freqs = log_bands(2, 90, 24)
    full = GaborScalogram(FS, freqs, padding=padding).transform(x, np.float64)
    dec = GaborScalogram(FS, freqs, padding=padding, hop=hop).transform(x, np.float64)
    assert dec.shape == (2, 3, 24, -(-1000 // hop))
    assert np.abs(dec - full[..., ::hop]).max() <= 1e-5 * full.max()
    torch_dec = GaborScalogram(FS, freqs, padding=padding, hop=hop)(torch.from_numpy(x)).numpy()
    assert np.abs(dec - torch_dec).max() <= 1e-5 * full.max()


def test_numpy_and_torch_paths_agree():
    x = np.random.default_rng(4).standard_normal((3, 2, 777))
    g = GaborScalogram(FS, log_bands(2, 90, 16))
    np.testing.assert_allclose(
        g.transform(x, np.float64), g(torch.from_numpy(x)).numpy(), atol=1e-9, rtol=0
    )


def test_edge_modes_and_contract():
    x = torch.randn(4, 3, 100)
    for mode in ("reflect", "zero", "periodic"):
        out = GaborScalogram(FS, log_bands(3, 90, 12), padding=mode)(x)
        assert out.shape == (4, 3, 12, 100) and torch.isfinite(out).all()
    # reflect padding: a constant signal has no band energy anywhere, edges included
    const = GaborScalogram(FS, log_bands(5, 90, 8)).transform(np.ones((1, 1, 100)))
    assert const.max() < 1e-3


def test_rejects_bad_input():
    with pytest.raises(ValueError, match="Nyquist"):
        GaborScalogram(FS, [95.0])
    with pytest.raises(ValueError, match="padding"):
        GaborScalogram(FS, [10.0], padding="wrap")
    g = GaborScalogram(FS, [10.0])
    x = np.zeros((1, 2, 50))
    x[0, 1, 7] = np.nan
    with pytest.raises(ValueError, match="channel 1, sample 7"):
        g.transform(x)
    with pytest.raises(ValueError, match="dimensions"):
        g.transform(np.zeros(50))


@pytest.mark.parametrize(
    ("fs", "n", "hop"), [(4000.0, 2000, 1), (1000.0, 3000, 1), (4000.0, 2000, 4)]
)
@pytest.mark.slow
def test_fir_export_form_matches_fft_path(fs: float, n: int, hop: int) -> None:
    """The exported FIR form equals the FFT path, also when the lowest wavelet outlasts the
    window (4 kHz, 0.5 s window, 3 Hz band: the FFT's wrap-around must be reproduced)."""
    from tactilesnn.encoders.gwt import log_bands
    from tactilesnn.encoders.latency import LatencyCode
    from tactilesnn.encoders.window_graphs import GaborConvEncoder

    sc = GaborScalogram(fs, log_bands(3.0, 90.0, 20), hop=hop)
    enc = GaborConvEncoder(sc, LatencyCode(), n).double()
    x = torch.from_numpy(np.random.default_rng(0).standard_normal((2, 3, n)))
    ref = sc(x)
    got = enc.scalogram(x)
    assert got.shape == ref.shape
    assert float((got - ref).abs().max() / ref.abs().max()) < 1e-6
    assert enc.weight.shape[-1] <= 4 * n  # size independent of window^2


def test_feature_map_is_the_scalogram_the_code_reads():
    """The run folder's picture shows the map the latency code is computed from."""
    import torch

    from tactilesnn.encoders import build_encoder
    from tactilesnn.encoders.base import ENCODERS
    from tactilesnn.encoders.scalogram_latency import unit_peak

    x = np.random.default_rng(0).standard_normal((2, 100)).astype(np.float32)
    enc = build_encoder(ENCODERS.config_class("gwt")(), 200.0, 100, 2)
    mag, freqs = enc.feature_map(x)
    assert mag.shape == (len(freqs), 100) and np.all(np.diff(freqs) > 0)
    scal = enc.scalogram(unit_peak(torch.from_numpy(x)[None]))[0].sum(0).numpy()
    np.testing.assert_allclose(mag, scal, rtol=1e-6)
    lif = build_encoder(ENCODERS.config_class("lif")(), 200.0, 100, 2)
    assert lif.feature_map(x) is None


@pytest.mark.slow
def test_gwt_hop_decimates_exactly_and_exports(tmp_path):
    """hop h: the frames are every h-th frame of the full-rate scalogram (exact), and the
    exported graph matches the torch encoder."""
    import onnxruntime as ort
    import torch

    from tactilesnn.core.onnx_graph import torch_to_onnx
    from tactilesnn.encoders import build_encoder
    from tactilesnn.encoders.base import ENCODERS
    from tactilesnn.encoders.scalogram_latency import unit_peak

    cfg = ENCODERS.config_class("gwt")
    x = np.random.default_rng(1).standard_normal((8, 2, 200)).astype(np.float32)
    full = build_encoder(cfg(), 200.0, 200, 2)
    dec = build_encoder(cfg(hop=5), 200.0, 200, 2)
    t = unit_peak(torch.from_numpy(x))
    np.testing.assert_allclose(dec.scalogram(t).numpy(), full.scalogram(t).numpy()[..., ::5],
                               rtol=1e-4, atol=1e-6)  # fmt: skip
    ref = dec.encode(x).numpy()
    torch_to_onnx(dec.onnx_module(), (torch.from_numpy(x[:2]),), tmp_path / "g.onnx", ["window"],
                  ["spikes"])  # fmt: skip
    got = ort.InferenceSession(str(tmp_path / "g.onnx")).run(None, {"window": x})[0]
    fin = np.isfinite(ref)
    assert np.array_equal(np.isfinite(got), fin) and np.abs(got[fin] - ref[fin]).max() < 0.05
    with pytest.raises(ValueError, match="hop"):
        cfg(hop=0)


def test_data_defaults_follow_the_rate_and_the_training_spectrum():
    from tactilesnn.encoders.base import ENCODERS
    from tactilesnn.selection import median_power_frequency

    for name in ("gwt", "stft"):
        cls = ENCODERS.config_class(name)
        hi = cls.data_defaults(2000.0, 3250, 150.0)  # power above 3 Hz: keeps 3 Hz
        assert hi == {"f_lo_hz": 3.0, "f_hi_hz": 900.0, "n_bands": 34, "dynamic_range_db": 60.0}
        # the default density: 20 bands per 30x
        assert hi["n_bands"] / np.log(300) == pytest.approx(20 / np.log(30), rel=0.02)
        slow = cls.data_defaults(500.0, 1500, 0.67)  # slow presses: bands reach down to them
        assert slow["f_lo_hz"] == 0.67 and slow["n_bands"] == 34
        assert cls.data_defaults(500.0, 1500, 0.01)["f_lo_hz"] == pytest.approx(1 / 3)  # 1 cycle
        assert cls.data_defaults(200.0, 100, 8.0)["f_hi_hz"] == 90.0
        assert cls.data_defaults(1e12, 100, 1e9)["n_bands"] == 128  # capped
    fs = 500.0
    t = np.arange(1500) / fs
    x = (np.sin(2 * np.pi * 0.8 * t) + 0.1 * np.sin(2 * np.pi * 40 * t))[None, None]
    assert median_power_frequency(np.repeat(x, 4, 0), fs) == pytest.approx(0.8, abs=1 / 3)


@pytest.mark.parametrize(
    ("padding", "n", "hop"), [("reflect", 1000, 10), ("reflect", 400, 1), ("zero", 300, 3),
                              ("periodic", 256, 4)],
)  # fmt: skip
@pytest.mark.slow
def test_factored_export_form_matches_fft_path(padding: str, n: int, hop: int) -> None:
    """Low-rank, FIR and dense bands together reproduce the FFT path in float64 (to the rank
    tolerance), with fewer multiply-adds than the dense window matrices, and code the same
    spikes in band order."""
    from tactilesnn.encoders.gwt import log_bands
    from tactilesnn.encoders.latency import LatencyCode
    from tactilesnn.encoders.window_graphs import FactoredGaborEncoder, WindowEncoder

    sc = GaborScalogram(2000.0, log_bands(5.0, 800.0, 20), hop=hop, padding=padding)
    enc = FactoredGaborEncoder(sc, LatencyCode(stats=("mean", "std")), n).double()
    x = torch.from_numpy(np.random.default_rng(0).standard_normal((2, 3, n)))
    x[1, 2] = torch.sin(torch.arange(n) * 0.3)  # a pure tone: most bands far below the peak
    ref = sc(x)[:, :, enc.order]
    got = enc.scalogram(x)
    assert got.shape == ref.shape
    rel = (got - ref).abs().amax(-1) / ref.abs().amax(-1)
    assert float(rel.max()) < 3e-5
    kinds = set(enc.kinds)
    assert "low_rank" in kinds and ("conv" in kinds or padding == "periodic")
    frames = -(-n // hop)
    assert enc.macs_per_channel() < 0.7 * 2 * n * sc.n_bands * frames
    if (padding, n) == ("reflect", 1000):  # the low bands' U's share a 147-dimensional basis
        assert 0 < enc.basis_rank < sum(enc.lr_cols) / 3
        assert enc.macs_per_channel() < 0.3 * 2 * n * sc.n_bands * frames
    dense = WindowEncoder(sc, LatencyCode(stats=("mean", "std")), n).double()
    t_ref, t_got = dense(x), enc(x)
    fin = torch.isfinite(t_ref)
    assert torch.equal(torch.isfinite(t_got), fin)
    assert float((t_got[fin] - t_ref[fin]).abs().max()) < 1e-2  # ms


@pytest.mark.parametrize("hop", [1, 3, 10])
@pytest.mark.parametrize("taps", [1, 7, 185])
def test_polyphase_convolution_equals_the_strided_convolution(hop: int, taps: int) -> None:
    from tactilesnn.encoders.window_graphs import polyphase_conv, polyphase_weight

    g = torch.Generator().manual_seed(hop * 1000 + taps)
    for length in (taps, taps + 1, taps + hop * 7 + 2, 1184):
        seg = torch.randn(5, 1, length, dtype=torch.float64, generator=g)
        w = torch.randn(6, 1, taps, dtype=torch.float64, generator=g)
        ref = torch.nn.functional.conv1d(seg, w, stride=hop)
        got = polyphase_conv(seg, polyphase_weight(w, hop), ref.shape[-1])
        assert got.shape == ref.shape
        assert torch.allclose(got, ref, rtol=0, atol=1e-12)
