"""The one-frame step graph: a frame of samples and the state in, that frame's scores out.

For a pipeline of a continuous code (an encoder with ``has_frame_step``: ``frames``) and a
stream model (a model with ``has_frame_step``: ``stream``), the graph takes one hop of samples of
every channel (``window`` input ``[1, channels, hop]``) and its state (``[1, units]``:
the code's bank tail and recursion, its converters, whether the stream has started; the model's
membranes and its silent-frame count) and returns ``scores`` (the readout at this frame),
``decision`` (the leading class where it leads by the fitted margin, else -1) and each state's
next value (``<name>_out``). No loop over a window: each call is one frame, so a decision is
one frame (one hop) after the frame's last sample. A fresh stream starts from
:func:`initial_frame_state` (the runtime's rule per state, in the graph's metadata: the code's
tail repeats the stream's first sample, every other state starts at zero).

:func:`run_frames` runs a whole recording through the graph in onnxruntime, as a service
would; :func:`torch_frames` through the same step in torch; :func:`export_frames` writes the
graph after checking the two agree frame by frame over whole recordings (spikes, scores,
decisions and state).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import Tensor, nn

from ..core.graph_contract import SCORES_OUTPUT, WINDOW_INPUT, state_output
from ..core.onnx_graph import component_to_onnx, operator_nodes
from ..pipeline import SpikePipeline

DECISION_OUTPUT = "decision"
SPIKES_OUTPUT = "frame_spikes"


#: the graph's one state input (every part packed: one input and one output instead of six
#: of each; each graph input or output costs onnxruntime ~1.5 us per call from Python)
STATE = "frame_state"


class FrameGraph(nn.Module):
    """``window [B, channels, hop]`` + ``frame_state [B, units]`` -> ``(scores, decision,
    frame spikes, next frame_state)``: the code's frame step, then the model's; the state is
    their parts (:attr:`parts`: ``(name, units)``) side by side."""

    def __init__(self, pipe: SpikePipeline, gather: bool = False) -> None:
        super().__init__()
        problem = pipe.frame_problem()
        if problem:
            raise ValueError(problem)
        self.encoder = pipe.encoder.frame_module()
        self.model = pipe.model.frame_module(gather)
        idx = list(pipe.channel_idx)
        self.select = idx != list(range(len(pipe.channel_names)))
        self.register_buffer("channel_idx", torch.as_tensor(idx, dtype=torch.long))
        self.n_enc = len(self.encoder.state_names)
        self.parts: list[tuple[str, int]] = [*self.encoder.state_names, *self.model.state_names]
        self.state_names = [(STATE, sum(u for _, u in self.parts))]
        self.hop = pipe.encoder.frame_hop
        self.encoder_init = pipe.encoder.initial_frame_state
        self.channels = idx

    def forward(self, frame: Tensor, state: Tensor) -> tuple[Tensor, ...]:
        x = torch.index_select(frame, 1, self.channel_idx) if self.select else frame
        parts = state.split([u for _, u in self.parts], 1)
        spikes, *enc_new = self.encoder(x, *parts[: self.n_enc])
        scores, decision, *model_new = self.model(spikes, *parts[self.n_enc :])
        return scores, decision, spikes, torch.cat([*enc_new, *model_new], 1)


def initial_frame_state(graph: FrameGraph, first: np.ndarray) -> dict[str, np.ndarray]:
    """The state of fresh streams whose first frames are ``first [B, channels, >= 1]`` (all
    the data's channels): the code's (it holds each channel's first sample constant before the
    stream), the model's at rest (zeros)."""
    sel = np.asarray(first, np.float32)[:, graph.channels]
    parts = {n: np.zeros((len(sel), u), np.float32) for n, u in graph.parts}
    parts.update(graph.encoder_init(sel))
    return {STATE: np.concatenate([parts[n] for n, _ in graph.parts], 1)}


def repeat_first_rule(graph: FrameGraph) -> list[int]:
    """How a fresh stream's state holds its first samples, as the runtime applies it
    (``[offset, stride, length]``: encoder channel ``c``'s first sample fills
    ``state[offset + c stride : offset + c stride + length]``, every other entry zero), read off
    :func:`initial_frame_state` (first samples ``c + 1``) and checked against it."""
    c = len(graph.channels)
    first = np.zeros((1, max(graph.channels) + 1, 1), np.float32)
    first[0, graph.channels, 0] = np.arange(1, c + 1)
    state = initial_frame_state(graph, first)[STATE][0]
    where = [np.flatnonzero(state == k + 1) for k in range(c)]
    offset, length = int(where[0][0]), len(where[0])
    stride = int(where[1][0] - offset) if c > 1 else length
    rule = [offset, stride, length]
    want = np.zeros_like(state)
    for k in range(c):
        want[offset + k * stride : offset + k * stride + length] = k + 1
    if not np.array_equal(want, state):
        raise ValueError("the code's initial state is not one span per channel: no runtime rule")
    return rule


def build_frame_graph(
    pipe: SpikePipeline, exporter: str | None = None, gather: bool = False
) -> tuple[onnx.ModelProto, FrameGraph]:
    """The one-frame step graph (any batch of streams; batch 1 with ``gather``, whose gather
    reads the first stream's spikes) and its torch module."""
    graph = FrameGraph(pipe, gather).eval()
    batch = 1 if gather else 2  # (an example batch of 1 would fix the graph's batch at 1)
    gen = torch.Generator().manual_seed(0)
    frame = torch.randn(batch, len(pipe.channel_names), graph.hop, generator=gen)
    state = [torch.zeros(batch, u) for _, u in graph.state_names]
    names = [n for n, _ in graph.state_names]
    outs = [SCORES_OUTPUT, DECISION_OUTPUT, SPIKES_OUTPUT, *(state_output(n) for n in names)]
    model = component_to_onnx(graph, (frame, *state), [WINDOW_INPUT, *names], outs,
                              exporter=exporter)  # fmt: skip
    return model, graph


def frame_session(model: onnx.ModelProto, threads: int = 1):
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = int(threads)
    opts.inter_op_num_threads = 1
    return ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])


def _frames_of(stream: np.ndarray, hop: int) -> np.ndarray:
    x = np.asarray(stream, np.float32)
    n = x.shape[1] // hop
    return x[:, : n * hop].reshape(x.shape[0], n, hop).transpose(1, 0, 2)  # [frames, C, hop]


def run_frames(session, graph: FrameGraph, stream: np.ndarray) -> dict[str, np.ndarray]:
    """A whole recording ``stream [channels, samples]`` through the step graph in onnxruntime,
    one frame per call from a fresh state: ``scores [frames, classes]``, ``decision
    [frames]``, ``spikes [frames, afferents]`` and the final state."""
    frames = _frames_of(stream, graph.hop)
    state = initial_frame_state(graph, frames[:1])
    names = list(state)
    outs = [SCORES_OUTPUT, DECISION_OUTPUT, SPIKES_OUTPUT, *(state_output(n) for n in names)]
    scores, decision, spikes = [], [], []
    for f in frames:
        got = session.run(outs, {WINDOW_INPUT: f[None], **state})
        scores.append(got[0][0])
        decision.append(got[1][0])
        spikes.append(got[2][0])
        state = dict(zip(names, got[3:], strict=True))
    return {"scores": np.asarray(scores), "decision": np.asarray(decision, np.int64),
            "spikes": np.asarray(spikes), "state": state}  # fmt: skip


class BoundFrames:
    """One stream stepped frame after frame through buffers bound once (onnxruntime's
    IOBinding): each :meth:`step` copies the frame into the bound input, and the graph writes
    the next state straight into the buffer the following call reads (two buffers, swapped), so
    no call converts or allocates its feeds and outputs (33-35 us against 41 us per frame with
    ``session.run`` for the bench's 12-taxel step graph: docs/streaming.md). ``first [1,
    channels, >= 1]``: the stream's first samples (:func:`initial_frame_state`)."""

    def __init__(self, session, graph: FrameGraph, first: np.ndarray) -> None:
        import onnxruntime as ort

        state = initial_frame_state(graph, first)[STATE]
        if state.shape[0] != 1:
            raise ValueError(f"one stream at a time: first must be [1, channels, samples], "
                             f"got {np.shape(first)}")  # fmt: skip
        self.hop, n_in = graph.hop, int(np.shape(first)[1])
        self.frame = ort.OrtValue.ortvalue_from_numpy(np.zeros((1, n_in, self.hop), np.float32))
        self._state = [ort.OrtValue.ortvalue_from_numpy(state.copy()) for _ in range(2)]
        outs = {o.name: o for o in session.get_outputs()}
        n_cls = int(outs[SCORES_OUTPUT].shape[1])
        self._scores = ort.OrtValue.ortvalue_from_numpy(np.zeros((1, n_cls), np.float32))
        self._decision = ort.OrtValue.ortvalue_from_numpy(np.zeros(1, np.int64))
        self._spikes = ort.OrtValue.ortvalue_from_numpy(
            np.zeros((1, int(outs[SPIKES_OUTPUT].shape[1])), np.float32)
        )
        self._bind = []
        for src, dst in ((0, 1), (1, 0)):
            b = session.io_binding()
            b.bind_ortvalue_input(WINDOW_INPUT, self.frame)
            b.bind_ortvalue_input(STATE, self._state[src])
            b.bind_ortvalue_output(SCORES_OUTPUT, self._scores)
            b.bind_ortvalue_output(DECISION_OUTPUT, self._decision)
            b.bind_ortvalue_output(SPIKES_OUTPUT, self._spikes)
            b.bind_ortvalue_output(state_output(STATE), self._state[dst])
            self._bind.append(b)
        self._session, self._next = session, 0

    def step(self, frame: np.ndarray | None = None) -> None:
        """One frame ``[1, channels, hop]`` float32 (None: the frame already in
        :attr:`frame`); read the results from :attr:`scores` / :attr:`decision`."""
        if frame is not None:
            self.frame.update_inplace(np.ascontiguousarray(frame, np.float32))
        self._session.run_with_iobinding(self._bind[self._next])
        self._next ^= 1

    @property
    def scores(self) -> np.ndarray:
        return self._scores.numpy()

    @property
    def decision(self) -> np.ndarray:
        return self._decision.numpy()

    @property
    def spikes(self) -> np.ndarray:
        return self._spikes.numpy()

    @property
    def state(self) -> np.ndarray:
        """The state after the last step."""
        return self._state[self._next].numpy()


@torch.no_grad()
def torch_frames(graph: FrameGraph, stream: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`run_frames` in torch: the same step module, frame after frame."""
    frames = _frames_of(stream, graph.hop)
    state = [torch.from_numpy(v) for v in initial_frame_state(graph, frames[:1]).values()]
    scores, decision, spikes = [], [], []
    for f in frames:
        s, d, sp, *state = graph(torch.from_numpy(np.ascontiguousarray(f[None])), *state)
        scores.append(s[0].numpy())
        decision.append(int(d[0]))
        spikes.append(sp[0].numpy())
    names = [n for n, _ in graph.state_names]
    return {"scores": np.asarray(scores), "decision": np.asarray(decision, np.int64),
            "spikes": np.asarray(spikes),
            "state": {n: v.numpy() for n, v in zip(names, state, strict=True)}}  # fmt: skip


#: test windows joined end to end into the recordings the export is checked on
CHECK_WINDOWS = 32
#: score tolerance (absolute, plus relative to the score range) of the frame-by-frame check
SCORE_ATOL, SCORE_RTOL = 1e-4, 1e-4


def compare_frames(got: dict, want: dict) -> dict:
    """Frame-by-frame agreement of two :func:`run_frames` results: frames whose spikes all
    agree, score differences on those frames up to the first disagreement (after a threshold
    flip on a rounding boundary, the two streams may part, legitimately), and the final state's
    difference relative to its size where no frame flipped."""
    same = (got["spikes"] == want["spikes"]).all(1)
    first = int(np.argmin(same)) if not same.all() else len(same)
    ds = np.abs(got["scores"][:first] - want["scores"][:first])
    return {"frames": len(same), "frames_before_first_flip": first,
            "spike_flips": int((got["spikes"] != want["spikes"]).sum()),
            "max_score_diff": float(ds.max()) if ds.size else 0.0,
            "decisions_agree": float((got["decision"] == want["decision"]).mean()),
            # each state's largest difference relative to its largest value (at least 1)
            "max_state_diff": (max(float(np.abs(got["state"][k] - want["state"][k]).max()
                                         / max(1.0, float(np.abs(want["state"][k]).max())))
                                   for k in want["state"]) if first == len(same) else None)}  # fmt: skip


def export_frames(
    pipe: SpikePipeline,
    out: Path,
    X_check: np.ndarray,
    metadata: dict[str, str] | None = None,
    overwrite: bool = False,
    exporter: str | None = None,
    gather: bool = False,
) -> dict:
    """Write the step graph of ``pipe`` to ``out`` after running up to ``CHECK_WINDOWS`` of
    ``X_check`` joined into one recording through it in onnxruntime and its torch module, frame
    by frame: every frame's spikes equal, scores within tolerance, the same decisions."""
    from .onnx import ExportError, check_out, pipeline_contract, save_atomic

    out = check_out(out, overwrite)
    model, graph = build_frame_graph(pipe, exporter, gather)
    names = [n for n, _ in graph.state_names]
    extra = {**dict(metadata or {}), "frame_step_samples": str(graph.hop),
             "frame_state_parts": json.dumps(graph.parts),
             "frame_state_init": json.dumps({"repeat_first": repeat_first_rule(graph)}),
             "frame_outputs": json.dumps([SCORES_OUTPUT, DECISION_OUTPUT, SPIKES_OUTPUT])}  # fmt: skip
    contract = pipeline_contract(pipe, tuple(names),
                                 f"input: the next {graph.hop} samples (one frame) in the sensor's "
                                 "readout units", extra)  # fmt: skip
    for k, v in contract.to_metadata().items():
        entry = model.metadata_props.add()
        entry.key, entry.value = k, str(v)
    onnx.checker.check_model(model)
    X = np.asarray(X_check, np.float32)[:CHECK_WINDOWS]
    stream = np.concatenate(list(X), axis=1)
    got = run_frames(frame_session(model), graph, stream)
    want = torch_frames(graph, stream)
    rep = compare_frames(got, want)
    span = float(np.ptp(want["scores"])) if want["scores"].size else 0.0
    if rep["frames_before_first_flip"] < rep["frames"] and rep["spike_flips"] > 2:
        raise ExportError(f"the frame graph's spikes differ from torch's on {rep['spike_flips']} "
                          f"(frame, afferent) pairs of {rep['frames']} frames")  # fmt: skip
    if rep["max_score_diff"] > SCORE_ATOL + SCORE_RTOL * span:
        raise ExportError(f"the frame graph's scores differ from torch's by up to "
                          f"{rep['max_score_diff']:.3g}")  # fmt: skip
    save_atomic(model, out)
    return {"path": str(out), "nodes": operator_nodes(model), "hop_samples": graph.hop,
            "frame_ms": 1000.0 * graph.hop / pipe.fs_hz, **rep}  # fmt: skip
