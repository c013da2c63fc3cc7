"""Exported forms of the functional core with no per-step ONNX nodes.

A scripted scan becomes an ONNX ``Loop`` (~4 us of onnxruntime overhead per iteration), a traced
one ``T`` copies of its step (~0.3 us per node): at 100 steps either costs more than the whole
rest of a pipeline. These operators compute with the reference functions of
:mod:`~tactilesnn.models.functional` in torch and export as single vectorised ONNX operators:

* :func:`raster_current`: spike times -> the raster's input current ``W raster_t + b`` as one
  ``ScatterND`` (each spike adds its afferent's weight column to its step), not a dense
  ``[T, afferents]`` raster times ``W``;
* :func:`lif_as_lstm`: the LIF recurrence as one ``LSTM`` node
  (:func:`~tactilesnn.models.functional.lif_lstm_parameters`).

Each is written once (``_raster_nodes``, ``_lif_nodes``) against a small node emitter and reaches
both exporters: the TorchScript-based one through an autograd function's ``symbolic``, the
supported ``torch.export``-based one through a custom torch op (``tactilesnn::...``) and its
translation, registered with :func:`~tactilesnn.core.onnx_graph.register_translation`. Export
parity with the reference is checked by every export (``export.onnx.verify``) and by
``tests/models/test_onnx_ops.py``, for both exporters.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..core.onnx_graph import register_translation
from ..core.spikes import spike_raster
from .functional import lif_lstm_activations, lif_lstm_parameters, lif_rec_scan, lif_scan

_I64 = 7  # onnx.TensorProto.INT64
#: the LIF form's outputs: spikes, membrane and spikes of the last step
_Three = tuple[Tensor, Tensor, Tensor]


class _TorchScriptNodes:
    """Node emitter for a ``symbolic`` (TorchScript exporter): ``g.op`` with typed attribute
    suffixes (``_i``, ``_f``, ``_s``, ``_t``) inferred from the Python values."""

    def __init__(self, g) -> None:
        self.g = g

    def op(self, name: str, *inputs, outputs: int = 1, **attrs):
        typed = {}
        for k, v in attrs.items():
            first = v[0] if isinstance(v, (list, tuple)) else v
            kind = ("s" if isinstance(first, str) else "f" if isinstance(first, float)
                    else "t" if isinstance(first, torch.Tensor) else "i")  # fmt: skip
            typed[f"{k}_{kind}"] = v
        return self.g.op(name, *inputs, outputs=outputs, **typed)

    def const(self, value):
        return self.g.op("Constant", value_t=torch.as_tensor(value))

    def none(self):
        from torch.onnx.symbolic_opset9 import unused

        return unused(self.g)

    @staticmethod
    def sizes(value) -> list[int]:
        return list(value.type().sizes())


class _OnnxScriptNodes:
    """Node emitter for a translation of the ``torch.export``-based exporter (onnxscript)."""

    def __init__(self) -> None:
        from onnxscript import opset18

        self.ops = opset18

    def op(self, name: str, *inputs, outputs: int = 1, **attrs):
        attrs = {k: (_proto(v) if isinstance(v, torch.Tensor) else v) for k, v in attrs.items()}
        return getattr(self.ops, name)(*inputs, **attrs)

    def const(self, value):
        return self.ops.Constant(value=_proto(torch.as_tensor(value)))

    def none(self):
        return None

    @staticmethod
    def sizes(value) -> list[int]:
        return [int(d) for d in value.shape]


def _proto(t: Tensor):
    import onnx

    return onnx.numpy_helper.from_array(t.numpy())


def _raster_nodes(e, spikes, bias, updates, dt_ms: float, steps: int):
    """``spikes [B, A, k]`` -> ``[T, B, H]`` current: one ``ScatterND`` of ``updates`` rows."""
    t = int(steps)
    ak, h = e.sizes(updates)
    q = e.op("Floor", e.op("Div", spikes, e.const(float(dt_ms))))
    # step -> scatter row by a table (one Gather instead of five elementwise nodes on every
    # spike slot): steps 0..T-1 stay, T (a spike at exactly the window end) is the last
    # step (the spike_raster convention), below 0 and above T (silent: inf) the discarded
    # row T; the clip maps those to -1 and T + 1, the table's last entry, and so does the
    # where a NaN (dropped, as in torch)
    table = torch.cat([torch.arange(t), torch.tensor([t - 1, t])])
    q = e.op("Clip", q, e.const(-1.0), e.const(float(t + 1)))
    q = e.op("Where", e.op("IsNaN", q), e.const(-1.0), q)
    q = e.op("Cast", q, to=_I64)
    step = e.op("Reshape", e.op("Gather", e.const(table), q), e.const([-1, ak, 1]))
    ones = e.op("ConstantOfShape", e.op("Shape", step), value=torch.ones(1, dtype=torch.long))
    sample = e.op("CumSum", ones, e.const(0), exclusive=1)  # 0, 1, ... per window
    # scattered time-major, [T + 1, B, H], so no transpose follows
    index = e.op("Concat", step, sample, axis=2)  # [B, A k, 2]: (step, window)
    batch = e.op("Shape", spikes, start=0, end=1)
    upd = e.op("Expand", updates, e.op("Concat", batch, e.const([ak, h]), axis=0))
    zeros = e.op(
        "ConstantOfShape",
        e.op("Concat", e.const([t + 1]), batch, e.const([h]), axis=0),
        value=torch.zeros(1),
    )
    cur = e.op("ScatterND", zeros, index, upd, reduction="add")  # [T + 1, B, H]
    cur = e.op("Slice", cur, e.const([0]), e.const([t]), e.const([0]))
    return e.op("Add", cur, bias)


def _lif_nodes(e, cur, u0, s0, w, r, b, theta: float, subtract: bool):
    """``cur [T, B, H]`` from ``(u0, s0)`` -> ``(spikes, u_T, s_T)`` through one ``LSTM``."""
    hidden = int(e.sizes(w)[-1])  # W [1, 4H, H] (lif_lstm_parameters)
    attrs = lif_lstm_activations(theta)
    axis0 = e.const([0])
    # c holds the membrane before reset: after a spike that is u + theta (subtract); with a
    # reset to zero, u0 is already the post-reset value and the forget gate handles s0
    # s0 None: h_0 omitted (the LSTM's default is zeros) and c_0 = u0
    if s0 is None:
        c0, h0 = u0, e.none()
    else:
        c0 = e.op("Add", u0, e.op("Mul", s0, e.const(float(theta)))) if subtract else u0
        h0 = e.op("Unsqueeze", s0, axis0)
    y, yh, yc = e.op(
        "LSTM", cur, w, r, b, e.none(), h0, e.op("Unsqueeze", c0, axis0), outputs=3,
        hidden_size=hidden, activations=attrs["activations"],
        activation_alpha=attrs["activation_alpha"], activation_beta=attrs["activation_beta"],
    )  # fmt: skip
    spikes = e.op("Squeeze", y, e.const([1]))
    s_t = e.op("Squeeze", yh, axis0)
    c_t = e.op("Squeeze", yc, axis0)
    if subtract:
        u_t = e.op("Sub", c_t, e.op("Mul", s_t, e.const(float(theta))))
    else:
        u_t = e.op("Mul", c_t, e.op("Sub", e.const(1.0), s_t))
    return spikes, u_t, s_t


def _lif_reference(cur, u0, s0, w_rec, beta: float, theta: float, subtract: bool):
    if s0 is None:  # no spike before the first step (a feed-forward layer's state is u alone)
        s0 = torch.zeros_like(u0)
    if w_rec.shape[0] == cur.shape[-1]:
        return lif_rec_scan(cur, u0, s0, w_rec, beta, theta, subtract)
    spikes, u = lif_scan(cur, u0, beta, theta, subtract)
    return spikes, u, spikes[-1]


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
        return _raster_nodes(_TorchScriptNodes(g), spikes, bias, updates, dt_ms, steps)


class LIFAsLSTM(torch.autograd.Function):
    """LIF scan ``cur [T, B, H]`` from ``(u0, s0)`` -> ``(spikes [T, B, H], u_T, s_T)``.

    Computes with :func:`~tactilesnn.models.functional.lif_scan` (``lif_rec_scan`` when
    ``w_rec`` has ``H x H`` entries) and exports as one ``LSTM`` node whose ``W``, ``R``, ``B``
    are :func:`~tactilesnn.models.functional.lif_lstm_parameters`.
    """

    @staticmethod
    def forward(ctx, cur, u0, s0, w_rec, w, r, b, beta: float, theta: float, subtract: bool):  # type: ignore[override]
        return _lif_reference(cur, u0, s0, w_rec, beta, theta, subtract)

    @staticmethod
    def symbolic(g, cur, u0, s0, w_rec, w, r, b, beta: float, theta: float, subtract: bool):
        return _lif_nodes(_TorchScriptNodes(g), cur, u0, s0, w, r, b, theta, subtract)


@torch.library.custom_op("tactilesnn::raster_current", mutates_args=())
def _raster_op(spikes: Tensor, weight: Tensor, bias: Tensor, updates: Tensor, dt_ms: float,
               steps: int) -> Tensor:  # fmt: skip
    return torch.nn.functional.linear(spike_raster(spikes, dt_ms, steps), weight, bias)


@_raster_op.register_fake
def _(spikes, weight, bias, updates, dt_ms, steps):
    return spikes.new_empty((int(steps), spikes.shape[0], weight.shape[0]))


@torch.library.custom_op("tactilesnn::lif_as_lstm", mutates_args=())
def _lif_op(cur: Tensor, u0: Tensor, s0: Tensor | None, w_rec: Tensor, w: Tensor, r: Tensor,
            b: Tensor, beta: float, theta: float, subtract: bool) -> _Three:  # fmt: skip
    spikes, u, s = _lif_reference(cur, u0, s0, w_rec, beta, theta, subtract)
    return spikes, u, s.clone()  # (a custom op's outputs may not alias one another)


@_lif_op.register_fake
def _(cur, u0, s0, w_rec, w, r, b, beta, theta, subtract):
    return torch.empty_like(cur), torch.empty_like(u0), torch.empty_like(u0)


def _raster_translation(spikes, weight, bias, updates, dt_ms: float, steps: int):
    return _raster_nodes(_OnnxScriptNodes(), spikes, bias, updates, dt_ms, steps)


def _lif_translation(cur, u0, s0, w_rec, w, r, b, beta: float, theta: float, subtract: bool):
    return _lif_nodes(_OnnxScriptNodes(), cur, u0, s0, w, r, b, theta, subtract)


register_translation("tactilesnn::raster_current", _raster_translation)
register_translation("tactilesnn::lif_as_lstm", _lif_translation)


def raster_current(spikes: Tensor, weight: Tensor, bias: Tensor, updates: Tensor, dt_ms: float,
                   steps: int) -> Tensor:  # fmt: skip
    """:class:`RasterCurrent`, or its custom op while ``torch.export`` traces."""
    if torch.compiler.is_exporting():
        return _raster_op(spikes, weight, bias, updates, float(dt_ms), int(steps))
    return RasterCurrent.apply(spikes, weight, bias, updates, dt_ms, steps)


def lif_as_lstm(cur: Tensor, u0: Tensor, s0: Tensor | None, w_rec: Tensor, w: Tensor, r: Tensor,
                b: Tensor, beta: float, theta: float, subtract: bool) -> _Three:  # fmt: skip
    """:class:`LIFAsLSTM`, or its custom op while ``torch.export`` traces."""
    if torch.compiler.is_exporting():
        return _lif_op(cur, u0, s0, w_rec, w, r, b, float(beta), float(theta), bool(subtract))
    return LIFAsLSTM.apply(cur, u0, s0, w_rec, w, r, b, beta, theta, subtract)


def lif_lstm_buffers(
    hidden: int, beta: float, theta: float, subtract: bool, w_rec: Tensor | None
) -> dict[str, Tensor]:
    """``W``, ``R``, ``B`` of :class:`LIFAsLSTM`'s node, to register as module buffers."""
    p = lif_lstm_parameters(hidden, beta, theta, subtract, w_rec)
    return {"W": p["W"], "R": p["R"], "B": p["B"]}
