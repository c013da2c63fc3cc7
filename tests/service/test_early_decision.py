"""Early decision on the service path: the exported tempotron names the first class to fire and
when, as the torch model does; the stream reports it per window and counts it in its stats."""

from __future__ import annotations

import tempfile

import numpy as np
import pytest
import torch

from tactilesnn.config import PipelineConfig
from tactilesnn.datasets_synth import HookLoopTask
from tactilesnn.export import export_pipeline
from tactilesnn.service.runtime import InputError, PipelineSession, StreamState
from tactilesnn.training import fit_and_evaluate

SMALL = {"seed": 0, "n_planar": 10, "n_concave": 5, "n_convex": 5, "n_test": 4}


@pytest.fixture(scope="session")
def tasks():
    return HookLoopTask(**SMALL).build()


def _export(tasks, model: str, path):
    train, test = tasks
    res = fit_and_evaluate(PipelineConfig.from_flat(epochs=2, model=model), train, test)
    report = export_pipeline(res.pipeline, path, test.X[:48])
    return res.pipeline, test, report


@pytest.mark.slow
def test_the_exported_tempotron_decides_early_as_torch_does(tasks, tmp_path):
    pipe, test, report = _export(tasks, "tempotron", tmp_path / "t.onnx")
    assert report["early_class_agreement"] == 1.0 and report["early_max_time_diff_ms"] < 1e-3
    sess = PipelineSession(str(tmp_path / "t.onnx"))
    assert sess.decides_early
    x = test.X[:48]
    out = sess.run_detail(x)
    cls, t = pipe.model.early_decision(pipe.encode(x))
    np.testing.assert_array_equal(out.early_class, cls.numpy())
    np.testing.assert_allclose(out.decision_ms, t.numpy(), atol=1e-3)
    # decided before the window's end where a class fired; the duration where none did
    fired = (out.scores >= pipe.model.net.theta + pipe.model.net.v_rest).any(1)
    assert (out.decision_ms[fired] < pipe.duration_ms).all()
    np.testing.assert_array_equal(out.decision_ms[~fired], pipe.duration_ms)

    # the stream: every window carries its early class and time; the stats count them
    stream = np.concatenate(list(x[:10]), axis=1)
    got = sess.feed_stream(StreamState(), stream, hop=pipe.window)
    assert [r["early_class"] for r in got] == [pipe.class_names[i] for i in cls[:10]]
    np.testing.assert_allclose([r["decision_ms"] for r in got], t[:10].numpy(), atol=1e-3)
    stats = sess.info()["stats"]
    full = out.scores[:10].argmax(1)
    assert stats["stream_early_decisions"] == 10
    assert stats["stream_early_differs"] == int((cls[:10].numpy() != full).sum())
    assert stats["stream_early_mean_decision_ms"] == pytest.approx(float(t[:10].mean()), abs=1e-3)

    # plain classification runs the graph pruned to the scores (onnxruntime would run the
    # decision nodes for any output asked) and gets the same scores
    plain = sess.plain_session
    assert plain is not sess.session
    assert [o.name for o in plain.get_outputs()] == ["scores"]
    asked = []
    real_run = plain.run

    def spy(names, feeds):
        asked.append(list(names))
        return real_run(names, feeds)

    sess.plain_session.run = spy
    np.testing.assert_array_equal(sess.run(x), out.scores)
    assert asked == [["scores"]]

    # a session that only classifies holds the pruned graph alone (one copy of the weights);
    # the whole graph is loaded by the first call that asks for the early decision
    fresh = PipelineSession(str(tmp_path / "t.onnx"))
    assert fresh.decides_early
    np.testing.assert_array_equal(fresh.run(x), out.scores)
    assert fresh._full is None
    again = fresh.run_detail(x)
    assert fresh._full is not None
    np.testing.assert_array_equal(again.early_class, out.early_class)


@pytest.mark.slow
def test_a_model_without_early_decision_reports_none(tasks, tmp_path):
    _, test, report = _export(tasks, "readout", tmp_path / "r.onnx")
    assert "early_class_agreement" not in report
    sess = PipelineSession(str(tmp_path / "r.onnx"))
    assert not sess.decides_early and "stream_early_decisions" not in sess.info()["stats"]
    assert sess.plain_session is sess.session  # nothing to prune
    out = sess.run_detail(test.X[:4])
    assert out.early_class is None and out.decision_ms is None
    got = sess.feed_stream(StreamState(), np.concatenate(list(test.X[:2]), axis=1))
    assert got and all("early_class" not in r for r in got)


@pytest.mark.slow
def test_the_exported_snn_decides_early_as_torch_does_and_streams_it(tasks, tmp_path):
    """The SNN decides when its leading class leads by the margin fitted on the training
    windows; the graph's decisions equal torch's, and a stateful stream reports them."""
    pipe, test, report = _export(tasks, "snn", tmp_path / "s.onnx")
    model = pipe.model
    assert 0 < float(model.early_margin) < model.NEVER  # fitted by training
    assert report["early_windows_differing"] == 0 and report["early_max_time_diff_ms"] == 0.0
    sess = PipelineSession(str(tmp_path / "s.onnx"))
    assert sess.decides_early and sess.stateful
    x = test.X[:48]
    out = sess.run_detail(x)
    cls, t = model.early_decision(pipe.encode(x))
    np.testing.assert_array_equal(out.early_class, cls.numpy())
    np.testing.assert_array_equal(out.decision_ms, t.numpy())
    # the end of a time step, or the window's end
    tn = t.numpy()
    assert np.all((tn % model.config.dt_ms == 0) | (tn == pipe.duration_ms))
    assert float(t.mean()) < pipe.duration_ms  # some windows are decided before their end

    stream = np.concatenate(list(x[:6]), axis=1)
    got = sess.feed_stream(StreamState(), stream, hop=pipe.window)
    assert len(got) == 6 and all(r["early_class"] in pipe.class_names for r in got)
    assert all(0 < r["decision_ms"] <= pipe.duration_ms for r in got)
    assert sess.info()["stats"]["stream_early_decisions"] == 6
    # plain classification: the pruned graph, same scores and carried state as the full one
    import onnx

    from tactilesnn.service.runtime import pruned_graph

    full_graph = onnx.load(str(tmp_path / "s.onnx")).graph
    pruned = onnx.load_from_string(pruned_graph(str(tmp_path / "s.onnx"), sess.plain_outputs))
    assert len(pruned.graph.node) < len(full_graph.node)
    assert not {"early_class", "decision_ms"} & {o for n in pruned.graph.node for o in n.output}
    st_plain, st_full = StreamState(), StreamState()
    for _ in range(2):  # the second call starts from the carried state
        np.testing.assert_array_equal(sess.run(x, st_plain), sess.run_detail(x, st_full).scores)
    assert st_full.values and st_plain.values.keys() == st_full.values.keys()
    for k, v in st_full.values.items():
        np.testing.assert_array_equal(st_plain.values[k], v)
    # an empty batch is refused before onnxruntime, whose LSTM would abort the process
    with pytest.raises(InputError, match="empty batch"):
        sess.run(x[:0])


@pytest.mark.slow
def test_grid_crossings_agree_with_a_fine_bisection():
    """The grid rounds (the exported form) against 60 bisection steps in float64."""
    from tactilesnn.models.tempotron import Tempotron

    g = torch.Generator().manual_seed(5)
    m = Tempotron(12, 3, 200.0, tau_ms=20.0, tau_s_ms=5.0).double()
    with torch.no_grad():
        m.weight.copy_(torch.randn(3, 12, generator=g, dtype=torch.float64))
    times = torch.rand(32, 12, 1, generator=g, dtype=torch.float64) * 200
    got = m.decision_times(times, levels=3)
    # first grid point at or above threshold, on a 1 us grid, in 10 chunks (bounded memory)
    grid = torch.linspace(0, 200, 200_001, dtype=torch.float64)
    idx = torch.full(got.shape, -1, dtype=torch.long)
    with torch.no_grad():
        for part in torch.arange(grid.numel()).chunk(10):
            above = m.potential(times, grid[part]) >= m.theta + m.v_rest
            first = part[0] + above.to(torch.int32).argmax(2)
            idx = torch.where((idx < 0) & above.any(2), first, idx)
    fin = idx >= 0
    assert torch.equal(fin, torch.isfinite(got)) and fin.any()
    # bisect between the dense grid's bracketing points
    idx = idx.clamp_min(0)
    lo, hi = grid[(idx - 1).clamp_min(0)], grid[idx]
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        v = torch.stack([
            torch.diagonal(m.potential(times, mid[:, c])[:, c], 0) for c in range(3)
        ], 1)  # fmt: skip
        up = v >= m.theta + m.v_rest
        hi, lo = torch.where(up, mid, hi), torch.where(up, lo, mid)
    np.testing.assert_allclose(got[fin].numpy(), hi[fin].numpy(), atol=200 * 64.0**-3)


@pytest.mark.slow
def test_without_the_onnx_package_plain_classification_runs_the_full_graph(
    tasks, tmp_path, monkeypatch
):
    import sys

    _, test, _ = _export(tasks, "tempotron", tmp_path / "t.onnx")
    monkeypatch.setitem(sys.modules, "onnx", None)  # import onnx raises ImportError
    sess = PipelineSession(str(tmp_path / "t.onnx"))
    assert sess.decides_early and sess.plain_session is sess.session
    np.testing.assert_array_equal(sess.run(test.X[:8]), sess.run_detail(test.X[:8]).scores)


def test_pruning_keeps_the_outer_values_a_loop_body_reads():
    """A ``Loop`` whose body reads an outer-graph value keeps that value's producer; the node
    that feeds only the dropped output goes; the pruned graph runs and gives the same answer."""
    import onnx
    import onnxruntime as ort
    from onnx import TensorProto, helper

    from tactilesnn.service.runtime import pruned_graph

    f = TensorProto.FLOAT
    body = helper.make_graph(
        [helper.make_node("Identity", ["cond_in"], ["cond_out"]),
         helper.make_node("Add", ["acc_in", "step"], ["acc_out"])],  # "step": the outer value
        "body",
        [helper.make_tensor_value_info("i", TensorProto.INT64, []),
         helper.make_tensor_value_info("cond_in", TensorProto.BOOL, []),
         helper.make_tensor_value_info("acc_in", f, [2])],
        [helper.make_tensor_value_info("cond_out", TensorProto.BOOL, []),
         helper.make_tensor_value_info("acc_out", f, [2])],
    )  # fmt: skip
    trips = helper.make_tensor("trips", TensorProto.INT64, [], [3])
    yes = helper.make_tensor("yes", TensorProto.BOOL, [], [True])
    graph = helper.make_graph(
        [helper.make_node("Mul", ["x", "x"], ["step"]),
         helper.make_node("Loop", ["trips", "yes", "x"], ["scores"], body=body),
         helper.make_node("Neg", ["x"], ["early_class"])],
        "g", [helper.make_tensor_value_info("x", f, [2])],
        [helper.make_tensor_value_info("scores", f, [2]),
         helper.make_tensor_value_info("early_class", f, [2])],
        [trips, yes],
    )  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    with tempfile.TemporaryDirectory() as d:
        path = f"{d}/m.onnx"
        onnx.save(model, path)
        pruned = onnx.load_from_string(pruned_graph(path, ["scores"]))
    assert [n.op_type for n in pruned.graph.node] == ["Mul", "Loop"]
    assert [o.name for o in pruned.graph.output] == ["scores"]
    x = np.array([1.0, 2.0], np.float32)
    got = ort.InferenceSession(pruned.SerializeToString()).run(None, {"x": x})[0]
    np.testing.assert_array_equal(got, x + 3 * x * x)
