"""The static-size folding of exported graphs: fewer run-time nodes, identical results."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from onnx import TensorProto, helper
from torch import nn

from tactilesnn.core.onnx_graph import torch_to_onnx
from tactilesnn.core.onnx_shapes import fold_static_shapes


class _Traced(nn.Module):
    """Size arithmetic of the kind tracing emits: reshapes sized from ``x.shape``, a pad whose
    length is computed, a buffer of a computed size."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, c, n = x.shape
        flat = x.reshape(b * c, n)
        y = nn.functional.pad(flat, (0, n // 4))
        z = y.reshape(b, c, n + n // 4).sum(-1)
        return z + torch.zeros(b, c)


def _run(model: onnx.ModelProto, x: np.ndarray) -> np.ndarray:
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, {"x": x})[0]


def _count(model: onnx.ModelProto, op: str) -> int:
    return sum(n.op_type == op for n in model.graph.node)


def test_traced_sizes_fold_and_results_stay(tmp_path):
    module = _Traced()
    with torch.no_grad():
        torch.onnx.export(module, (torch.zeros(2, 3, 8),), str(tmp_path / "raw.onnx"),
                          input_names=["x"], output_names=["y"],
                          dynamic_axes={"x": {0: "batch"}, "y": {0: "batch"}}, dynamo=False)  # fmt: skip
    raw = onnx.load(str(tmp_path / "raw.onnx"))
    folded = onnx.ModelProto()
    folded.CopyFrom(raw)
    assert fold_static_shapes(folded) > 0
    live = [n for n in folded.graph.node if n.op_type != "Constant"]
    assert len(live) < len([n for n in raw.graph.node if n.op_type != "Constant"])
    # both reshapes get constant targets with -1 on the batch axis (also right for 0 rows, see
    # below); the pad's computed lengths are constants
    targets = {i.name: onnx.numpy_helper.to_array(i) for i in folded.graph.initializer}
    reshapes = [n for n in folded.graph.node if n.op_type == "Reshape"]
    assert [targets[n.input[1]].tolist() for n in reshapes if n.input[1] in targets] == [
        [-1, 8],
        [-1, 3, 10],
    ]
    assert _count(folded, "Cast") == 0 and _count(raw, "Cast") > 0
    rng = np.random.default_rng(0)
    for batch in (0, 1, 5):
        x = rng.integers(-8, 8, (batch, 3, 8)).astype(np.float32)  # sums exact in any order
        want = module(torch.from_numpy(x)).numpy()
        np.testing.assert_array_equal(_run(folded, x), want)
        np.testing.assert_array_equal(_run(raw, x), want)


def test_torch_to_onnx_folds(tmp_path):
    model = torch_to_onnx(_Traced(), (torch.zeros(1, 3, 8),), tmp_path / "m.onnx", ["x"], ["y"])
    assert _count(model, "Shape") == 1  # only the batch size (zeros and the last reshape)
    x = np.ones((4, 3, 8), np.float32)
    np.testing.assert_array_equal(_run(model, x), np.full((4, 3), 8.0, np.float32))


def _reshape_graph(target_dims: list[str | int]) -> onnx.ModelProto:
    """x [a, b, 6] -> Reshape(x, Shape(x)) as [a, b, 2, 3] via a computed target."""
    nodes = [
        helper.make_node("Shape", ["x"], ["s"], end=2),
        helper.make_node("Concat", ["s", "tail"], ["t"], axis=0),
        helper.make_node("Reshape", ["x", "t"], ["y"]),
    ]
    graph = helper.make_graph(
        nodes, "g", [helper.make_tensor_value_info("x", TensorProto.FLOAT, target_dims)],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)],
        [helper.make_tensor("tail", TensorProto.INT64, [2], [2, 3])],
    )  # fmt: skip
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])


@pytest.mark.parametrize(("dims", "folds"), [(["a", 4, 6], True), (["a", "b", 6], False)])
def test_reshape_target_only_with_one_unknown_axis(dims, folds):
    model = _reshape_graph(dims)
    fold_static_shapes(model)
    computed = any(n.op_type == "Concat" for n in model.graph.node)
    assert computed != folds
    x = np.arange(2 * 4 * 6, dtype=np.float32).reshape(2, 4, 6)
    np.testing.assert_array_equal(_run(model, x), x.reshape(2, 4, 2, 3))


def test_sizes_from_an_unknown_op_are_left_to_run_time():
    """A value whose shape inference cannot know (an op of another domain) keeps its
    computed sizes: nothing is folded from it."""
    model = _reshape_graph(["a", 4, 6])
    model.graph.node.insert(0, helper.make_node("Mystery", ["x"], ["m"], domain="nowhere"))
    for node in model.graph.node[1:]:
        node.input[:] = ["m" if i == "x" else i for i in node.input]
    model.opset_import.append(helper.make_opsetid("nowhere", 1))
    before = model.SerializeToString()
    assert fold_static_shapes(model) == 0
    assert model.SerializeToString() == before


def test_an_initializer_a_caller_may_override_is_not_folded():
    """An initializer also listed as a graph input is a default, not a constant."""
    nodes = [
        helper.make_node("Mul", ["k", "two"], ["k2"]),
        helper.make_node("Add", ["x", "k2"], ["y"]),
    ]
    graph = helper.make_graph(
        nodes, "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [2]),
         helper.make_tensor_value_info("k", TensorProto.FLOAT, [1])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)],
        [helper.make_tensor("k", TensorProto.FLOAT, [1], [1.0]),
         helper.make_tensor("two", TensorProto.FLOAT, [1], [2.0])],
    )  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    fold_static_shapes(model)
    assert any(n.op_type == "Mul" for n in model.graph.node)
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    x = np.zeros(2, np.float32)
    np.testing.assert_array_equal(
        sess.run(None, {"x": x, "k": np.array([5.0], np.float32)})[0], 10.0
    )
