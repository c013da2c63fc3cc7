"""In-process inference on an exported pipeline: imports numpy and onnxruntime only.

:class:`PipelineSession` validates windows (shape, dtype, NaN/Inf, sampling rate) with specific
errors, runs the graph and returns class names, indices and scores. SNN graphs carry state: pass a
``stream`` (a :class:`StreamState`) to continue it across consecutive windows.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
import onnxruntime as ort

from ..core.checks import check_float32_range
from ..core.graph_contract import (
    EARLY_OUTPUTS,
    SCORES_OUTPUT,
    WINDOW_INPUT,
    ContractError,
    GraphContract,
    state_output,
)
from ..core.onnx_run import run_batched, session_threads


class InputError(ValueError):
    """The request's data is unusable (wrong shape, dtype, rate, NaN...): a client error."""


@dataclass
class StreamState:
    """Per-stream model state (graph state inputs by name) and the samples not yet in a window."""

    values: dict[str, np.ndarray] = field(default_factory=dict)
    buffer: np.ndarray | None = None
    windows_done: int = 0
    #: stream graphs (a step per call): steps fed so far, and the last window's samples but
    #: its last step (``[channels, window - step]``, once a window is complete)
    steps: int = 0
    recent: np.ndarray | None = None

    @property
    def h(self) -> np.ndarray | None:
        """The SNN hidden-layer membrane (``h_state``), if the model has one."""
        return self.values.get("h_state")


class Stats:
    """Counters of a session, updated from the service's worker threads (one lock)."""

    def __init__(self, **initial: float) -> None:
        self._lock = threading.Lock()
        self._values: dict[str, float] = dict(initial)

    def add(self, **deltas: float) -> None:
        with self._lock:
            for k, v in deltas.items():
                self._values[k] = self._values.get(k, 0) + v

    def mean(self, name: str, count: str, value: float) -> None:
        """Fold ``value`` into the running mean ``name`` over the counter ``count``
        (incremented here)."""
        with self._lock:
            n = self._values[count] = self._values.get(count, 0) + 1
            self._values[name] = (
                self._values.get(name, 0.0) + (value - self._values.get(name, 0.0)) / n
            )

    def snapshot(self) -> dict[str, float]:
        with self._lock:
            return dict(self._values)

    def __getitem__(self, name: str) -> float:
        with self._lock:
            return self._values[name]


class Detail(NamedTuple):
    """One graph run: scores ``[B, classes]``; the encoder's spike times ``[B, afferents, k]``
    (ms, inf = silent) when exposed; a model deciding early also gives the class of its first
    output neuron to fire ``[B]`` and when, ``decision_ms [B]`` (the duration if none fires)."""

    scores: np.ndarray
    spikes: np.ndarray | None = None
    early_class: np.ndarray | None = None
    decision_ms: np.ndarray | None = None


def _check_float32(arr: np.ndarray, name: str) -> None:
    """Finite values that overflow float32 (the graph's precision) are refused with the range."""
    try:
        check_float32_range(arr, name)
    except ValueError as e:
        raise InputError(str(e)) from e


def _with_spikes_output(path: str) -> bytes | str:
    """The model with its encoder's spike times (the value ``spikes`` that feeds the model part)
    also a graph output, so a live view can show the raster the model saw; without the ``onnx``
    package (a torch-free deployment may lack it) the graph as it is (the live page then shows
    no raster)."""
    try:
        import onnx  # only for the live view: plain inference needs onnxruntime alone
    except ImportError:
        return str(path)

    model = onnx.load(str(path))
    produced = {o for n in model.graph.node for o in n.output}
    if "spikes" in produced and all(o.name != "spikes" for o in model.graph.output):
        model.graph.output.append(
            onnx.helper.make_tensor_value_info("spikes", onnx.TensorProto.FLOAT, None)
        )
    return model.SerializeToString()


def pruned_graph(path: str, outputs: list[str]) -> bytes | None:
    """The graph at ``path`` cut down to the nodes that ``outputs`` need (serialised), or None
    when it needs them all or the ``onnx`` package is not installed.

    onnxruntime runs every node of a graph whatever outputs a call asks for (measured: a graph
    whose second output costs 10 ms took 10 ms when only its cheap first output was asked for),
    so plain classification runs its own copy without the early decision's nodes."""
    found = _plain_graph(path, outputs)
    return None if found is None else found[1]


def _plain_graph(path: str, outputs: list[str] | None = None) -> tuple[list[str], bytes] | None:
    """``(every output of the graph at path, the graph pruned to outputs)``, None when nothing
    would be pruned or ``onnx`` is not installed. ``outputs`` defaults to
    :func:`_plain_outputs` of the graph's state inputs (every input but the window)."""
    try:
        import onnx  # optional here: plain inference needs onnxruntime alone
    except ImportError:
        return None
    from ..core.onnx_prune import prune_to_outputs

    model = onnx.load(str(path))
    every = [o.name for o in model.graph.output]
    if outputs is None:
        states = [i.name for i in model.graph.input if i.name != WINDOW_INPUT]
        outputs = [SCORES_OUTPUT, *(state_output(n) for n in states)]
    if not prune_to_outputs(model.graph, outputs):
        return None
    return every, model.SerializeToString()


def _onnx_model(path: str):
    """The ONNX graph at ``path`` (``onnx.load``), None without the ``onnx`` package or when it
    cannot be read (the session's own load then reports what is wrong)."""
    try:
        import onnx
    except ImportError:
        return None
    try:
        return onnx.load(str(path))
    except Exception:  # protobuf raises its own types; the session's load says what is wrong
        return None


def _check_weights(path: str, model) -> None:
    """Refuse a graph whose weights hold NaN (it would give one answer for every input; +inf is
    a legitimate constant: a silent afferent's spike time). ``model``: the graph at ``path``
    (:func:`_onnx_model`); None (no ``onnx`` package) skips the check."""
    if model is None:
        return
    import onnx
    from onnx import numpy_helper

    for init in model.graph.initializer:
        if init.data_type in (onnx.TensorProto.FLOAT, onnx.TensorProto.DOUBLE,
                              onnx.TensorProto.FLOAT16):  # fmt: skip
            if np.isnan(numpy_helper.to_array(init)).any():
                raise ValueError(f"{path}: weight {init.name!r} holds NaN; refusing to serve it")


def _check_io(
    path: str, c: GraphContract, inputs: dict, outputs: set[str], step: int | None = None
) -> None:
    """The graph's inputs and outputs are those its metadata promises (a tampered or foreign
    graph is refused at load, not at the first request); ``step``: a stream graph's samples per
    call (its ``window`` input)."""
    window = inputs.get(WINDOW_INPUT)
    if window is None:
        raise ValueError(f"{path}: the graph has no {WINDOW_INPUT!r} input")
    dims = list(window.shape)
    want = [len(c.channels), c.window_samples if step is None else step]
    if len(dims) != 3 or any(
        isinstance(d, int) and d != w for d, w in zip(dims[1:], want, strict=True)
    ):
        raise ValueError(
            f"{path}: input {WINDOW_INPUT!r} is {dims}, metadata says [batch, {want[0]}, {want[1]}]"
        )
    states = set(inputs) - {WINDOW_INPUT}
    if states != set(c.state_inputs):
        raise ValueError(
            f"{path}: state inputs {sorted(states)} differ from the metadata's {list(c.state_inputs)}"
        )
    missing = [o for o in c.plain_outputs if o not in outputs]
    if missing:
        raise ValueError(f"{path}: the graph lacks the outputs {missing}")


@dataclass(frozen=True)
class StreamContract:
    """A stream graph's promise (metadata ``stream_step_samples``, ``stream_encoder_states``,
    ``stream_state_init``): its ``window`` input is the next ``step`` samples (dividing the
    window, at most half of it: a window ends every step); the encoder's state inputs are
    listed, and how a fresh stream starts each (``repeat_first``: every encoder channel's first
    sample repeated, channel-major; the others zeros)."""

    step: int
    encoder_states: tuple[str, ...]
    repeat_first: tuple[str, ...]

    @classmethod
    def parse(cls, path: str, c: GraphContract) -> StreamContract | None:
        import json

        if "stream_step_samples" not in c.extra:
            return None
        try:
            step = int(c.extra["stream_step_samples"], 10)
            enc = json.loads(c.extra.get("stream_encoder_states", "[]"))
            init = json.loads(c.extra.get("stream_state_init", "{}"))
        except (ValueError, RecursionError) as e:
            raise ValueError(f"{path}: unreadable stream metadata ({e})") from e
        if step < 1 or c.window_samples % step or 2 * step > c.window_samples:
            raise ValueError(f"{path}: stream step {step} does not divide the window "
                             f"{c.window_samples} at most twice over")  # fmt: skip
        if not (isinstance(enc, list) and isinstance(init, dict)
                and all(isinstance(n, str) and n in c.state_inputs for n in [*enc, *init])
                and set(init.values()) <= {"repeat_first"}):  # fmt: skip
            raise ValueError(f"{path}: stream state metadata names unknown states or rules")
        return cls(step, tuple(enc), tuple(init))

    def check_units(self, path: str, units: dict[str, int], channels: int) -> None:
        """Each ``repeat_first`` state splits evenly over the encoder's channels."""
        for name in self.repeat_first:
            if channels < 1 or units[name] % channels:
                raise ValueError(f"{path}: stream state {name!r} ({units[name]} units) does not "
                                 f"split over {channels} encoder channels")  # fmt: skip

    def initial(self, first: np.ndarray, channels: tuple[int, ...], units: dict[str, int]) -> dict:
        """The ``repeat_first`` states of fresh streams whose first steps are ``first``
        ``[B, channels, step]``."""
        out = {}
        x = first[:, list(channels), :1]  # [B, C, 1]
        for name in self.repeat_first:  # (check_units: whole per channel)
            per = units[name] // x.shape[1]
            out[name] = np.ascontiguousarray(
                np.repeat(x, per, axis=2).reshape(len(x), -1), np.float32
            )
        return out


@dataclass(frozen=True)
class FrameContract:
    """A one-frame step graph's promise (metadata ``frame_step_samples``, ``frame_state_init``;
    :mod:`tactilesnn.export.frames`): its ``window`` input is one frame of ``hop`` samples, its
    one state holds a stream's state, and a fresh stream starts from zeros with encoder channel
    ``c``'s first sample in ``state[offset + c stride : offset + c stride + length]``; outputs
    ``scores`` and ``decision`` (the leading class, or -1 while undecided) every frame."""

    hop: int
    state: str
    repeat_first: tuple[int, int, int]

    @classmethod
    def parse(cls, path: str, c: GraphContract) -> FrameContract | None:
        import json

        if "frame_step_samples" not in c.extra:
            return None
        try:
            hop = int(c.extra["frame_step_samples"], 10)
            rule = json.loads(c.extra.get("frame_state_init", "{}")).get("repeat_first")
        except (ValueError, AttributeError, RecursionError) as e:
            raise ValueError(f"{path}: unreadable frame metadata ({e})") from e
        if not 1 <= hop <= c.window_samples:
            raise ValueError(f"{path}: frame step {hop} is not within the window")
        if len(c.state_inputs) != 1 or not (isinstance(rule, list) and len(rule) == 3 and all(
                isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in rule)):  # fmt: skip
            raise ValueError(f"{path}: frame state metadata is not one state and one rule")
        return cls(hop, c.state_inputs[0], (rule[0], rule[1], rule[2]))

    def check_units(self, path: str, units: int, channels: int) -> None:
        offset, stride, length = self.repeat_first
        if length > stride or offset + max(channels - 1, 0) * stride + length > units:
            raise ValueError(f"{path}: the frame state's start rule does not fit its {units} units")

    def initial(self, first: np.ndarray, channels: tuple[int, ...], units: int) -> np.ndarray:
        """The state of fresh streams whose first frames are ``first [B, channels, hop]``."""
        offset, stride, length = self.repeat_first
        out = np.zeros((len(first), units), np.float32)
        for k, ch in enumerate(channels):
            start = offset + k * stride
            out[:, start : start + length] = first[:, ch, :1]
        return out


class PipelineSession:
    """onnxruntime session over an exported ``model.onnx`` with validation and metadata."""

    #: working memory of one onnxruntime call; larger batches are run in slices
    RUN_BUDGET_BYTES = 256 << 20

    def __init__(self, path: str, threads: int = 0, expose_spikes: bool = False) -> None:
        opts = ort.SessionOptions()
        if not Path(path).is_file():
            raise FileNotFoundError(f"model file {path} does not exist")
        # one thread for a graph with a reducing scatter (more would race: core.onnx_run)
        graph = _onnx_model(path)
        threads = session_threads(graph, threads)
        if threads:
            opts.intra_op_num_threads = threads
        self._opts, self._full, self._lock = opts, None, threading.Lock()
        try:
            self._source = _with_spikes_output(path) if expose_spikes else str(path)
            # plain classification (scores and state only) runs a copy of the graph without
            # the nodes only the early decision (or the exposed spikes) need, when there are
            # such nodes; the whole graph is loaded when a call first asks for those
            plain = None if expose_spikes else _plain_graph(path)
            if plain is None:
                self.plain_session = self.session
                outs = {o.name for o in self.session.get_outputs()}
            else:
                outs = set(plain[0])
                self.plain_session = ort.InferenceSession(
                    plain[1], opts, providers=["CPUExecutionProvider"]
                )
        except Exception as e:  # onnxruntime / protobuf raise their own types for unreadable graphs
            raise ValueError(f"{path} is not a loadable ONNX model ({e})") from e
        _check_weights(path, graph)
        del graph
        self.has_spikes = "spikes" in outs
        self.decides_early = set(EARLY_OUTPUTS) <= outs
        meta = self.plain_session.get_modelmeta().custom_metadata_map
        try:
            self.contract = c = GraphContract.from_metadata(meta)
        except ContractError as e:
            raise ValueError(f"{path} is not a usable tactilesnn export: {e}") from e
        self.fs_hz, self.window = c.fs_hz, c.window_samples
        self.channels, self.class_names = list(c.channels), list(c.class_names)
        self.metadata = dict(meta)
        # windows per onnxruntime call, so a large batch never needs more than the budget
        per_window = c.bytes_per_window
        self.batch = max(1, self.RUN_BUDGET_BYTES // per_window) if per_window > 0 else 1 << 30
        self.inputs = {i.name: i for i in self.plain_session.get_inputs()}
        self.stream = StreamContract.parse(path, c)
        self.frames = FrameContract.parse(path, c)
        if self.frames is not None and self.stream is not None:
            raise ValueError(f"{path}: a graph is a stream graph or a frame graph, not both")
        step = self.stream.step if self.stream is not None else None
        _check_io(path, c, self.inputs, outs, self.frames.hop if self.frames else step)
        # every graph input besides the window is streaming state, returned as "<name>_out"
        self.state_units = {k: int(v.shape[1]) for k, v in self.inputs.items() if k != WINDOW_INPUT}
        self.stateful = bool(self.state_units)
        if self.stream is not None:
            self.stream.check_units(path, self.state_units, len(c.encoder_channels))
        if self.frames is not None:
            self.frames.check_units(path, self.state_units[self.frames.state],
                                    len(c.encoder_channels))  # fmt: skip
        # activity gate of the encoder: the graph encodes only the channels above their RMS
        # threshold (the rest is silent); a window in which every channel is silent has the
        # same scores each time for a stateless model, so the stream path answers it from a
        # cache instead of running the graph
        self.gated = c.gate_rms is not None and bool(c.encoder_channels)
        self._silent: Detail | None = None
        self.stats = Stats(
            stream_windows=0,
            stream_windows_skipped=0,
            stream_channel_windows=0,  # (window, encoder channel) pairs seen by the gate
            stream_channel_windows_skipped=0,  # of which silent: not encoded
        )
        # band restriction: bands outside the sensor's passband are not transformed (static:
        # the graph holds only the others)
        if c.bands_hz is not None and c.bands_transformed is not None:
            n_bands = len(c.bands_hz)
            self.stats.add(encoder_bands=n_bands,
                           encoder_bands_skipped=n_bands - len(c.bands_transformed))  # fmt: skip
        if self.decides_early:  # the first output neuron to fire vs the full-window answer
            self.stats.add(stream_early_decisions=0, stream_early_differs=0,
                           stream_early_mean_decision_ms=0.0)  # fmt: skip
        self.plain_outputs = c.plain_outputs
        self._zeros: tuple[int, dict[str, np.ndarray]] | None = None

    @property
    def session(self) -> ort.InferenceSession:
        """The whole graph (early decision, exposed spikes), loaded on first use: a service
        that only classifies holds the pruned copy alone (one copy of the weights)."""
        with self._lock:
            if self._full is None:
                self._full = ort.InferenceSession(
                    self._source, self._opts, providers=["CPUExecutionProvider"]
                )
            return self._full

    def info(self) -> dict:
        return {
            "fs_hz": self.fs_hz,
            "window_samples": self.window,
            "channels": self.channels,
            "class_names": self.class_names,
            "stateful": self.stateful,
            "stats": self.stats.snapshot(),
            "metadata": self.metadata,
        }

    def validate(self, x: object, fs_hz: float | None = None) -> np.ndarray:
        """-> float32 ``[batch, channels, window]``; a single ``[channels, window]`` is batched."""
        if fs_hz is not None and not np.isfinite(float(fs_hz)):
            raise InputError(f"sampling rate must be a finite number of Hz, got {fs_hz}")
        if fs_hz is not None and abs(float(fs_hz) - self.fs_hz) > 1e-6 * self.fs_hz:
            raise InputError(f"sampling rate {fs_hz} Hz does not match the model's {self.fs_hz} Hz")
        try:
            arr = np.asarray(x)
        except Exception as e:  # ragged nested lists
            raise InputError(f"window is not a rectangular array: {e}") from e
        if arr.dtype == object or arr.dtype.kind not in "fiu":
            raise InputError(f"window must be numeric, got dtype {arr.dtype}")
        if arr.ndim == 2:
            arr = arr[None]
        want = (len(self.channels), self.window)
        if arr.ndim != 3 or arr.shape[1:] != want:
            raise InputError(
                f"window must be [{want[0]} channels, {want[1]} samples] or a batch of them, "
                f"got shape {list(arr.shape)}"
            )
        if arr.shape[0] == 0:
            raise InputError("empty batch")
        bad = ~np.isfinite(arr)
        if bad.any():
            b, c, s = (int(i) for i in np.argwhere(bad)[0])
            raise InputError(f"non-finite value at batch {b}, channel {c}, sample {s}")
        _check_float32(arr, "window")
        return np.ascontiguousarray(arr, dtype=np.float32)

    def run(self, x: np.ndarray, state: StreamState | None = None) -> np.ndarray:
        """Scores ``[batch, classes]`` for validated windows (updates ``state`` if given).

        Batches larger than the memory budget run in slices (same results, bounded memory).
        Only the scores (and state) are computed: this runs :attr:`plain_session`, the graph
        without the early decision's nodes (onnxruntime would run them for any output asked).
        """
        return self.run_detail(x, state, detail=False).scores

    def run_detail(
        self, x: np.ndarray, state: StreamState | None = None, detail: bool = True
    ) -> Detail:
        """:meth:`run`, plus (``detail``) the encoder's spike times when the session exposes
        them (``expose_spikes``) and the model's early decision when it makes one."""
        if len(x) == 0:  # onnxruntime's LSTM (the SNN) aborts the whole process on zero rows
            raise InputError("empty batch: no windows to classify")
        if self.stream is not None:
            return self._run_steps(x, state, detail)
        if self.frames is not None:
            return self._run_frames(x)
        names = list(self.state_units)
        feeds: dict[str, np.ndarray] = {}
        if names:
            held = state.values if state is not None else {}
            zeros = self._zero_state(len(x))
            feeds = {n: zeros[n] if held.get(n) is None else held[n] for n in names}
        out, new = self._call(x, feeds, detail)
        if state is not None and names:
            state.values = new
        return out

    def _feed_steps(self, state: StreamState, buf: np.ndarray, detail: bool) -> list[dict]:
        """The stream path of a stream graph: one call per step, every sample transformed once;
        the first step of a stream starts the encoder's state, and the calls before the first
        complete window carry the encoder's state only."""
        step, results = self.stream.step, []
        first_complete = self.window // step - 1
        while buf.shape[1] >= step:
            x = buf[None, :, :step]
            if state.steps == 0:
                state.values = self._started(x, dict(self._zero_state(1)))
            elif state.steps < first_complete:
                state.values = self._advanced(x, state.values)
            else:
                self.stats.add(stream_windows=1)
                out, state.values = self._call(x, state.values, detail)
                k = int(out.scores[0].argmax())
                res = {"window_index": state.windows_done, "class": self.class_names[k],
                       "scores": out.scores[0].tolist()}  # fmt: skip
                if out.decision_ms is not None:
                    res.update(self._early(k, int(out.early_class[0]), float(out.decision_ms[0])))
                if detail:
                    win = np.concatenate([state.recent, x[0]], axis=1)
                    res.update(window=win, spikes=None if out.spikes is None else out.spikes[0])
                results.append(res)
                state.windows_done += 1
            state.steps += 1
            kept = self.window - step  # the next window's samples before its last step
            past = x[0] if state.recent is None else np.concatenate([state.recent, x[0]], axis=1)
            state.recent = past[:, -kept:]
            buf = buf[:, step:]
        state.buffer = buf
        return results

    def _run_steps(self, x: np.ndarray, state: StreamState | None, detail: bool) -> Detail:
        """A stream graph on whole windows ``x``: the first step from a fresh encoder state,
        then the window's other steps (the scores of all but the last discarded: no window is
        complete before it); the model's state is the stream's (or zeros) and is updated by the
        last call only."""
        step = self.stream.step
        held = dict(state.values) if state is not None else {}
        zeros = self._zero_state(len(x))
        feeds = self._started(x[:, :, :step], {n: held.get(n, zeros[n]) for n in self.state_units})
        for start in range(step, self.window - step, step):
            feeds = self._advanced(x[:, :, start : start + step], feeds)
        out, new = self._call(x[:, :, self.window - step :], feeds, detail)
        if state is not None:
            state.values = new
        return out

    def _frame(
        self, x: np.ndarray, values: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One call of a frame graph: ``(scores, decision, next state)``."""
        name = self.frames.state
        scores, decision, new = run_batched(self.session, [SCORES_OUTPUT, "decision",
                                                           state_output(name)],
                                            {WINDOW_INPUT: x, name: values}, self.batch)  # fmt: skip
        return scores, decision, new

    def _run_frames(self, x: np.ndarray) -> Detail:
        """A frame graph on whole windows ``x``: every frame from a fresh stream's state (a
        window from rest); the scores at its last frame."""
        hop = self.frames.hop
        values = self.frames.initial(x[:, :, :hop], self.contract.encoder_channels,
                                     self.state_units[self.frames.state])  # fmt: skip
        scores = np.zeros((len(x), len(self.class_names)), np.float32)
        for start in range(0, self.window - hop + 1, hop):
            scores, _, values = self._frame(np.ascontiguousarray(x[:, :, start : start + hop]),
                                            values)  # fmt: skip
        return Detail(scores, None, None, None)

    def _feed_frames(self, state: StreamState, buf: np.ndarray, detail: bool) -> list[dict]:
        """The stream path of a frame graph: one call per frame, the state carried; a result
        every frame (its scores, its class, and its decision: a class name, or None while the
        model is undecided)."""
        hop, name, results = self.frames.hop, self.frames.state, []
        while buf.shape[1] >= hop:
            x = np.ascontiguousarray(buf[None, :, :hop])
            if state.steps == 0:
                state.values = {name: self.frames.initial(x, self.contract.encoder_channels,
                                                          self.state_units[name])}  # fmt: skip
            self.stats.add(stream_windows=1)
            scores, decision, state.values[name] = self._frame(x, state.values[name])
            k, d = int(scores[0].argmax()), int(decision[0])
            res = {"window_index": state.windows_done, "class": self.class_names[k],
                   "scores": scores[0].tolist(),
                   "decision": self.class_names[d] if 0 <= d < len(self.class_names) else None}  # fmt: skip
            past = x[0] if state.recent is None else np.concatenate([state.recent, x[0]], axis=1)
            state.recent = past[:, -self.window :]
            if detail:
                res.update(window=state.recent, spikes=None)
            results.append(res)
            state.windows_done += 1
            state.steps += 1
            buf = buf[:, hop:]
        state.buffer = buf
        return results

    def _advanced(self, x: np.ndarray, feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``feeds`` with the encoder's state after the step ``x`` (a call that completes no
        window: the model's state in ``feeds`` is kept)."""
        _, new = self._call(x, feeds, False)
        return {**feeds, **{n: v for n, v in new.items() if n in self.stream.encoder_states}}

    def _started(self, first: np.ndarray, feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``feeds`` with the encoder's state after fresh streams' first steps ``first`` (its
        ``repeat_first`` states set from them, then the step fed); the model's state in
        ``feeds`` is kept (that call completes no window)."""
        feeds = {**feeds, **self.stream.initial(first, self.contract.encoder_channels,
                                                self.state_units)}  # fmt: skip
        return self._advanced(first, feeds)

    def _call(
        self, x: np.ndarray, feeds: dict[str, np.ndarray], detail: bool
    ) -> tuple[Detail, dict[str, np.ndarray]]:
        """One graph call on ``x`` (a window, or a stream graph's half) with the state ``feeds``:
        its :class:`Detail` and every state's next value."""
        names = list(self.state_units)
        early = list(EARLY_OUTPUTS) if self.decides_early and detail else []
        spikes = ["spikes"] if self.has_spikes and detail else []
        outputs = [*self.plain_outputs, *early, *spikes] if early or spikes else self.plain_outputs
        sess = self.session if early or spikes else self.plain_session
        got = run_batched(sess, outputs, {WINDOW_INPUT: x, **feeds}, self.batch)
        scores, rest = got[0], got[1:]
        new, rest = rest[: len(names)], rest[len(names) :]
        cls, t = (rest[0], rest[1]) if early else (None, None)
        return Detail(scores, rest[-1] if spikes else None, cls, t), dict(
            zip(names, new, strict=True)
        )

    def _zero_state(self, batch: int) -> dict[str, np.ndarray]:
        """Zero streaming state for ``batch`` windows, kept for the last batch size (read-only:
        onnxruntime only reads its inputs; a call on one window is ~0.25 ms, two fresh arrays
        and their lists ~2 us of it)."""
        cached = self._zeros  # read once: service threads may replace it meanwhile
        if cached is None or cached[0] != batch:
            arrays = {k: np.zeros((batch, u), np.float32) for k, u in self.state_units.items()}
            for a in arrays.values():
                a.flags.writeable = False
            cached = self._zeros = (batch, arrays)
        return cached[1]

    def classify(self, x: object, fs_hz: float | None = None) -> dict:
        arr = self.validate(x, fs_hz)
        scores = self.run(arr)
        idx = scores.argmax(1)
        return {
            "classes": [self.class_names[i] for i in idx],
            "class_index": idx.tolist(),
            "scores": scores.tolist(),
        }

    def _silent_channels(self, win: np.ndarray) -> int:
        """How many of the window's encoder channels the gate silences (0 without a gate)."""
        if not self.gated:
            return 0
        silent = int(self.contract.silent_channels(win[0]).sum())
        self.stats.add(stream_channel_windows=len(self.contract.encoder_channels),
                       stream_channel_windows_skipped=silent)  # fmt: skip
        return silent

    def _run_gated(self, win: np.ndarray, state: StreamState) -> Detail:
        """One stream window: from the silent-window cache when the gate silences every channel
        of a stateless model (the result is identical), else through the graph (which encodes
        only the active channels)."""
        self.stats.add(stream_windows=1)
        silent = self._silent_channels(win)
        if not self.stateful and self.gated and silent == len(self.contract.encoder_channels):
            if self._silent is None:
                self._silent = self.run_detail(np.zeros_like(win))
            self.stats.add(stream_windows_skipped=1)
            return self._silent
        return self.run_detail(win, state if self.stateful else None)

    def _early(self, full: int, early: int, t_ms: float) -> dict:
        """A window's early decision, counted in :attr:`stats`."""
        self.stats.add(stream_early_differs=int(early != full))
        self.stats.mean("stream_early_mean_decision_ms", "stream_early_decisions", t_ms)
        return {"early_class": self.class_names[early], "decision_ms": t_ms}

    @property
    def window_step(self) -> int:
        """Samples between the starts of the windows a stream is classified in: a stream
        graph's step, a frame graph's frame, else half a window."""
        if self.frames is not None:
            return self.frames.hop
        return self.window // 2 if self.stream is None else self.stream.step

    def feed_stream(
        self, state: StreamState, chunk: object, hop: int | None = None, detail: bool = False
    ) -> list[dict]:
        """Append ``[channels, n]`` samples; classify every complete window (hop: the stream
        graph's step, else ``window / 2``).

        SNN state is carried from window to window; returns one result per completed window
        (with ``detail``, also its ``"window"`` array and ``"spikes"``, for the live view).
        """
        hop = hop or self.window_step
        try:
            arr = np.asarray(chunk)
        except (TypeError, ValueError) as e:
            raise InputError(f"chunk is not a numeric array: {e}") from e
        if arr.dtype == object or arr.dtype.kind not in "fiu":
            raise InputError(f"chunk must be numeric, got dtype {arr.dtype}")
        if arr.ndim != 2 or arr.shape[0] != len(self.channels):
            raise InputError(
                f"chunk must be [{len(self.channels)} channels, samples], got {list(arr.shape)}"
            )
        if not np.isfinite(arr).all():
            c, s = (int(i) for i in np.argwhere(~np.isfinite(arr))[0])
            raise InputError(f"non-finite value at channel {c}, sample {s}")
        _check_float32(arr, "chunk")
        arr = arr.astype(np.float32)
        buf = arr if state.buffer is None else np.concatenate([state.buffer, arr], axis=1)
        if self.frames is not None:
            if hop != self.frames.hop:
                raise InputError(f"this frame graph classifies every frame of {self.frames.hop} "
                                 f"samples, not every {hop}")  # fmt: skip
            return self._feed_frames(state, buf, detail)
        if self.stream is not None:
            if hop != self.stream.step:
                raise InputError(f"this stream graph classifies a window every {self.stream.step} "
                                 f"samples (its step), not every {hop}")  # fmt: skip
            return self._feed_steps(state, buf, detail)
        results = []
        while buf.shape[1] >= self.window:
            win = buf[None, :, : self.window]
            out = self._run_gated(win, state)
            k = int(out.scores[0].argmax())
            res = {
                "window_index": state.windows_done,
                "class": self.class_names[k],
                "scores": out.scores[0].tolist(),
            }
            if out.decision_ms is not None:
                res.update(self._early(k, int(out.early_class[0]), float(out.decision_ms[0])))
            if detail:
                res.update(window=win[0], spikes=None if out.spikes is None else out.spikes[0])
            results.append(res)
            state.windows_done += 1
            buf = buf[:, hop:]
        state.buffer = buf
        return results
