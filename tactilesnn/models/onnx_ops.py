"""Exported forms of the functional core with no per-step ONNX nodes.

A scripted scan becomes an ONNX ``Loop`` (~4 us of onnxruntime overhead per iteration), a traced
one ``T`` copies of its step (~0.3 us per node): at 100 steps either costs more than the whole
rest of a pipeline. These :class:`torch.autograd.Function` s compute with the reference functions
of :mod:`~tactilesnn.models.functional` in torch and export as single vectorised operators:

* :class:`RasterCurrent`: spike times -> the raster's input current ``W raster_t + b`` as one
  ``ScatterND`` (each spike adds its afferent's weight column to its step), not a dense
  ``[T, afferents]`` raster times ``W``;
* :class:`LIFAsLSTM`: the LIF recurrence as one ``LSTM`` node
  (:func:`~tactilesnn.models.functional.lif_lstm_parameters`).

Export parity with the reference is checked by every export (``export.onnx.verify``) and by
``tests/models/test_onnx_ops.py``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..core.spikes import spike_raster
from .functional import lif_lstm_activations, lif_lstm_parameters, lif_rec_scan, lif_scan

_I64 = 7  # onnx.TensorProto.INT64


def _const(g, value) -> object:
    return g.op("Constant", value_t=torch.as_tensor(value))


class RasterCurrent(torch.autograd.Function):
    """``spikes [B, A, k]`` (ms) -> ``spike_raster(spikes) @ weight.T + bias`` as ``[T, B, H]``.

    ``updates``: ``weight.T`` with each row repeated ``k`` times (``[A k, H]``), what the
    exported ``ScatterND`` adds at each spike's step.
    """

    @staticmethod
    def forward(ctx, spikes, weight, bias, updates, dt_ms: float, steps: int):  # type: ignore[override]
        return torch.nn.functional.linear(spike_raster(spikes, dt_ms, steps), weight, bias)

    @staticmethod
    def symbolic(g, spikes, weight, bias, updates, dt_ms: float, steps: int):
        t = int(steps)
        ak, h = updates.type().sizes()
        q = g.op("Floor", g.op("Div", spikes, _const(g, float(dt_ms))))
        # step -> scatter row by a table (one Gather instead of five elementwise nodes on every
        # spike slot): steps 0..T-1 stay, T (a spike at exactly the window end) is the last
        # step (the spike_raster convention), below 0 and above T (silent: inf) the discarded
        # row T; the clip maps those to -1 and T + 1, the table's last entry, and so does the
        # where a NaN (dropped, as in torch)
        table = torch.cat([torch.arange(t), torch.tensor([t - 1, t])])
        q = g.op("Clip", q, _const(g, -1.0), _const(g, float(t + 1)))
        q = g.op("Where", g.op("IsNaN", q), _const(g, -1.0), q)
        q = g.op("Cast", q, to_i=_I64)
        step = g.op("Reshape", g.op("Gather", _const(g, table), q), _const(g, [-1, ak, 1]))
        ones = g.op("ConstantOfShape", g.op("Shape", step), value_t=torch.ones(1, dtype=torch.long))
        sample = g.op("CumSum", ones, _const(g, 0), exclusive_i=1)  # 0, 1, ... per window
        # scattered time-major, [T + 1, B, H], so no transpose follows
        index = g.op("Concat", step, sample, axis_i=2)  # [B, A k, 2]: (step, window)
        batch = g.op("Shape", spikes, start_i=0, end_i=1)
        upd = g.op("Expand", updates, g.op("Concat", batch, _const(g, [ak, h]), axis_i=0))
        zeros = g.op(
            "ConstantOfShape",
            g.op("Concat", _const(g, [t + 1]), batch, _const(g, [h]), axis_i=0),
            value_t=torch.zeros(1),
        )
        cur = g.op("ScatterND", zeros, index, upd, reduction_s="add")  # [T + 1, B, H]
        cur = g.op("Slice", cur, _const(g, [0]), _const(g, [t]), _const(g, [0]))
        return g.op("Add", cur, bias)


class LIFAsLSTM(torch.autograd.Function):
    """LIF scan ``cur [T, B, H]`` from ``(u0, s0)`` -> ``(spikes [T, B, H], u_T, s_T)``.

    Computes with :func:`~tactilesnn.models.functional.lif_scan` (``lif_rec_scan`` when
    ``w_rec`` has ``H x H`` entries) and exports as one ``LSTM`` node whose ``W``, ``R``, ``B``
    are :func:`~tactilesnn.models.functional.lif_lstm_parameters`.
    """

    @staticmethod
    def forward(ctx, cur, u0, s0, w_rec, w, r, b, beta: float, theta: float, subtract: bool):  # type: ignore[override]
        if s0 is None:  # no spike before the first step (a feed-forward layer's state is u alone)
            s0 = torch.zeros_like(u0)
        if w_rec.shape[0] == cur.shape[-1]:
            return lif_rec_scan(cur, u0, s0, w_rec, beta, theta, subtract)
        spikes, u = lif_scan(cur, u0, beta, theta, subtract)
        return spikes, u, spikes[-1]

    @staticmethod
    def symbolic(g, cur, u0, s0, w_rec, w, r, b, beta: float, theta: float, subtract: bool):
        from torch.onnx.symbolic_opset9 import unused

        hidden = int(w.type().sizes()[-1])  # W [1, 4H, H] (lif_lstm_parameters)
        attrs = lif_lstm_activations(theta)
        axis0 = _const(g, [0])
        # c holds the membrane before reset: after a spike that is u + theta (subtract); with a
        # reset to zero, u0 is already the post-reset value and the forget gate handles s0
        # s0 None: h_0 omitted (the LSTM's default is zeros) and c_0 = u0
        if s0 is None:
            c0, h0 = u0, unused(g)
        else:
            c0 = g.op("Add", u0, g.op("Mul", s0, _const(g, float(theta)))) if subtract else u0
            h0 = g.op("Unsqueeze", s0, axis0)
        y, yh, yc = g.op(
            "LSTM",
            cur,
            w,
            r,
            b,
            unused(g),
            h0,
            g.op("Unsqueeze", c0, axis0),
            hidden_size_i=hidden,
            activations_s=attrs["activations"],
            activation_alpha_f=attrs["activation_alpha"],
            activation_beta_f=attrs["activation_beta"],
            outputs=3,
        )
        spikes = g.op("Squeeze", y, _const(g, [1]))
        s_t = g.op("Squeeze", yh, axis0)
        c_t = g.op("Squeeze", yc, axis0)
        if subtract:
            u_t = g.op("Sub", c_t, g.op("Mul", s_t, _const(g, float(theta))))
        else:
            u_t = g.op("Mul", c_t, g.op("Sub", _const(g, 1.0), s_t))
        return spikes, u_t, s_t


def lif_lstm_buffers(
    hidden: int, beta: float, theta: float, subtract: bool, w_rec: Tensor | None
) -> dict[str, Tensor]:
    """``W``, ``R``, ``B`` of :class:`LIFAsLSTM`'s node, to register as module buffers."""
    p = lif_lstm_parameters(hidden, beta, theta, subtract, w_rec)
    return {"W": p["W"], "R": p["R"], "B": p["B"]}
