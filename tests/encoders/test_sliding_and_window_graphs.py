"""Stream encoding (chunks, activity gate), numerical robustness, ONNX parity."""

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from tactilesnn.config import PipelineConfig
from tactilesnn.encoders.gwt import GaborScalogram, log_bands
from tactilesnn.encoders.latency import LatencyCode
from tactilesnn.encoders.passband import restrict_bands
from tactilesnn.encoders.sliding import SlidingEncoder
from tactilesnn.encoders.window_graphs import WindowEncoder, export_window_encoder
from tactilesnn.pipeline import SpikePipeline

FS = 200.0


def make_stream_encoder(**kw):
    g = GaborScalogram(FS, log_bands(3, 90, 16))
    return SlidingEncoder(g, LatencyCode(stats=("mean", "std")), window=100, hop=50, **kw)


@pytest.mark.slow
def test_chunked_equals_one_shot_on_a_long_stream():
    x = np.random.default_rng(0).standard_normal((1, 2, 200_000)).astype(np.float32)
    one = make_stream_encoder(chunk_windows=10**9).encode(x)
    chunked = make_stream_encoder(chunk_windows=97).encode(x)
    assert one.shape == (1, 3999, 64)
    np.testing.assert_array_equal(one, chunked)


def test_activity_gate_skips_quiet_parts_and_keeps_active_spikes_identical():
    rng = np.random.default_rng(1)
    x = 1e-4 * rng.standard_normal((2, 6, 4000))
    x[0, 2, 1000:2500] += np.sin(np.arange(1500) * 0.7)  # one taxel touched for a while
    gated = make_stream_encoder(noise_floor=1e-3)
    ungated = make_stream_encoder()
    a, b = gated.encode(x), ungated.encode(x)
    active = gated.active(np.lib.stride_tricks.sliding_window_view(x, 100, axis=-1)[:, :, ::50])
    assert 0 < active.sum() < 0.05 * active.size
    assert gated.last_stats["skipped_fraction"] > 0.95
    a = a.reshape(2, -1, 6, 32)
    b = b.reshape(2, -1, 6, 32)
    bi, ci, wi = np.nonzero(active)
    np.testing.assert_array_equal(a[bi, wi, ci], b[bi, wi, ci])
    assert np.isinf(a[~active.transpose(0, 2, 1)]).all(), "quiet windows emit no spikes"


@pytest.mark.parametrize("scale", [1e-6, 1e-3, 1.0, 1e3, 1e6])
def test_spanning_amplitudes_float32_matches_float64(scale):
    # PVDF spans 5 decades: the float32 scalogram and the spikes must not depend on the scale
    x = scale * np.random.default_rng(2).standard_normal((3, 2, 400))
    g = GaborScalogram(FS, log_bands(3, 90, 20))
    s32, s64 = g.transform(x, np.float32), g.transform(x, np.float64)
    assert np.isfinite(s32).all()
    assert np.abs(s32 - s64).max() <= 1e-5 * s64.max()
    code = LatencyCode(stats=("mean", "std"))
    t_scaled = code(torch.from_numpy(s32))
    t_unit = code(torch.from_numpy(g.transform(x / scale, np.float32)))
    np.testing.assert_allclose(t_scaled.numpy(), t_unit.numpy(), atol=1e-2)


def test_constant_step_and_zero_inputs_are_safe():
    g = GaborScalogram(FS, log_bands(3, 90, 12))
    code = LatencyCode(stats=("mean", "std"))
    zeros = np.zeros((1, 1, 300))
    const = np.full((1, 1, 300), 7.0)
    step = np.r_[np.zeros(150), np.ones(150)][None, None]
    for x in (zeros, const, step):
        s = g.transform(x)
        t = code(torch.from_numpy(s))
        assert np.isfinite(s).all() and not torch.isnan(t).any()
    assert torch.isinf(code(torch.from_numpy(g.transform(zeros)))).all()
    assert g.transform(const).max() < 1e-4 * 7.0  # reflect edges: no spurious edge energy


def test_restrict_bands_drops_what_the_sensor_cannot_deliver():
    f = log_bands(1, 900, 30)
    kept = restrict_bands(f, fs_hz=200.0, passband_hz=(2.0, 1000.0))
    assert kept.min() >= 2.0 and kept.max() <= 90.0
    with pytest.raises(ValueError, match="passband"):
        restrict_bands(f, fs_hz=200.0, passband_hz=(95.0, 99.0))


@pytest.mark.parametrize("encoder", ["gwt", "stft"])
def test_onnx_export_matches_torch(encoder, tmp_path):
    pipe = SpikePipeline(
        PipelineConfig.from_flat(encoder=encoder, clock_afferents=0),
        FS,
        100,
        ("static", "dynamic"),
        ("hook", "loop"),
    )
    enc = WindowEncoder(pipe.encoder.scalogram, pipe.encoder.code, 100, pipe.channel_idx)
    x = np.abs(np.random.default_rng(3).standard_normal((32, 2, 100))).astype(np.float32)
    ref = pipe.encode(x).numpy()[..., 0]  # the FFT implementation, one spike per afferent
    with torch.no_grad():
        mine = enc(torch.from_numpy(x)).numpy()
        scal = enc.scalogram(torch.from_numpy(x)).numpy()
    path = export_window_encoder(enc, 2, tmp_path / "enc.onnx")
    model = onnx.load(str(path))
    onnx.checker.check_model(model)
    assert model.opset_import[0].version >= 17
    got = ort.InferenceSession(str(path)).run(None, {"window": x})[0]
    for other in (ref, got):
        assert (np.isfinite(other) == np.isfinite(mine)).all()
        fin = np.isfinite(mine)
        # spike times agree within 1e-5 of the 500 ms code span
        assert np.abs(other[fin] - mine[fin]).max() <= 1e-5 * pipe.duration_ms
    sess = ort.InferenceSession(str(path))
    inner = sess.get_outputs()[0].name
    assert inner == "spike_times_ms"
    assert np.isfinite(scal).all()


def test_continuous_gwt_of_a_million_samples_in_chunks_equals_one_shot():
    x = np.random.default_rng(5).standard_normal((1, 1, 1_000_000)).astype(np.float32)
    g = GaborScalogram(FS, log_bands(3, 90, 8), hop=10)
    one = g.transform(x)
    chunked = g.transform_chunked(x, chunk_samples=65_536)
    assert chunked.shape == one.shape == (1, 1, 8, 100_000)
    assert np.abs(chunked - one).max() <= 1e-5 * one.max()


def test_latency_times_to_events_and_dense_agree():
    from tactilesnn.encoders.latency import to_dense, to_events

    t = torch.tensor([[0.0, 12.0, float("inf")], [3.0, float("inf"), 499.0]])
    ev = to_events(t, 500.0)
    assert len(ev) == 4
    np.testing.assert_array_equal(ev.to_dense(1.0), to_dense(t, 500.0, 1.0).numpy()[..., :500])


@pytest.mark.slow
def test_long_windows_export_the_gwt_within_its_budget(tmp_path):
    """A 4,000-sample window: the dense matrix form would need 1.3 GB; the per-band forms
    (low rank, short FIR, dense) stay within their 32 MB budget and match the encoder."""
    import onnxruntime as ort

    from tactilesnn.config import PipelineConfig
    from tactilesnn.export.onnx import build_parts

    fs, n = 2000.0, 4000
    pipe = SpikePipeline(PipelineConfig.from_flat(channels=("all",), f_hi_hz=800.0), fs, n,
                         ("a", "b"), ("x", "y"))  # fmt: skip
    enc, _ = build_parts(pipe)
    assert enc.ByteSize() < 32 << 20  # ~21 MB instead of 1.3 GB of matrices
    rng = np.random.default_rng(0)
    t = np.arange(n) / fs
    x = (np.sin(2 * np.pi * 40 * t) * (1 + rng.random((6, 2, 1))) + 0.3 * rng.standard_normal(
        (6, 2, n))).astype(np.float32)  # fmt: skip
    got = ort.InferenceSession(enc.SerializeToString()).run(["spikes"], {"window": x})[0]
    want = pipe.encode(x).numpy()
    fin = np.isfinite(want)
    assert np.array_equal(np.isfinite(got), fin)
    assert np.abs(got[fin] - want[fin]).max() < 1e-2  # ms, within the export's tolerance
