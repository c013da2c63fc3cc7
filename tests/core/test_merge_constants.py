"""Identical large constants of a traced graph are kept once, the graph's outputs unchanged."""

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

from tactilesnn.core.onnx_graph import merge_constants


def _graph(w: np.ndarray, w2: np.ndarray) -> onnx.ModelProto:
    nodes = [
        helper.make_node("Constant", [], ["a"], value=numpy_helper.from_array(w)),
        helper.make_node("Constant", [], ["b"], value=numpy_helper.from_array(w.copy())),
        helper.make_node("Constant", [], ["c"], value=numpy_helper.from_array(w2)),
        helper.make_node("MatMul", ["x", "a"], ["y1"]),
        helper.make_node("MatMul", ["y1", "b"], ["y2"]),
        helper.make_node("MatMul", ["y2", "c"], ["y"]),
    ]
    g = helper.make_graph(nodes, "g", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [2, 32])],
                          [helper.make_tensor_value_info("y", TensorProto.FLOAT, [2, 32])])  # fmt: skip
    return helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])


def _run(m: onnx.ModelProto, x: np.ndarray) -> np.ndarray:
    return ort.InferenceSession(m.SerializeToString(), providers=["CPUExecutionProvider"]).run(
        None, {"x": x}
    )[0]


def test_identical_constants_are_merged_and_different_ones_kept():
    rng = np.random.default_rng(0)
    w, w2 = rng.standard_normal((2, 32, 32)).astype(np.float32)
    x = rng.standard_normal((2, 32)).astype(np.float32)
    m = _graph(w, w2)
    want = _run(m, x)
    assert merge_constants(m) == 1
    assert sum(n.op_type == "Constant" for n in m.graph.node) == 2
    onnx.checker.check_model(m)
    assert np.array_equal(_run(m, x), want)
    assert merge_constants(m) == 0  # nothing left to merge
