"""Activity gate on the main paths: encoder, training metrics, export and the service stream."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tactilesnn.config import PipelineConfig
from tactilesnn.datasets_synth import WindowDataset
from tactilesnn.encoders import build_encoder
from tactilesnn.encoders.base import ENCODERS
from tactilesnn.export import export_pipeline
from tactilesnn.service.runtime import PipelineSession, StreamState
from tactilesnn.training import fit_and_evaluate

FS, W = 200.0, 100


def _touches(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Windows of 3 taxels: noise everywhere, one taxel touched by a class-specific vibration
    in half of the windows (the other half: nothing touched)."""
    rng = np.random.default_rng(seed)
    X = 1e-3 * rng.standard_normal((n, 3, W))
    y = rng.integers(0, 2, n)
    t = np.arange(W) / FS
    touched = rng.random(n) < 0.5
    for i in np.flatnonzero(touched):
        f = 20.0 if y[i] else 60.0
        X[i, rng.integers(3)] += np.sin(2 * np.pi * f * t + rng.uniform(0, 6))
    return X.astype(np.float32), y


def test_gate_skips_quiet_channels_and_keeps_active_ones_exact():
    X, _ = _touches(64, 0)
    for name in ("gwt", "stft"):
        cfg = ENCODERS.config_class(name)
        ref = build_encoder(cfg(), FS, W, 3).fit(X)
        gated = build_encoder(cfg(gate=3.0), FS, W, 3).fit(X)
        a, b = ref.encode(X).numpy(), gated.encode(X).numpy()
        per = a.shape[1] // 3
        active = X.std(-1) > gated.gate_rms.numpy()
        assert 0 < active.mean() < 0.5  # the touched channels only
        for c in range(3):
            blk = slice(c * per, (c + 1) * per)
            # same code up to float32 rounding (a smaller FFT batch), same silent slots
            np.testing.assert_allclose(b[active[:, c], blk], a[active[:, c], blk], atol=0.05)
            assert np.isinf(b[~active[:, c], blk]).all()
        st = gated.skip_stats()["activity_gate"]
        assert st["channel_windows"] == X.shape[0] * 3
        assert st["skipped_fraction"] == 1 - active.mean()
        with gated.skipping(False):
            np.testing.assert_array_equal(gated.encode(X).numpy(), a)
        assert ref.skip_stats() is None


@pytest.mark.slow
def test_training_reports_the_gate_and_the_service_skips_silent_windows_exactly(tmp_path):
    Xtr, ytr = _touches(400, 1)
    Xte, yte = _touches(200, 2)
    names, classes = ("t0", "t1", "t2"), ("slow", "fast")
    tr = WindowDataset(Xtr, ytr, np.arange(400), FS, classes, names)
    te = WindowDataset(Xte, yte, np.arange(200), FS, classes, names)
    cfg = PipelineConfig.from_flat(model="readout", channels=("all",), gate=3.0, epochs=5)
    res = fit_and_evaluate(cfg, tr, te)
    gate = res.metrics["activity_gate"]
    assert 0.5 < gate["skipped_fraction"] < 0.95
    assert 0 <= gate["predictions_changed"] <= 1 and "test_accuracy_without_skipping" in gate
    path = tmp_path / "m.onnx"
    export_pipeline(res.pipeline, path, Xte)  # the graph masks as the encoder skips
    sess = PipelineSession(str(path))
    assert json.loads(sess.metadata["encoder_channels"]) == [0, 1, 2]
    # a stream of quiet and touched windows: identical to running the graph on every window
    stream = np.concatenate(list(Xte[:20]), axis=1)
    got = sess.feed_stream(StreamState(), stream, hop=W)
    want = sess.run(Xte[:20])
    np.testing.assert_allclose([r["scores"] for r in got], want, atol=1e-6)
    assert sess.info()["stats"]["stream_windows"] == 20
    quiet = (Xte[:20].std(-1) <= res.pipeline.encoder.gate_rms.numpy()).all(1).sum()
    assert sess.info()["stats"]["stream_windows_skipped"] == quiet > 0
    silent = int((Xte[:20].std(-1) <= res.pipeline.encoder.gate_rms.numpy()).sum())
    assert sess.info()["stats"]["stream_channel_windows"] == 60
    assert sess.info()["stats"]["stream_channel_windows_skipped"] == silent > quiet * 3


@pytest.mark.slow
def test_exported_gate_encodes_only_the_active_rows_and_matches_torch():
    """The encoder graph gathers the active (window, channel) rows (``NonZero`` -> ``Gather``)
    and scatters their spikes back: same spikes as the torch path for mixed, wholly silent and
    wholly active batches, GWT (factored forms, band permutation) and STFT alike."""
    import onnxruntime as ort
    import torch

    from tactilesnn.export.onnx import build_parts
    from tactilesnn.pipeline import SpikePipeline

    X, _ = _touches(16, 3)
    for name, extra in (("gwt", {"gwt_hop": 5}), ("stft", {})):
        cfg = PipelineConfig.from_flat(
            model="readout", encoder=name, channels=("all",), gate=3.0, **extra
        )
        pipe = SpikePipeline(cfg, FS, W, ("t0", "t1", "t2"), ("slow", "fast"))
        pipe.calibrate(X)
        enc, _ = build_parts(pipe)
        assert {"NonZero", "Gather"} <= {n.op_type for n in enc.graph.node}
        sess = ort.InferenceSession(enc.SerializeToString(), providers=["CPUExecutionProvider"])
        active = X.std(-1) > pipe.encoder.gate_rms.numpy()
        assert 0 < active.mean() < 0.5
        silent = np.full_like(X[:3], 1e-6)
        sig = X[active][0]
        loud = np.stack([np.stack([sig, 2 * sig, -sig])] * 2)  # every row active
        for batch in (X, silent, loud):
            want = pipe.encoder.encode(torch.from_numpy(batch)).numpy()
            got = sess.run(None, {"window": batch})[0][:, : want.shape[1]]  # then the clock
            assert got.shape == want.shape
            np.testing.assert_array_equal(np.isinf(got), np.isinf(want))
            fin = np.isfinite(want)
            np.testing.assert_allclose(got[fin], want[fin], atol=0.05)
        n_aff = pipe.encoder.n_afferents
        assert np.isinf(sess.run(None, {"window": silent})[0][:, :n_aff]).all()


@pytest.mark.slow
def test_exported_gate_with_every_gwt_form_passes_zero_one_and_all_rows(tmp_path):
    """2 kHz windows whose GWT uses all three exported forms (shared-basis low rank, polyphase
    Conv, dense): the gated graph gives torch's scores with no active row, one, and all."""
    from tactilesnn.pipeline import SpikePipeline
    from tactilesnn.service.runtime import PipelineSession

    cfg = PipelineConfig.from_flat(model="readout", channels=("all",), f_lo_hz=5.0,
                                   f_hi_hz=800.0, gwt_hop=10, gate=0.5)  # fmt: skip
    pipe = SpikePipeline(cfg, 2000.0, 1000, ("t0", "t1", "t2"), ("a", "b"))
    X = np.random.default_rng(0).standard_normal((8, 3, 1000)).astype(np.float32)
    pipe.calibrate(X)
    graph = pipe.encoder.onnx_module().inner.inner  # gate -> spike slot -> scalogram graph
    assert set(graph.kinds) == {"low_rank", "conv", "dense"} and graph.basis_rank > 0
    export_pipeline(pipe, tmp_path / "m.onnx", X)
    sess = PipelineSession(str(tmp_path / "m.onnx"), threads=1)
    one = X[:3].copy()
    one[:, 1:] = 1e-6
    for batch in (np.full_like(X[:3], 1e-6), one, X[:3]):
        want = pipe.scores(pipe.encode(batch)).numpy()
        np.testing.assert_allclose(sess.run(batch), want, atol=1e-4)


@pytest.mark.slow
def test_a_stateful_snn_stream_counts_gated_channels_but_never_skips_windows(tmp_path):
    """An SNN carries its state from window to window, so no window is answered from the
    silent cache; the graph still encodes only the active taxels, and the stream's scores are
    those of running the windows one by one with the state carried."""
    from tactilesnn.pipeline import SpikePipeline

    X, _ = _touches(12, 4)
    cfg = PipelineConfig.from_flat(model="snn", channels=("all",), gate=3.0)
    pipe = SpikePipeline(cfg, FS, W, ("t0", "t1", "t2"), ("slow", "fast"))
    pipe.calibrate(X)
    path = tmp_path / "snn.onnx"
    export_pipeline(pipe, path, X)
    sess = PipelineSession(str(path))
    assert sess.stateful
    got = sess.feed_stream(StreamState(), np.concatenate(list(X), axis=1), hop=W)
    state, want = StreamState(), []
    for x in X:
        want.append(sess.run(x[None], state)[0])
    np.testing.assert_allclose([r["scores"] for r in got], want, atol=1e-6)
    stats = sess.info()["stats"]
    silent = int((X.std(-1) <= pipe.encoder.gate_rms.numpy()).sum())
    assert stats["stream_windows"] == 12 and stats["stream_windows_skipped"] == 0
    assert stats["stream_channel_windows"] == 36
    assert stats["stream_channel_windows_skipped"] == silent > 0
