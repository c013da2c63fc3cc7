"""Sessions of graphs with a reducing scatter run on one thread: onnxruntime's multi-threaded
ScatterND with reduction='add' loses updates that share an output element."""

import numpy as np
import onnxruntime as ort
from onnx import TensorProto, helper

from tactilesnn.core.onnx_run import reducing_scatter, session_threads


def _scatter_model(reduction: str, in_loop: bool = False):
    t, b, h, n = 142, 3, 64, 20000
    vi = helper.make_tensor_value_info
    node = helper.make_node("ScatterND", ["data", "idx", "upd"], ["out"], reduction=reduction)
    ios = ([vi("data", TensorProto.FLOAT, [t, b, h]), vi("idx", TensorProto.INT64, [n, 2]),
            vi("upd", TensorProto.FLOAT, [n, h])], [vi("out", TensorProto.FLOAT, [t, b, h])])  # fmt: skip
    if in_loop:  # the same node inside a subgraph (an If's branch)
        branch = helper.make_graph([node], "branch", [], ios[1])
        cond = helper.make_tensor_value_info("c", TensorProto.BOOL, [])
        node = helper.make_node("If", ["c"], ["out"], then_branch=branch, else_branch=branch)
        ios = ([*ios[0], cond], ios[1])
    model = helper.make_model(helper.make_graph([node], "g", *ios),
                              opset_imports=[helper.make_opsetid("", 18)])  # fmt: skip
    model.ir_version = 8
    return model, (t, b, h, n)


def test_a_reducing_scatter_runs_on_one_thread_and_adds_every_update():
    model, (t, b, h, n) = _scatter_model("add")
    assert reducing_scatter(model) and session_threads(model, 0) == 1
    assert session_threads(model, 8) == 1
    assert reducing_scatter(_scatter_model("add", in_loop=True)[0])
    plain, _ = _scatter_model("none")
    assert not reducing_scatter(plain) and session_threads(plain, 0) == 0
    assert session_threads(None, 0) == 1  # the graph unreadable: the safe side
    rng = np.random.default_rng(0)
    idx = np.stack([rng.integers(0, t, n), rng.integers(0, b, n)], 1).astype(np.int64)
    upd = rng.standard_normal((n, h)).astype(np.float32)
    want = np.zeros((t, b, h))
    np.add.at(want, (idx[:, 0], idx[:, 1]), upd.astype(np.float64))
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = session_threads(model, 0)
    sess = ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])
    feeds = {"data": np.zeros((t, b, h), np.float32), "idx": idx, "upd": upd}
    # on 2+ threads onnxruntime 1.32 was off by ~4 here, differently every run
    for _ in range(3):
        assert np.abs(sess.run(None, feeds)[0] - want).max() < 1e-4


def test_a_reducing_scatter_elements_keeps_its_threads_and_adds_every_update():
    """ScatterElements with reduction='add' (the LIF code's slot histogram) is exact on several
    threads (its CPU kernel is sequential), so its graph is not held to one: a histogram of
    sorted bins, as the slots' are, checked element by element on 4 threads."""
    w, n, a, k = 600, 16, 32, 9
    vi = helper.make_tensor_value_info
    node = helper.make_node("ScatterElements", ["data", "idx", "upd"], ["out"], axis=0,
                            reduction="add")  # fmt: skip
    graph = helper.make_graph(
        [node], "g",
        [vi("data", TensorProto.INT64, [k, n, a]), vi("idx", TensorProto.INT64, [w, n, a]),
         vi("upd", TensorProto.INT64, [w, n, a])], [vi("out", TensorProto.INT64, [k, n, a])],
    )  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 8
    assert not reducing_scatter(model) and session_threads(model, 0) == 0
    rng = np.random.default_rng(1)
    idx = np.sort(rng.integers(0, k, (w, n, a)), axis=0).astype(np.int64)
    want = np.zeros((k, n, a), np.int64)
    np.add.at(want, (idx, np.arange(n)[None, :, None], np.arange(a)[None, None, :]), 1)
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 4
    sess = ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])
    feeds = {"data": np.zeros((k, n, a), np.int64), "idx": idx, "upd": np.ones_like(idx)}
    for _ in range(5):
        assert np.array_equal(sess.run(None, feeds)[0], want)
