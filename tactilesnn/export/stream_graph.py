"""The stream graph: the next ``step`` samples in, the scores of the window they complete out.

For a pipeline whose encoder has a stream form (``encoder.stream_module(step)``: the ``cgwt``
encoder's causal bank), the graph takes the next ``step`` samples of every channel (``window``
input ``[batch, channels, step]``; default half a window, any whole number of the encoder's hops
that divides the window and is at most half of it) plus the encoder's state and the model's, and
returns ``scores`` and every state's next value (``<name>_out``): a window ends every ``step``
samples. Each input sample is transformed once (the window graph of a half-overlapping stream
transforms every sample twice). ``step`` trades rate for latency: one hop gives the spikes (and
scores) of the window ending at each frame one call after the frame's last sample, at the cost
of coding and classifying a whole window per frame. A fresh stream starts from
:func:`initial_state` on its first step (the calls before the first complete window give
scores that are discarded); ``stream_windows`` runs a whole stream, as the service would.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import Tensor, nn

from ..core.graph_contract import SCORES_OUTPUT, WINDOW_INPUT, state_output
from ..core.onnx_graph import chain, component_to_onnx, operator_nodes
from ..core.onnx_prune import prune_to_outputs
from ..pipeline import SpikePipeline
from .onnx import PipelineEncoderGraph, build_model_part

#: the window's samples before the step, carried where the pipeline's level code reads them
PREV_STATE = "stream_prev"


class StreamEncoderGraph(PipelineEncoderGraph):
    """``step`` samples + encoder state -> the completed window's spikes (level code and clock
    afferents appended, as the window graph) + the next state. The encoder's stream step is
    this graph's ``encoder``."""

    def __init__(self, pipe: SpikePipeline, step: int | None = None) -> None:
        if stage := pipe.window_stage():
            raise ValueError(f"{stage}: the stream graph, which codes each sample "
                             "once, cannot; export the window graph")  # fmt: skip
        if not pipe.encoder.has_stream_form:
            pipe.encoder.stream_module()  # the error naming the encoder
        self.step = stream_step(pipe, step)
        enc = pipe.encoder.stream_module(self.step)
        super().__init__(pipe, encoder=enc)
        self.state_init = dict(enc.state_init)
        self.with_prev = self.with_level
        n = len(pipe.channel_idx)
        self.state_names = list(enc.state_names)
        self.n_step_states = len(self.state_names)
        self.kept = pipe.window - self.step
        if self.with_prev:
            self.state_names.append((PREV_STATE, n * self.kept))

    def forward(self, chunk: Tensor, *state: Tensor) -> tuple[Tensor, ...]:
        x = torch.index_select(chunk, 1, self.channel_idx) if self.select else chunk
        k = self.n_step_states
        s, *new = self.encoder(x, *state[:k])
        window = x
        if self.with_prev:
            b, c = x.shape[0], x.shape[1]
            window = torch.cat([state[k].reshape(b, c, self.kept), x], -1)
            new.append(window[..., self.step :].reshape(b, -1))
        return (self.append(s, window), *new)


def stream_step(pipe: SpikePipeline, step: int | None) -> int:
    """The stream graph's samples per call: ``step``, or half the window when None."""
    return pipe.window // 2 if step is None else int(step)


def build_stream_graph(
    pipe: SpikePipeline, exporter: str | None = None, step: int | None = None
) -> tuple[onnx.ModelProto, list[tuple[str, int]], dict[str, str]]:
    """The stream graph (``step`` samples per call, default half a window), its encoder state
    ``(name, units)`` (the model's follow in the graph's inputs, as in the window graph) and how
    a fresh stream starts them (the runtime's rule per state: ``repeat_first``; unnamed states
    start at zero). Both parts from :func:`~tactilesnn.core.onnx_graph.component_to_onnx`
    (``exporter``: see there)."""
    graph = StreamEncoderGraph(pipe, step).eval()
    names = graph.state_names
    mod = build_model_part(pipe, exporter)  # (the window encoder's graph is not needed here)
    gen = torch.Generator().manual_seed(0)
    chunk = torch.randn(2, len(pipe.channel_names), graph.step, generator=gen)
    state = [torch.randn(2, u, generator=gen) for _, u in names]
    io = ([WINDOW_INPUT, *(n for n, _ in names)], ["spikes", *(state_output(n) for n, _ in names)])
    enc = component_to_onnx(graph, (chunk, *state), *io, exporter=exporter)
    model = chain(enc, mod, [("spikes", "spikes_in")], tags=("enc/", "model/"))
    return model, names, graph.state_init


def initial_state(
    pipe: SpikePipeline, first: np.ndarray, step: int | None = None
) -> dict[str, np.ndarray]:
    """The encoder state of fresh streams whose first steps are ``first [B, channels, >= 1]``
    (all the run's channels), before that step is fed (``step``: the graph's)."""
    graph = StreamEncoderGraph(pipe, step)
    sel = np.asarray(first, np.float32)[:, list(pipe.channel_idx)]
    state = graph.encoder.initial_state(sel[:, :, 0])
    if graph.with_prev:
        state[PREV_STATE] = np.zeros((len(sel), sel.shape[1] * graph.kept), np.float32)
    return state


def stream_windows(
    model: onnx.ModelProto,
    pipe: SpikePipeline,
    stream: np.ndarray,
    spikes: bool = False,
    carry_model: bool = True,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Scores ``[windows, classes]`` of every complete window of ``stream [channels, samples]``
    (a window ending every step: the graph's input length) through the stream graph ``model``
    in onnxruntime, the encoder's state carried, the model's too unless ``carry_model`` is False
    (then zeros for each window, as torch's per-window scores). With ``spikes``, also the
    encoder's spike times ``[windows, afferents, slots]`` (the graph's intermediate ``spikes``
    value, exposed)."""
    session = stream_session(model, expose_spikes=spikes)
    step = int(next(i for i in session.get_inputs() if i.name == WINDOW_INPUT).shape[2])
    n, first_complete = stream.shape[1] // step, pipe.window // step - 1
    inputs = [i.name for i in session.get_inputs()]
    x = np.asarray(stream, np.float32)
    state = initial_state(pipe, x[None, :, :step], step)
    encoder = set(state)
    zeros = {i.name: np.zeros((1, int(i.shape[1])), np.float32) for i in session.get_inputs()
             if i.name != WINDOW_INPUT and i.name not in state}  # fmt: skip
    state.update(zeros)
    outs = [SCORES_OUTPUT, *(state_output(k) for k in inputs if k != WINDOW_INPUT)]
    if spikes:
        outs.append("spikes")
    scores, times = [], []
    for k in range(n):
        got = session.run(outs, {WINDOW_INPUT: x[None, :, k * step : (k + 1) * step], **state})
        done = k >= first_complete  # the calls before complete no window
        for name, value in zip(outs[1:], got[1:], strict=False):
            # an incomplete window's scores, and the model's state they give, are discarded
            if name.endswith("_out") and (done or name[: -len("_out")] in encoder):
                state[name[: -len("_out")]] = value
        if not carry_model:
            state.update(zeros)
        if done:
            scores.append(got[0][0])
            if spikes:
                times.append(got[-1][0])
    s = np.asarray(scores)
    return (np.asarray(times), s) if spikes else s


def stream_session(model: onnx.ModelProto, expose_spikes: bool = False):
    """An onnxruntime session of the stream graph ``model`` (1 thread) that computes its scores
    and state alone, or also exposes the encoder's ``spikes`` value (``expose_spikes``)."""
    import onnxruntime as ort

    copy = onnx.ModelProto()
    copy.CopyFrom(model)
    if expose_spikes:
        copy.graph.output.append(
            onnx.helper.make_tensor_value_info("spikes", onnx.TensorProto.FLOAT, None)
        )
    else:  # scores and state only: onnxruntime runs every node whatever a call asks for
        states = [i.name for i in copy.graph.input if i.name != WINDOW_INPUT]
        prune_to_outputs(copy.graph, [SCORES_OUTPUT, *(state_output(n) for n in states)])
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    return ort.InferenceSession(copy.SerializeToString(), opts, providers=["CPUExecutionProvider"])


#: test windows joined end to end into the stream the export is verified on
CHECK_WINDOWS = 64
#: at most this many of its windows (one ends every step) are compared with torch
CHECK_STREAM_WINDOWS = 2048


def reference_stream(
    pipe: SpikePipeline, stream: np.ndarray, step: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Torch's spike times ``[windows, afferents, 1]`` and scores (each window's model from zero
    state) of every complete window of ``stream [channels, samples]``, a window ending every
    ``step`` samples (default half a window): the encoder's ``stream_reference`` (float64;
    ``cgwt``: its bank run once over the whole stream), then the level code and clock afferents
    of each window, as the graph appends them."""
    step = stream_step(pipe, step)
    x = torch.from_numpy(np.asarray(stream, np.float64)[None, list(pipe.channel_idx)])
    n = stream.shape[1] // step - pipe.window // step + 1
    with torch.no_grad():
        t = pipe.encoder.stream_reference(x, step)  # the encoder's own reference
        wins = np.stack([stream[:, j * step : j * step + pipe.window] for j in range(n)])
        graph = PipelineEncoderGraph(pipe, encoder=nn.Identity())
        sel = torch.from_numpy(np.ascontiguousarray(wins[:, list(pipe.channel_idx)], np.float32))
        spikes = graph.append(t, sel)
        scores = pipe.scores(spikes).numpy()
    return spikes.numpy(), scores


def export_stream(
    pipe: SpikePipeline,
    out: Path,
    X_check: np.ndarray,
    metadata: dict[str, str] | None = None,
    overwrite: bool = False,
    exporter: str | None = None,
    step: int | None = None,
) -> dict:
    """Write the stream graph of ``pipe`` (``step`` samples per call, default half a window) to
    ``out`` after verifying it in onnxruntime against :func:`reference_stream` on up to
    ``CHECK_WINDOWS`` of ``X_check`` joined into one stream (its first ``CHECK_STREAM_WINDOWS``
    complete windows): spike times within the window graph's tolerances, scores (the model's
    state reset for each window, as torch's) within its score tolerance except on its
    rounding-boundary allowance."""
    from .onnx import (
        TIME_ATOL_MS,
        TIME_RTOL,
        ExportError,
        _boundary_allowance,
        check_out,
        compare_spike_times,
        pipeline_contract,
        save_atomic,
        score_tolerance,
    )

    out = check_out(out, overwrite)
    step = stream_step(pipe, step)
    model, names, init = build_stream_graph(pipe, exporter, step)
    model_states = tuple(n for n, _ in pipe.model.state_names)
    extra = {**dict(metadata or {}), "stream_step_samples": str(step),
             "stream_encoder_states": json.dumps([n for n, _ in names]),
             "stream_state_init": json.dumps(init)}  # fmt: skip
    contract = pipeline_contract(pipe, (*(n for n, _ in names), *model_states),
                                 f"input: the next {step} samples in the sensor's readout units",
                                 extra)  # fmt: skip
    for k, v in contract.to_metadata().items():
        entry = model.metadata_props.add()
        entry.key, entry.value = k, str(v)
    onnx.checker.check_model(model)
    X = np.asarray(X_check, np.float32)[:CHECK_WINDOWS]
    stream = np.concatenate(list(X), axis=1) if len(X) else np.zeros((X.shape[1], 0), np.float32)
    if stream.shape[1] < 2 * pipe.window:
        raise ValueError("the stream graph is verified on at least two test windows; got fewer")
    stream = stream[:, : pipe.window + (CHECK_STREAM_WINDOWS - 1) * step]  # bounded work
    want_t, want_s = reference_stream(pipe, stream, step)
    got_t, got_s = stream_windows(model, pipe, stream, spikes=True, carry_model=False)
    tol = max(TIME_ATOL_MS, TIME_RTOL * pipe.duration_ms)
    dt, flips = compare_spike_times(got_t, want_t, pipe.duration_ms, tol)
    per = np.abs(got_s - want_s).max(1)
    off = int((~(per <= score_tolerance(want_s))).sum())  # a NaN score is off
    if off > _boundary_allowance(len(per)):
        raise ExportError(f"stream graph differs from torch by up to {per.max():.3g} on {off} of "
                          f"{len(per)} windows")  # fmt: skip
    agree = float((got_s.argmax(1) == want_s.argmax(1)).mean())
    save_atomic(model, out)
    return {"path": str(out), "nodes": operator_nodes(model), "windows_checked": len(per),
            "encoder_max_time_diff_ms": dt, "encoder_cutoff_flips": flips,
            "max_score_diff": float(per.max()), "prediction_agreement": agree,
            "step_samples": step, "encoder_state": dict(names)}  # fmt: skip
