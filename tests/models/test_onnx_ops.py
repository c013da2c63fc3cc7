"""The vectorised ONNX forms of the functional core against its reference scans."""

import tempfile
import warnings
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from torch import nn

from tactilesnn.core.onnx_graph import exported_to_onnx
from tactilesnn.core.spikes import spike_raster
from tactilesnn.models.functional import (
    li_closed,
    li_decay_matrix,
    li_scan,
    lif_rec_scan,
    lif_scan,
)
from tactilesnn.models.onnx_ops import lif_as_lstm, lif_lstm_buffers, raster_current

#: the TorchScript-based exporter (autograd symbolics) and the torch.export-based one (custom ops
#: and their onnxscript translations)
EXPORTERS = ("torchscript", "torch.export")


def _export(module: nn.Module, args: tuple, names: list[str], exporter: str) -> onnx.ModelProto:
    if exporter == "torch.export":
        got = module(*args)
        outs = [f"out{i}" for i in range(len(got) if isinstance(got, tuple) else 1)]
        axes = [1 if n == "cur" else 0 for n in names]  # cur is time-major [T, B, H]
        return exported_to_onnx(module, args, names, outs, batch_axes=axes)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "m.onnx"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(module, args, str(path), input_names=names, opset_version=17,
                              dynamo=False, dynamic_axes={n: {0: "b"} for n in names[:1]})  # fmt: skip
        return onnx.load(str(path))


def _run_onnx(
    module: nn.Module, args: tuple, names: list[str], exporter: str = "torchscript"
) -> list[np.ndarray]:
    model = _export(module, args, names, exporter)
    ops = [n.op_type for n in model.graph.node]
    assert "Loop" not in ops
    # one vectorised node, whichever exporter: no step unrolled
    assert ops.count("LSTM") + ops.count("ScatterND") == 1
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, {n: a.numpy() for n, a in zip(names, args, strict=True)})


@pytest.mark.slow
def test_leaky_integrator_closed_form_matches_the_scan_in_float64():
    g = torch.Generator().manual_seed(0)
    cur = torch.randn(300, 3, 5, dtype=torch.float64, generator=g)
    v0 = torch.randn(3, 5, dtype=torch.float64, generator=g)
    beta = 0.93
    ref, last = li_scan(cur, v0, beta)
    got = li_closed(cur, v0, beta, li_decay_matrix(300, beta, torch.float64))
    assert torch.allclose(got, ref, rtol=0, atol=1e-12)
    assert torch.allclose(got[-1], last, atol=1e-12)
    # no overflow or NaN for long windows and strong decay
    assert torch.isfinite(li_decay_matrix(5000, 1e-3)).all()


class _LIF(nn.Module):
    def __init__(self, hidden, beta, theta, subtract, w_rec=None):
        super().__init__()
        for k, v in lif_lstm_buffers(hidden, beta, theta, subtract, w_rec).items():
            self.register_buffer(k, v)
        self.register_buffer("w_rec", w_rec if w_rec is not None else torch.zeros(0, 0))
        self.cfg = (beta, theta, subtract)

    def forward(self, cur, u0, s0):
        return lif_as_lstm(cur, u0, s0, self.w_rec, self.W, self.R, self.B, *self.cfg)


@pytest.mark.slow
@pytest.mark.parametrize("exporter", EXPORTERS)
@pytest.mark.parametrize("subtract", [True, False])
@pytest.mark.parametrize("recurrent", [False, True])
def test_lif_as_one_lstm_node_spikes_exactly_like_the_scan(subtract, recurrent, exporter):
    g = torch.Generator().manual_seed(1)
    steps, batch, hidden = 200, 4, 24
    beta = 0.9048  # exp(-5 ms / 50 ms), rounded
    cur = (0.35 * torch.randn(steps, batch, hidden, generator=g) + 0.12).float()
    cur[0, 0, :] = 1.0  # from a zero membrane: exactly at the threshold (v >= theta spikes)
    u0 = (0.5 * torch.rand(batch, hidden, generator=g)).float()
    u0[0] = 0.0
    w_rec = (0.2 * torch.randn(hidden, hidden, generator=g)).float() if recurrent else None
    s0 = (
        (torch.rand(batch, hidden, generator=g) < 0.3).float()
        if recurrent
        else torch.zeros_like(u0)
    )
    s0[0] = 0.0
    if recurrent and not subtract:
        u0 = u0 * (1 - s0)  # a membrane reset to zero after a spike
    if recurrent:
        ref_s, ref_u, _ = lif_rec_scan(cur, u0, s0, w_rec, beta, 1.0, subtract)
    else:
        ref_s, ref_u = lif_scan(cur, u0, beta, 1.0, subtract)
    mod = _LIF(hidden, beta, 1.0, subtract, w_rec)
    spikes, u_t, s_t = _run_onnx(mod, (cur, u0, s0), ["cur", "u0", "s0"], exporter)
    assert ref_s.sum() > 500  # an active layer, not a trivially silent one
    assert ref_s[0, 0].sum() == hidden
    assert np.array_equal(spikes, ref_s.numpy())  # every spike at its step
    assert np.abs(u_t - ref_u.numpy()).max() < 1e-4
    assert np.array_equal(s_t, ref_s[-1].numpy())


class _Raster(nn.Module):
    def __init__(self, fc, k, dt, steps):
        super().__init__()
        self.fc, self.dt, self.steps = fc, dt, steps
        self.register_buffer("updates", fc.weight.detach().t().repeat_interleave(k, 0))

    def forward(self, spikes):
        w, b = self.fc.weight, self.fc.bias
        return raster_current(spikes, w, b, self.updates, self.dt, self.steps)


@pytest.mark.slow
@pytest.mark.parametrize(("subtract", "scale"), [(True, 0.35), (False, 0.35), (True, 30.0)])
def test_lif_as_lstm_holds_at_scale(subtract, scale):
    # 2,000 windows of 141 steps x 64 units (a FabricSlide-sized check set): with sigmoid gates
    # (onnxruntime's approximate sigmoid of logit beta) 1-9 spikes flipped here; the hard gates
    # carry beta exactly
    g = torch.Generator().manual_seed(0)
    steps, batch, hidden = 141, 2000, 64
    beta = float(np.exp(-28 / 200))
    cur = (scale * torch.randn(steps, batch, hidden, generator=g) + 0.12).float()
    u0 = torch.zeros(batch, hidden)
    ref_s, _ = lif_scan(cur, u0, beta, 1.0, subtract)
    spikes, _, _ = _run_onnx(_LIF(hidden, beta, 1.0, subtract), (cur, u0, torch.zeros_like(u0)),
                             ["cur", "u0", "s0"])  # fmt: skip
    assert ref_s.sum() > 1e6
    assert int((spikes != ref_s.numpy()).sum()) == 0


@pytest.mark.slow
@pytest.mark.parametrize("exporter", EXPORTERS)
def test_raster_current_scatter_equals_the_dense_raster_product(exporter):
    torch.manual_seed(2)
    steps, dt, k = 40, 5.0, 3
    fc = nn.Linear(30, 7)
    spikes = torch.rand(5, 30, k) * 200.0
    spikes[0, :, 0] = 0.0  # all in step 0: duplicates accumulate
    spikes[1, 2] = torch.tensor([steps * dt, float("inf"), float("inf")])  # window end: last step
    spikes[2, 4] = torch.tensor([-1.0, 250.0, float("nan")])  # outside the window: dropped
    spikes[3] = float("inf")  # a silent window
    ref = nn.functional.linear(spike_raster(spikes, dt, steps), fc.weight, fc.bias)
    (got,) = _run_onnx(_Raster(fc, k, dt, steps).eval(), (spikes,), ["spikes"], exporter)
    assert got.shape == (steps, 5, 7)
    assert np.abs(got - ref.detach().numpy()).max() < 1e-5


class _Rows(nn.Module):
    def __init__(self, hidden, beta, subtract):
        super().__init__()
        from tactilesnn.models.snn import _LSTMWeights

        self.lif = _LSTMWeights(hidden, beta, 1.0, subtract)
        self.register_buffer("w_rec", torch.zeros(0, 0))

    def forward(self, cur, u0, s0):
        return self.lif(cur, u0, s0, self.w_rec)


@pytest.mark.slow
@pytest.mark.parametrize("subtract", [True, False])
def test_feed_forward_lif_runs_as_rows_of_units_and_spikes_like_the_scan(subtract):
    """64 independent units as 4 LSTM rows of 16 (a smaller per-step product): same spikes and
    membranes as the scan, in torch and in onnxruntime (with another batch size than traced)."""
    from tactilesnn.models.snn import _unit_rows

    assert [_unit_rows(h, 16) for h in (64, 16, 8, 48, 100, 17)] == [4, 1, 1, 3, 5, 1]
    g = torch.Generator().manual_seed(3)
    steps, batch, hidden, beta = 120, 3, 64, 0.9048
    cur = (0.35 * torch.randn(steps, batch, hidden, generator=g) + 0.12).float()
    u0 = (0.5 * torch.rand(batch, hidden, generator=g)).float()
    mod = _Rows(hidden, beta, subtract)
    assert mod.lif.rows == 4 and mod.lif.W.shape == (1, 64, 16)
    ref_s, ref_u = lif_scan(cur, u0, beta, 1.0, subtract)
    got_s, got_u, _ = mod(cur, u0, torch.zeros_like(u0))
    assert torch.equal(got_s, ref_s) and torch.allclose(got_u, ref_u, atol=1e-6)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "m.onnx"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(mod, (cur, u0, torch.zeros_like(u0)), str(path), dynamo=False,
                              input_names=["cur", "u0", "s0"], opset_version=17,
                              dynamic_axes={"cur": {1: "b"}, "u0": {0: "b"}, "s0": {0: "b"}})  # fmt: skip
        lstm = [n for n in onnx.load(str(path)).graph.node if n.op_type == "LSTM"]
        assert [a.i for n in lstm for a in n.attribute if a.name == "hidden_size"] == [16]
        sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        cur, u0 = cur[:, 1:], u0[1:]  # batch 2, traced with 3
        ref_s, ref_u = lif_scan(cur, u0, beta, 1.0, subtract)
        feeds = {"cur": cur.numpy(), "u0": u0.numpy(), "s0": np.zeros_like(u0.numpy())}
        spikes, u_t, _ = sess.run(None, feeds)
        assert ref_s.sum() > 300
        assert np.array_equal(spikes, ref_s.numpy())
        assert np.abs(u_t - ref_u.numpy()).max() < 1e-4
