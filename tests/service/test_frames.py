"""The service serves a one-frame step graph: its stream path a result every frame (state
carried, any chunking), its classify path a window's frames from rest; a tampered start rule
is refused at load."""

import json

import numpy as np
import onnx
import pytest
import torch

from tactilesnn.config import PipelineConfig
from tactilesnn.export.frames import FrameGraph, export_frames, frame_session, run_frames
from tactilesnn.pipeline import SpikePipeline
from tactilesnn.service.runtime import PipelineSession, StreamState

FS, W = 1000.0, 200


@pytest.fixture(scope="session")
def frame_graph(tmp_path_factory):
    rng = np.random.default_rng(0)
    t = np.arange(W) / FS
    y = np.arange(16) % 2
    X = np.sin(2 * np.pi * np.where(y == 0, 40.0, 120.0)[:, None, None] * t)
    X = X * rng.uniform(0.5, 2.0, (16, 2, 1)) + 3.0 + 0.1 * rng.standard_normal((16, 2, W))
    X = X.astype(np.float32)  # (an offset of 3: a fresh stream's start rule matters)
    cfg = PipelineConfig.from_flat(encoder="frames", model="stream", channels=("all",), epochs=2,
                                   stream_epochs=0, f_lo_hz=10.0, f_hi_hz=300.0,
                                   stream_hidden=16, frame_ms=10.0)  # fmt: skip
    pipe = SpikePipeline(cfg, FS, W, ("a", "b"), ("lo", "hi"))
    torch.manual_seed(0)
    pipe.fit(X, y)
    pipe.model.decision_margin.fill_(0.0)  # decide every frame
    path = tmp_path_factory.mktemp("frames") / "frames.onnx"
    export_frames(pipe, path, X)
    return pipe, X, path


def test_the_stream_path_gives_a_result_every_frame(frame_graph):
    pipe, X, path = frame_graph
    sess = PipelineSession(str(path))
    assert sess.window_step == 10 and sess.frames is not None
    stream = np.concatenate(list(X[:3]), 1)
    state, got = StreamState(), []
    for a, b in ((0, 7), (7, 333), (333, stream.shape[1])):  # chunks that cut frames
        got += sess.feed_stream(state, stream[:, a:b])
    model = onnx.load(str(path))
    want = run_frames(frame_session(model), FrameGraph(pipe), stream)
    assert len(got) == stream.shape[1] // 10
    np.testing.assert_allclose([r["scores"] for r in got], want["scores"], atol=1e-5)
    names = [pipe.class_names[d] if d >= 0 else None for d in want["decision"]]
    assert [r["decision"] for r in got] == names


def test_classify_runs_a_windows_frames_from_rest(frame_graph):
    pipe, X, path = frame_graph
    sess = PipelineSession(str(path))
    got = sess.run(sess.validate(X[:4]))
    want = pipe.scores(pipe.encode(X[:4])).numpy()
    np.testing.assert_allclose(got, want, atol=1e-3, rtol=1e-3)


def test_a_tampered_start_rule_is_refused(frame_graph, tmp_path):
    _, _, path = frame_graph
    model = onnx.load(str(path))
    for p in model.metadata_props:
        if p.key == "frame_state_init":
            p.value = json.dumps({"repeat_first": [0, 10**9, 5]})
    bad = tmp_path / "bad.onnx"
    onnx.save(model, str(bad))
    with pytest.raises(ValueError, match="start rule"):
        PipelineSession(str(bad))
