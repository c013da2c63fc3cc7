"""The one-frame step graph: onnxruntime against torch frame by frame over whole recordings
(spikes, scores, decisions, state), with both exporters; refusals."""

import numpy as np
import pytest
import torch

from tactilesnn.config import PipelineConfig
from tactilesnn.export.frames import (
    BoundFrames,
    FrameGraph,
    build_frame_graph,
    compare_frames,
    export_frames,
    frame_session,
    run_frames,
    torch_frames,
)
from tactilesnn.pipeline import SpikePipeline

FS, W = 1000.0, 200


def _data(n=24, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(W) / FS
    y = np.arange(n) % 2
    f = np.where(y == 0, 40.0, 120.0)[:, None, None]
    X = np.sin(2 * np.pi * f * t) * rng.uniform(0.5, 2.0, (n, 3, 1))
    return (X + 0.1 * rng.standard_normal((n, 3, W))).astype(np.float32), y


@pytest.fixture(scope="session")
def trained():
    X, y = _data()
    cfg = PipelineConfig.from_flat(encoder="frames", model="stream", channels=("all",), epochs=3,
                                   f_lo_hz=10.0, f_hi_hz=300.0, stream_hidden=16)  # fmt: skip
    pipe = SpikePipeline(cfg, FS, W, ("a", "b", "c"), ("lo", "hi"))
    torch.manual_seed(0)
    pipe.fit(X, y)
    with torch.no_grad():  # a hidden layer that fires, whatever 3 epochs reached
        pipe.model.hidden.fc.weight.add_(0.5)
    pipe.model.calibrate_decision(pipe.encode(X))
    return pipe, X


@pytest.mark.parametrize("exporter", ["torchscript", "torch.export"])
def test_the_step_graph_matches_torch_frame_by_frame(trained, exporter, tmp_path):
    pipe, X = trained
    rep = export_frames(pipe, tmp_path / "f.onnx", X, exporter=exporter)
    assert rep["frames"] == 24 * W // rep["hop_samples"]
    assert rep["spike_flips"] == 0
    assert rep["max_score_diff"] < 1e-4 and rep["max_state_diff"] < 1e-4
    model, graph = build_frame_graph(pipe, exporter)
    stream = np.concatenate(list(X[:8]), 1)
    got = run_frames(frame_session(model), graph, stream)
    want = torch_frames(graph, stream)
    assert got["spikes"].sum() > 0 and (got["decision"] >= 0).any()  # a test that can fail
    # a decision may differ only where the lead sits on the margin (float rounding)
    top = np.sort(want["scores"], 1)
    lead = top[:, -1] - top[:, -2]
    off = got["decision"] != want["decision"]
    margin = float(pipe.model.decision_margin)
    assert np.all(np.abs(lead[off] - margin) < 1e-4), (lead[off], margin)


def test_bound_buffers_step_as_run_does(trained):
    pipe, X = trained
    model, graph = build_frame_graph(pipe)
    sess = frame_session(model)
    stream = np.concatenate(list(X[:6]), 1)
    want = run_frames(sess, graph, stream)
    hop = graph.hop
    bound = BoundFrames(sess, graph, stream[None, :, :hop])
    scores, decision, spikes = [], [], []
    for i in range(stream.shape[1] // hop):
        bound.step(stream[None, :, i * hop : (i + 1) * hop])
        scores.append(bound.scores[0].copy())
        decision.append(int(bound.decision[0]))
        spikes.append(bound.spikes[0].copy())
    assert want["spikes"].sum() > 0
    # the same session, the same arithmetic: equal to the bit, the state carried by the swap
    assert np.array_equal(np.asarray(spikes), want["spikes"])
    assert np.array_equal(np.asarray(scores), want["scores"])
    assert np.array_equal(np.asarray(decision), want["decision"])
    assert np.array_equal(bound.state, want["state"]["frame_state"])
    with pytest.raises(ValueError, match="one stream at a time"):
        BoundFrames(sess, graph, np.repeat(stream[None, :, :hop], 2, 0))


def test_the_step_stream_equals_the_window_code_from_rest(trained):
    pipe, X = trained
    graph = FrameGraph(pipe).eval()
    got = torch_frames(graph, X[0])
    want = np.isfinite(pipe.encoder.encode(X[:1])[0].numpy()).sum(-1)
    assert np.abs(got["spikes"].sum(0) - want).sum() <= 2
    # the model's scores at the window's last frame: the window's score (no silence in it)
    np.testing.assert_allclose(got["scores"][-1], pipe.scores(pipe.encode(X[:1]))[0].numpy(),
                               atol=1e-3, rtol=1e-3)  # fmt: skip


def test_compare_frames_reports_a_flip():
    a = {"spikes": np.zeros((5, 2)), "scores": np.zeros((5, 2)), "decision": np.zeros(5),
         "state": {"s": np.zeros((1, 2))}}  # fmt: skip
    b = {**a, "spikes": a["spikes"].copy()}
    b["spikes"][3, 1] = 1
    rep = compare_frames(a, b)
    assert rep["frames_before_first_flip"] == 3 and rep["spike_flips"] == 1
    assert rep["max_state_diff"] is None


def test_window_pipelines_are_refused():
    cfg = PipelineConfig.from_flat(encoder="gwt", model="stream", channels=("all",))
    pipe = SpikePipeline(cfg, FS, W, ("a",), ("x", "y"))
    assert "continuous code" in pipe.frame_problem()
    cfg = PipelineConfig.from_flat(encoder="frames", model="snn", channels=("all",))
    pipe = SpikePipeline(cfg, FS, W, ("a",), ("x", "y"))
    assert "stream model" in pipe.frame_problem()
    cfg = PipelineConfig.from_flat(encoder="frames", model="stream", channels=("all",),
                                   stream_dt_ms=2.0)  # fmt: skip
    pipe = SpikePipeline(cfg, FS, W, ("a",), ("x", "y"))
    assert "dt_ms" in pipe.frame_problem()
    with pytest.raises(ValueError, match="dt_ms"):
        FrameGraph(pipe)
