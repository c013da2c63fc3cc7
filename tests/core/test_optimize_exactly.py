"""The graph optimiser keeps constants it once took for 0 or 1 (onnxscript's no-op rules match
within an absolute tolerance of 1e-8)."""

import numpy as np
import onnxruntime as ort
import pytest
import torch
from torch import nn

from tactilesnn.core.onnx_graph import exported_to_onnx


class _Floors(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        share = x / (x.abs().sum(1, keepdim=True) + 1e-30)  # finite at x = 0
        return torch.cat([share, x * (1.0 + 2.0**-23) - x, x + 0.0, x * 1.0], 1)


@pytest.mark.slow
@pytest.mark.parametrize("x", [np.zeros((2, 3), np.float32),
                               np.full((2, 3), 1e3, np.float32)])  # fmt: skip
def test_tiny_scalar_constants_survive_the_optimiser(x):
    model = exported_to_onnx(_Floors(), (torch.ones(2, 3),), ["x"], ["y"])
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    got = sess.run(["y"], {"x": x})[0]
    want = _Floors()(torch.from_numpy(x)).numpy()
    assert np.isfinite(got).all()
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=0)
    # the exact no-ops still go: no Add of 0 or Mul by 1 is left
    ops = [n.op_type for n in model.graph.node]
    assert ops.count("Add") == 1 and ops.count("Mul") == 1, ops
