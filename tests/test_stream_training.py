"""A stream model scored as it runs (stream_training.py): the settle latency on hand-made decisions,
and the figures of a trained pipeline over recordings tiled by windows."""

import numpy as np
import pytest
import torch

from tactilesnn.config import PipelineConfig
from tactilesnn.pipeline import SpikePipeline
from tactilesnn.stream_training import settle_latency_ms, stream_evaluation


def test_the_settle_latency():
    assert settle_latency_ms(np.array([-1, 1, 0, -1, 0, 0]), 0, 5.0) == 15.0  # frame 2
    assert settle_latency_ms(np.array([0, 1, -1, 0, -1]), 0, 5.0) == 20.0  # after the 1
    assert settle_latency_ms(np.array([-1, -1]), 0, 5.0) is None
    assert settle_latency_ms(np.array([0, 0, 1]), 0, 5.0) is None  # it does not stay


def _recordings(n_rec=8, windows=6, w=200, hop=100, fs=1000.0, seed=0):
    """Recordings of a 40 Hz or a 120 Hz vibration that starts a quarter in, cut into
    half-overlapping windows (scan = recording)."""
    rng = np.random.default_rng(seed)
    n = w + (windows - 1) * hop
    t = np.arange(n) / fs
    X, y, scan = [], [], []
    for r in range(n_rec):
        c = r % 2
        x = np.sin(2 * np.pi * (40.0 if c == 0 else 120.0) * t)[None] * (t >= n / 4 / fs)
        x = (x * rng.uniform(0.5, 2.0, (2, 1)) + 0.05 * rng.standard_normal((2, n))).astype(
            np.float32
        )
        for k in range(windows):
            X.append(x[:, k * hop : k * hop + w])
            y.append(c)
            scan.append(r)
    return np.asarray(X), np.asarray(y), np.asarray(scan)


@pytest.mark.slow
def test_a_trained_stream_model_is_scored_frame_by_frame():
    X, y, scan = _recordings()
    cfg = PipelineConfig.from_flat(encoder="frames", model="stream", channels=("all",), epochs=30,
                                   f_lo_hz=10.0, f_hi_hz=300.0, stream_hidden=16)  # fmt: skip
    pipe = SpikePipeline(cfg, 1000.0, 200, ("a", "b"), ("lo", "hi"))
    torch.manual_seed(0)
    pipe.fit(X, y)
    pipe.model.calibrate_decision(pipe.encode(X))
    alone = pipe.scores(pipe.encode(X)).numpy()
    st = stream_evaluation(pipe, X, y, scan, alone)
    assert st is not None and st["windows_in_streams"] == len(X)
    assert st["per_window"] >= 0.9 and st["per_recording"] == 1.0
    assert st["segments"] == 8 and st["settled_fraction"] >= 0.75
    assert 0 < st["decision_latency_ms"]["median"] < 1000.0
    # the first window of each recording has no past: the stream's score is the window's own
    first = np.flatnonzero(np.r_[True, np.diff(scan) != 0])
    pred_first = alone[first].argmax(1)
    assert (pred_first == y[first]).mean() >= 0.5


def test_window_pipelines_are_not_scored_as_frames():
    X, y, scan = _recordings(n_rec=2, windows=3)
    cfg = PipelineConfig.from_flat(encoder="frames", model="readout", channels=("all",))
    pipe = SpikePipeline(cfg, 1000.0, 200, ("a", "b"), ("lo", "hi"))
    assert stream_evaluation(pipe, X, y, scan, np.zeros((len(X), 2))) is None


@pytest.mark.slow
def test_training_on_streams_is_bounded_by_a_byte_budget(monkeypatch):
    import tactilesnn.stream_training as streaming

    X, y, scan = _recordings(n_rec=6, windows=4)
    cfg = PipelineConfig.from_flat(encoder="frames", model="stream", channels=("all",), epochs=1,
                                   stream_epochs=2, f_lo_hz=10.0, f_hi_hz=300.0, stream_hidden=8)  # fmt: skip
    pipe = SpikePipeline(cfg, 1000.0, 200, ("a", "b"), ("lo", "hi"))
    pipe.calibrate(X)
    frames = (3 * 100 + 200) // pipe.encoder.hop  # one recording's frames
    monkeypatch.setattr(streaming, "STREAM_BYTES", 2 * frames * pipe.encoder.n_afferents)
    done = streaming.fit_streams(pipe, X, y, scan)
    assert done["of_recordings"] == 6 and done["recordings"] == 2  # every third, up to budget
    assert done["epochs"] == 2 and all(np.isfinite(done["loss_history"]))
