"""bench pareto's floor row: a graph's heavy operators alone, with the values they see in it."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

from tactilesnn.bench.pareto import heavy_operators


def _graph(big: np.ndarray, small: np.ndarray) -> onnx.ModelProto:
    nodes = [
        helper.make_node("Relu", ["x"], ["r"]),
        helper.make_node("MatMul", ["r", "big"], ["h"]),  # 8 x 200 x 100 = 160,000 multiply-adds
        helper.make_node("Tanh", ["h"], ["t"]),
        helper.make_node("MatMul", ["t", "small"], ["y"]),  # 8 x 100 x 3 = 2,400
    ]
    g = helper.make_graph(
        nodes, "g", [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["b", 200])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["b", 3])],
        [numpy_helper.from_array(big, "big"), numpy_helper.from_array(small, "small")],
    )  # fmt: skip
    return helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])


def test_heavy_operators_keeps_the_big_products_with_the_values_they_see():
    rng = np.random.default_rng(0)
    big = rng.standard_normal((200, 100)).astype(np.float32)
    small = rng.standard_normal((100, 3)).astype(np.float32)
    x = rng.standard_normal((8, 200)).astype(np.float32)
    heavy, feeds = heavy_operators(_graph(big, small), {"x": x})
    assert [n.op_type for n in heavy.graph.node] == ["MatMul"]
    assert heavy.graph.node[0].input[1] == "big"  # the weight stays an initializer
    # its input is the value the whole graph computes there (after the Relu), not the feed
    np.testing.assert_array_equal(feeds["r"], np.maximum(x, 0))
    onnx.checker.check_model(heavy)
    sess = ort.InferenceSession(heavy.SerializeToString(), providers=["CPUExecutionProvider"])
    (h,) = sess.run(None, feeds)
    np.testing.assert_allclose(h, np.maximum(x, 0) @ big, rtol=1e-5, atol=1e-4)
    # a lower bar takes the small product too, each node with its own inputs
    both, fed = heavy_operators(_graph(big, small), {"x": x}, min_macs=1000)
    assert [n.op_type for n in both.graph.node] == ["MatMul", "MatMul"]
    np.testing.assert_allclose(fed["t"], np.tanh(np.maximum(x, 0) @ big), rtol=1e-5, atol=1e-5)
