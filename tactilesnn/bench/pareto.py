"""Run time against error, end to end (raw window -> class): ``tactilesnn bench pareto``.

Each point is a pipeline configuration (encoder, bands, model, model size, time step) trained on
the task's training split, then run at several precisions: torch float32 (the training path),
torch with a float64 encoder, onnxruntime float32 (the exported graph, verified against torch)
and onnxruntime dynamic int8. For each (configuration, precision):

* test error with its 95 % interval (Wilson-free normal interval on the test windows);
* compute per second of signal: one window every ``window / 2`` samples (the service's stream
  hop), measured with 1 thread at batch 1 (latency) and batch 64 (throughput): every
  configuration is trained and exported first, then all are timed in 3 interleaved rounds of
  ``repeats`` calls (median of the round medians, :func:`time_rows`); the real-time factor is
  1 s divided by that;
* the encoder's error against its float64 run (max spike-time difference in ms where both spike,
  and the number of slots that spike in one only);
* model size (ONNX bytes; torch parameter bytes for the torch rows).

Points on the Pareto front (no other point has both lower error and lower batch-1 cost) are
marked. Writes ``pareto.json``, ``pareto.md`` and ``pareto.png`` (error vs cost, log axes).
"""

from __future__ import annotations

import argparse
import copy
import gc
import json
import logging
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..app.plots import pareto_front
from ..app.plots import plot_cost_error as plot
from ..app.runs import RunWriter
from ..config import PipelineConfig
from ..core.settings import flag_fields
from ..core.spikes import clock_times
from ..datasets_synth import TASKS, get_task
from ..encoders import ENCODERS
from ..pipeline import SpikePipeline, accuracy_ci95
from ..training import fit_and_evaluate

log = logging.getLogger("tactilesnn")


@dataclass(frozen=True)
class Point:
    """One configuration: a label and the flat pipeline settings it changes."""

    label: str
    settings: dict = field(default_factory=dict)


#: the default task's sweep (10 epochs each: the ranking, not the last tenth of a point)
FULL = (
    Point("gwt20+tempotron (default)", {}),
    Point("gwt10+tempotron", {"n_bands": 10}),
    Point("gwt40+tempotron", {"n_bands": 40}),
    Point("gwt20 mean+tempotron", {"stats": ("mean",)}),
    Point("gwt20 hop4+tempotron", {"gwt_hop": 4}),
    Point("gwt20 hop10+tempotron", {"gwt_hop": 10}),
    Point("stft20+tempotron", {"encoder": "stft"}),
    Point("gwt20+readout", {"model": "readout"}),
    Point("gwt20+snn16 dt10", {"model": "snn", "snn_hidden": 16, "snn_dt_ms": 10.0}),
    Point("gwt20+snn64 dt5", {"model": "snn", "snn_hidden": 64}),
    Point("lif+readout", {"encoder": "lif", "model": "readout"}),
    # the causal (streamable) Gabor bank with the same code
    Point("cgwt20+tempotron", {"encoder": "cgwt"}),
    Point("cgwt20+readout", {"encoder": "cgwt", "model": "readout"}),
    # 20 frames per window (the default task's 100-sample windows): the real-time rows' fastest
    Point(
        "cgwt20 hop5+snn16 dt10",
        {"encoder": "cgwt", "cgwt_hop": 5, "model": "snn", "snn_hidden": 16, "snn_dt_ms": 10.0},
    ),
    Point(
        "cgwt20 hop5+snn64 dt10",
        {"encoder": "cgwt", "cgwt_hop": 5, "model": "snn", "snn_dt_ms": 10.0},
    ),
    # the continuous code and the stream model (scored here as windows, from rest)
    Point("frames+stream", {"encoder": "frames", "model": "stream"}),
)
QUICK = (Point("gwt10 hop5+tempotron", {"n_bands": 10, "gwt_hop": 5}), Point("stft10+readout",
         {"encoder": "stft", "n_bands": 10, "model": "readout"}))  # fmt: skip
QUICK_TASK = {"n_planar": 12, "n_concave": 6, "n_convex": 6, "n_test": 6}


def _median_s(fn, repeats: int) -> float:
    fn()  # warm-up (allocations, onnxruntime's first run)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def encode_float64(pipe: SpikePipeline, X: np.ndarray, batch: int = 128) -> torch.Tensor:
    """``pipe.encode`` with a float64 copy of its encoder (clock afferents appended alike)."""
    enc64 = copy.deepcopy(pipe.encoder).double()
    x = pipe.encoder_input(X)
    with torch.no_grad():
        parts = [enc64.encode_batch(torch.from_numpy(np.asarray(x[i : i + batch], np.float64)))
                 for i in range(0, len(x), batch)]  # fmt: skip
    s = torch.cat(parts).double()
    if pipe.n_clock:
        clock = clock_times(pipe.n_clock, pipe.max_spikes, pipe.duration_ms).double()
        s = torch.cat([s, clock.expand(s.shape[0], -1, -1)], dim=1)
    return s


def encoder_error(s32: torch.Tensor, s64: torch.Tensor) -> tuple[float, int]:
    """(max |t32 - t64| ms where both spike, slots spiking in only one)."""
    t32, t64 = s32.double().numpy(), s64.numpy()
    both = np.isfinite(t32) & np.isfinite(t64)
    dt = float(np.abs(t32[both] - t64[both]).max()) if both.any() else 0.0
    return dt, int((np.isfinite(t32) != np.isfinite(t64)).sum())


def _windows_per_s(pipe: SpikePipeline) -> float:
    """Windows classified per second of signal: one every half window (the stream's hop)."""
    return pipe.fs_hz / max(1, pipe.window // 2)


def _cost_ms_per_s(seconds_per_window: float, windows_per_s: float) -> float:
    """Compute (ms) per second of signal."""
    return 1000.0 * seconds_per_window * windows_per_s


def _interleaved_medians(
    calls: list[Callable[[], object]], repeats: int, rounds: int
) -> list[float]:
    """Each call's time (s): ``rounds`` rounds over all calls, each a median of ``repeats``
    calls, then the median over rounds, so a burst of load on a noisy machine falls on every
    call alike instead of on one."""
    times: list[list[float]] = [[] for _ in calls]
    for _ in range(rounds):
        for call, ts in zip(calls, times, strict=True):
            ts.append(_median_s(call, repeats))
    return [statistics.median(ts) for ts in times]


#: a row of :func:`prepare_point` with the calls to time: ``(row, {"t1": call on 1 window,
#: "t64": call on up to 64 windows, "n64": that batch's size, "windows_per_s": windows per
#: second of signal} or None)``
Prepared = tuple[dict, dict | None]


def prepare_point(pipe: SpikePipeline, test, tmp: Path) -> list[Prepared]:
    """The precision rows of one trained pipeline (see the module docstring), untimed, each with
    the calls :func:`time_rows` times; its graphs are written into the empty folder ``tmp``."""
    from ..export import export_pipeline, quantize_int8
    from ..service.runtime import PipelineSession

    X, y = test.X, test.y
    x1, x64 = X[:1], X[: min(64, len(X))]
    out: list[Prepared] = []
    spikes = pipe.encode(X)
    pred = pipe.scores(spikes).argmax(1).numpy()
    params = sum(v.size * v.itemsize for v in pipe.weights().values())
    s64 = encode_float64(pipe, X)
    enc_dt, enc_flips = encoder_error(spikes, s64)
    calls = {"t1": lambda: pipe.scores(pipe.encode(x1)),
             "t64": lambda: pipe.scores(pipe.encode(x64)), "n64": len(x64),
             "windows_per_s": _windows_per_s(pipe)}  # fmt: skip
    out.append((_row("torch float32", pred, y, params, enc_dt, enc_flips), calls))
    # the float64 encoder the float32 code is judged against, same model: is the rounding costly?
    pred64 = pipe.scores(s64.float()).argmax(1).numpy()
    out.append((_row("torch, float64 encoder", pred64, y, params, 0.0, 0), None))
    # onnxruntime float32 and int8 (1 intra-op thread)
    path = tmp / "m.onnx"
    export_pipeline(pipe, path, X[: min(256, len(X))])
    for name, file in (("onnxruntime float32", path), ("onnxruntime int8", None)):
        if file is None:
            file = Path(quantize_int8(path, X[:64], y[:64])["path"])
        full = PipelineSession(str(file), threads=1)
        got = full.run(full.validate(X)).argmax(1)
        # timed on a session that never ran the whole split: onnxruntime keeps a session's
        # arena at its largest call, and every row's session stays open until timing ends
        # (peak RSS of the sweep: 2.7 GB when the split's session was kept, 1.3 GB with this)
        del full
        sess = PipelineSession(str(file), threads=1)
        calls = {"t1": lambda s=sess: s.run(x1), "t64": lambda s=sess: s.run(x64),
                 "n64": len(x64), "windows_per_s": _windows_per_s(pipe)}  # fmt: skip
        row = _row(name, got, y, file.stat().st_size, enc_dt, enc_flips)
        out.append((row, calls))
    return out


def time_rows(prepared: list[Prepared], repeats: int, rounds: int = 3) -> list[dict]:
    """Time every prepared row with 1 thread at batch 1 and at batch 64, all rows interleaved
    (:func:`_interleaved_medians`); fills the cost fields of each row and returns the rows."""
    timed = [(r, c) for r, c in prepared if c is not None]
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        secs = _interleaved_medians([c[k] for _, c in timed for k in ("t1", "t64")], repeats,
                                    rounds)  # fmt: skip
    finally:
        torch.set_num_threads(threads)
    for (row, calls), t1, t64n in zip(timed, secs[0::2], secs[1::2], strict=True):
        t64 = t64n / calls["n64"]
        cost1 = _cost_ms_per_s(t1, calls["windows_per_s"])
        row.update(ms_per_window_batch1=1000 * t1, ms_per_window_batch64=1000 * t64,
                   ms_per_signal_s_batch1=cost1,
                   ms_per_signal_s_batch64=_cost_ms_per_s(t64, calls["windows_per_s"]),
                   realtime_factor_batch1=1000.0 / cost1)  # fmt: skip
    return [r for r, _ in prepared]


def _row(precision, pred, y, size, enc_dt, enc_flips) -> dict:
    acc = float((np.asarray(pred) == np.asarray(y)).mean())
    return {
        "precision": precision,
        "test_error": 1.0 - acc,
        "test_error_ci95": accuracy_ci95(acc, len(y)),
        "ms_per_window_batch1": None,
        "ms_per_window_batch64": None,
        "ms_per_signal_s_batch1": None,
        "ms_per_signal_s_batch64": None,
        "realtime_factor_batch1": None,
        "encoder_max_time_err_ms": enc_dt,
        "encoder_flipped_slots": enc_flips,
        "size_bytes": int(size),
    }


def realtime_session(
    tmp: Path,
    window: int = 1000,
    hop: int = 1,
    touched: int | None = None,
    int8: bool = False,
    snn: tuple[int, float] = (64, 5.0),
    form: str = "gwt",
) -> tuple[Callable[[], object], dict]:
    """One real-time row's call and description: a scalogram encoder + SNN on 12 taxels at
    2 kHz, onnxruntime, 1 thread, batch 1, classifying a window every half window (random
    weights: cost does not depend on them); ``hop``: the scalogram's frame hop. ``form``:
    ``gwt`` (the window graph of the FFT-exact Gabor scalogram), ``cgwt`` (the window graph of
    the causal Gabor bank), ``cgwt stream`` (its stream graph: each call takes the next half
    window and the state, every sample transformed once; scores and state asked for), the same
    graph asked for its early decision too (``cgwt stream decision``: the service's stream
    path), that graph's encoder or model part alone (``cgwt stream encoder`` / ``cgwt stream
    model``: :func:`_stream_call`), its heavy operators alone (``cgwt stream heavy``:
    :func:`heavy_operators`, the floor), or the stream graph stepping one frame per call, every
    output asked for (``cgwt stream frame``: a window ending every hop, latency one frame). With
    ``touched`` (window graphs, ``gwt`` or ``cgwt``), the activity gate is on (0.5 x the training RMS)
    and only that many taxels carry signal (the others 1 % of it): the graph encodes only the
    touched ones. ``int8``: the
    graph's window-side MatMuls dynamically quantised (:func:`quantize_int8`; the Convs and the
    LSTM stay float32). ``snn``: its hidden units and time step (ms)."""
    from ..export import export_pipeline, quantize_int8
    from ..service.runtime import PipelineSession

    fs, channels = 2000.0, tuple(f"taxel{i}" for i in range(12))
    if form in _FRAME_FORMS:  # the continuous code + stream model, hop ~5 ms
        cfg = PipelineConfig.from_flat(encoder="frames", model="stream", channels=("all",),
                                       f_lo_hz=5.0, f_hi_hz=800.0, stream_hidden=snn[0],
                                       frame_ms=1000.0 * hop / fs)  # fmt: skip
        pipe = SpikePipeline(cfg, fs, window, channels, ("a", "b"))
        X = np.random.default_rng(0).standard_normal((8, 12, window)).astype(np.float32)
        pipe.calibrate(X)
        return _frame_call(pipe, X, form, {"form": form, "window_samples": window, "gwt_hop": hop,
                                           "touched_taxels": None, "precision": "float32",
                                           "snn_hidden": snn[0], "snn_dt_ms": 1000.0 * hop / fs,
                                           "step_samples": hop, "windows_per_s": fs / hop})  # fmt: skip
    enc = form.split()[0]
    hop_key = {f: k for k, f in flag_fields(ENCODERS.config_class(enc)).items()}["hop"]
    cfg = PipelineConfig.from_flat(encoder=enc, model="snn", channels=("all",), f_hi_hz=800.0,
                                   f_lo_hz=5.0, gate=0.0 if touched is None else 0.5,
                                   snn_hidden=snn[0], snn_dt_ms=snn[1], **{hop_key: hop})  # fmt: skip
    pipe = SpikePipeline(cfg, fs, window, channels, ("a", "b"))
    rng = np.random.default_rng(0)
    X = rng.standard_normal((8, 12, window)).astype(np.float32)
    pipe.calibrate(X)
    step = hop if form == _SF else window // 2  # a window ends every step samples
    info = {"form": form, "window_samples": window, "gwt_hop": hop, "touched_taxels": touched,
            "precision": "int8" if int8 else "float32", "snn_hidden": snn[0],
            "snn_dt_ms": snn[1], "step_samples": step,
            "windows_per_s": fs / step}  # fmt: skip
    if form.startswith(_S):
        return _stream_call(pipe, X, form, step), info
    path = tmp / f"rt{form.replace(' ', '_')}{hop}_{touched}_{int(int8)}_{snn[0]}_{snn[1]:g}.onnx"
    export_pipeline(pipe, path, X)
    if int8:
        path = Path(quantize_int8(path, X, np.arange(len(X)) % 2)["path"])
    sess = PipelineSession(str(path), threads=1)
    x = X[:1].copy()
    if touched is not None:
        x[:, touched:] *= 0.01
    return (lambda: sess.run(x)), info


def _stream_call(
    pipe: SpikePipeline, X: np.ndarray, form: str, step: int | None = None
) -> Callable[[], object]:
    """A stream-graph row's call: the whole graph (``cgwt stream``: the next ``step`` samples,
    default half a window, and the state in, scores and state out), its encoder part alone
    (``... encoder``: up to the window's spikes and the encoder's next state), its model part
    alone (``... model``: one window's spikes and the model's state in), the whole graph asked
    for every output (``... decision`` and ``... frame``: the early decision too, as the
    service's stream path asks), or the floor (``... heavy``: the whole graph's
    :func:`heavy_operators` alone)."""
    import onnx
    import onnxruntime as ort

    from ..core.onnx_prune import prune_to_outputs
    from ..export.onnx import build_model_part
    from ..export.stream_graph import build_stream_graph, initial_state, stream_session

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    if form == _SM:
        model = build_model_part(pipe)
        sess = ort.InferenceSession(model.SerializeToString(), opts,
                                    providers=["CPUExecutionProvider"])  # fmt: skip
        feeds = {"spikes_in": pipe.encode(X[:1]).numpy().astype(np.float32)}
    else:
        step = pipe.window // 2 if step is None else step
        graph, names, _ = build_stream_graph(pipe, step=step)
        if form == _SE:  # the spikes and the encoder's next state only
            graph = onnx.ModelProto.FromString(graph.SerializeToString())
            keep = ["spikes", *(f"{n}_out" for n, _ in names)]
            graph.graph.output.append(onnx.helper.make_tensor_value_info("spikes", 1, None))
            prune_to_outputs(graph.graph, keep)
            sess = ort.InferenceSession(graph.SerializeToString(), opts,
                                        providers=["CPUExecutionProvider"])  # fmt: skip
        elif form in (_SD, _SF):  # every output: the service's stream path asks for them
            sess = ort.InferenceSession(graph.SerializeToString(), opts,
                                        providers=["CPUExecutionProvider"])  # fmt: skip
        else:
            sess = stream_session(graph)
        feeds = {"window": X[:1, :, :step].copy(), **initial_state(pipe, X[:1, :, :step], step)}
    feeds = {k: v for k, v in feeds.items() if k in {i.name for i in sess.get_inputs()}}
    for i in sess.get_inputs():
        feeds.setdefault(i.name, np.zeros((1, int(i.shape[1])), np.float32))
    if form == _SH:
        heavy, feeds = heavy_operators(graph, feeds)
        sess = ort.InferenceSession(heavy.SerializeToString(), opts,
                                    providers=["CPUExecutionProvider"])  # fmt: skip
    outs = [o.name for o in sess.get_outputs()]
    return lambda: sess.run(outs, feeds)


def _frame_call(pipe: SpikePipeline, X: np.ndarray, form: str, info: dict
                ) -> tuple[Callable[[], object], dict]:  # fmt: skip
    """A one-frame step graph's call (:mod:`~tactilesnn.export.frames`: one hop of samples and
    the state in, the frame's scores, decision and next state out; random weights): ``frames
    step`` (batch 1: one stream, latency one frame), ``... gather`` (the input layer as a
    gather of the weight rows of the afferents that fired), ``... 100 streams`` (a skin of
    100 such 12-taxel streams in one call per frame: the real-time factor per stream), or the
    floor (``ort call floor``: a graph of one ``Identity`` node with one input and one output,
    what any call from Python costs); ``... bound``: the step graph or the floor through
    buffers bound once (:class:`~tactilesnn.export.frames.BoundFrames`: the frame copied in,
    the state written where the next call reads it)."""
    import onnx
    import onnxruntime as ort

    from ..core.graph_contract import WINDOW_INPUT
    from ..export.frames import (
        STATE,
        BoundFrames,
        build_frame_graph,
        frame_session,
        initial_frame_state,
    )

    streams = FRAME_STREAMS if form == _FB else 1
    hop = info["step_samples"]
    x = np.ascontiguousarray(np.repeat(X[:1, :, :hop], streams, 0))
    if form in (_FLOOR, _FLOORB):
        h = onnx.helper
        v_in = h.make_tensor_value_info(WINDOW_INPUT, onnx.TensorProto.FLOAT, [1, 12, hop])
        v_out = h.make_tensor_value_info("scores", onnx.TensorProto.FLOAT, [1, 12, hop])
        model = h.make_model(h.make_graph([h.make_node("Identity", [WINDOW_INPUT], ["scores"])],
                                          "floor", [v_in], [v_out]),
                             opset_imports=[h.make_opsetid("", 17)])  # fmt: skip
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        sess = ort.InferenceSession(model.SerializeToString(), opts,
                                    providers=["CPUExecutionProvider"])  # fmt: skip
        if form == _FLOORB:
            bind = sess.io_binding()
            bind.bind_ortvalue_input(WINDOW_INPUT, ort.OrtValue.ortvalue_from_numpy(x))
            bind.bind_ortvalue_output("scores", ort.OrtValue.ortvalue_from_numpy(x.copy()))
            return (lambda: sess.run_with_iobinding(bind)), {**info, "streams": 1}
        return (lambda: sess.run(["scores"], {WINDOW_INPUT: x})), {**info, "streams": 1}
    model, graph = build_frame_graph(pipe, gather=form == _FG)
    sess = frame_session(model)
    info = {**info, "streams": streams, "nodes": len(model.graph.node)}
    if form == _FBOUND:
        bound = BoundFrames(sess, graph, x)
        bound.step(x)
        return bound.step, info  # the frame already bound: the call alone, as the floor's
    feeds = {WINDOW_INPUT: x, **initial_frame_state(graph, x)}
    outs = ["scores", "decision", f"{STATE}_out"]  # what a stream's runtime reads
    return (lambda: sess.run(outs, feeds)), info


#: an operator doing at least this many multiply-adds per call counts as heavy
HEAVY_MACS = 100_000


def heavy_operators(
    model, feeds: dict[str, np.ndarray], min_macs: int = HEAVY_MACS
) -> tuple[object, dict[str, np.ndarray]]:
    """The floor of a graph's cost: its ``Conv``, ``MatMul`` / ``Gemm`` and ``LSTM`` nodes that
    do at least ``min_macs`` multiply-adds on ``feeds``, alone in one graph (each node's inputs
    as graph inputs, with the values the whole graph computes for them on ``feeds``, returned
    as the new graph's feeds). No exact rewrite of the rest of the graph can make a call
    cheaper than this graph's call."""
    import onnx
    import onnxruntime as ort

    kinds = {"Conv", "MatMul", "Gemm", "LSTM"}
    inits = {i.name: i for i in model.graph.initializer}
    nodes = [n for n in model.graph.node if n.op_type in kinds]
    wanted = sorted({v for n in nodes for v in (*n.input, *n.output) if v and v not in inits})
    probe = onnx.ModelProto()
    probe.CopyFrom(model)
    have = {o.name for o in probe.graph.output} | {i.name for i in probe.graph.input}
    probe.graph.output.extend(onnx.ValueInfoProto(name=v) for v in wanted if v not in have)
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    sess = ort.InferenceSession(probe.SerializeToString(), opts,
                                providers=["CPUExecutionProvider"])  # fmt: skip
    names = [o.name for o in sess.get_outputs()]
    values = {**feeds, **dict(zip(names, sess.run(names, feeds), strict=True))}
    for i in inits.values():
        values[i.name] = onnx.numpy_helper.to_array(i)

    def macs(n) -> int:
        out = values[n.output[0]]
        if n.op_type == "LSTM":  # seq x batch x 4H gates, each over input + hidden
            x, w = values[n.input[0]], values[n.input[1]]
            hidden = w.shape[1] // 4
            return int(x.shape[0] * x.shape[1] * w.shape[1] * (w.shape[2] + hidden))
        if n.op_type == "Conv":  # each output: in-channels per group x kernel
            w = values[n.input[1]]
            return int(out.size * np.prod(w.shape[1:]))
        return int(out.size * values[n.input[0]].shape[-1])

    def info(v: str):
        dtype = onnx.helper.np_dtype_to_tensor_dtype(values[v].dtype)
        return onnx.helper.make_tensor_value_info(v, dtype, values[v].shape)

    keep = [n for n in nodes if macs(n) >= min_macs]
    graph = onnx.helper.make_graph(
        keep, "heavy_operators",
        [info(v) for v in dict.fromkeys(i for n in keep for i in n.input if i and i not in inits)],
        [info(o) for n in keep for o in n.output if o],
        [inits[i] for i in dict.fromkeys(i for n in keep for i in n.input) if i in inits],
    )  # fmt: skip
    heavy = onnx.helper.make_model(graph, opset_imports=model.opset_import)
    heavy.ir_version = model.ir_version
    fed = {i.name: np.ascontiguousarray(values[i.name]) for i in graph.input}
    return heavy, fed


def realtime_rows(
    rows: tuple[tuple[int, int | None, bool, tuple[int, float], str], ...],
    repeats: int,
    tmp: Path,
    window: int = 1000,
    rounds: int = 5,
) -> list[dict]:
    """The real-time factor of each row of :data:`RT_ROWS` (``(hop, touched, int8, snn,
    form)``): every row's session is built first, then all are timed interleaved
    (:func:`_interleaved_medians`)."""
    built = [realtime_session(tmp, window, hop=h, touched=k, int8=q, snn=n, form=f)
             for h, k, q, n, f in rows]  # fmt: skip
    secs = _interleaved_medians([call for call, _ in built], repeats, rounds)
    out = []
    for (_, info), t in zip(built, secs, strict=True):
        # per stream: a call of several streams serves each of them
        cost = _cost_ms_per_s(t, info.pop("windows_per_s")) / info.get("streams", 1)
        out.append({**info, "ms_per_window": 1000 * t, "ms_per_signal_s": cost,
                    "realtime_factor": 1000.0 / cost})  # fmt: skip
    return out


#: the SNN of the default task's Pareto sweep that costs least (``gwt20+snn16 dt10``)
SMALL_SNN = (16, 10.0)
#: the real-time rows: (GWT hop, touched taxels with the activity gate on (None = gate off),
#: int8 MatMuls, SNN (hidden units, step ms), form (see :func:`realtime_session`))
_G, _C, _S = "gwt", "cgwt", "cgwt stream"
#: the stream graph's two parts timed alone (where its time goes, in the same run)
_SE, _SM = "cgwt stream encoder", "cgwt stream model"
#: the floor: the stream graph's heavy operators alone (:func:`heavy_operators`); the stream
#: graph with its early decision as well (what the service's stream path runs)
_SH, _SD = "cgwt stream heavy", "cgwt stream decision"
#: the stream graph stepping one frame (one hop) per call, asked for every output as the
#: service's stream path: a window's spikes and early decision every frame (latency one frame)
_SF = "cgwt stream frame"
#: the continuous code + stream model's one-frame step graph (:mod:`~tactilesnn.export.frames`):
#: one stream per call, its input layer as a gather, a skin of FRAME_STREAMS streams per call,
#: and the floor of any call (one Identity node)
_F, _FG, _FB, _FLOOR = "frames step", "frames step gather", "frames step streams", "ort call floor"
#: the step graph and the floor called through buffers bound once (IOBinding: no conversion or
#: allocation of feeds and outputs per call; :class:`~tactilesnn.export.frames.BoundFrames`)
_FBOUND, _FLOORB = "frames step bound", "ort call floor bound"
_FRAME_FORMS = (_F, _FG, _FB, _FLOOR, _FBOUND, _FLOORB)
FRAME_STREAMS = 100
RT_ROWS = ((1, None, False, (64, 5.0), _G), (10, None, False, (64, 5.0), _G),
           (10, None, True, (64, 5.0), _G), (10, 6, False, (64, 5.0), _G),
           (10, 3, False, (64, 5.0), _G), (10, 1, False, (64, 5.0), _G),
           (10, 1, True, (64, 5.0), _G), (10, None, True, SMALL_SNN, _G), (10, 1, True, SMALL_SNN, _G),
           (10, None, False, (64, 5.0), _C), (10, None, False, (64, 5.0), _S),
           (10, None, False, (64, 5.0), _SD),
           (10, None, False, (64, 5.0), _SE), (10, None, False, (64, 5.0), _SM),
           (10, None, False, (64, 5.0), _SH),
           (10, None, False, SMALL_SNN, _S), (10, None, False, SMALL_SNN, _SM),
           (10, None, False, SMALL_SNN, _SH),
           # 20 frames per window: the sweep's "cgwt20 hop5+snn16 dt10" at 2 kHz
           (50, None, False, (64, 5.0), _S), (50, None, False, SMALL_SNN, _S),
           (50, None, False, SMALL_SNN, _SD), (50, None, False, (64, 10.0), _S),
           (50, None, False, SMALL_SNN, _SH), (50, 1, False, SMALL_SNN, _C),
           # one frame per call: latency one frame (5 ms at hop 10, 25 ms at hop 50)
           (10, None, False, (64, 5.0), _SF), (50, None, False, SMALL_SNN, _SF),
           # the continuous stream model stepping one 5 ms frame per call (latency one frame)
           (10, None, False, (64, 5.0), _F), (10, None, False, (64, 5.0), _FG),
           (10, None, False, (64, 5.0), _FB), (10, None, False, (64, 5.0), _FLOOR),
           (10, None, False, (64, 5.0), _FBOUND), (10, None, False, (64, 5.0), _FLOORB))  # fmt: skip


def run(out: Path, task: str = "hook_loop", quick: bool = False, repeats: int = 15,
        epochs: int = 10, overwrite: bool = False, progress: bool = True) -> dict:  # fmt: skip
    from tqdm.auto import tqdm

    writer = RunWriter(Path(out), overwrite=overwrite)
    try:
        points = QUICK if quick else FULL
        kw = QUICK_TASK if quick and task == "hook_loop" else {}
        train, test = get_task(task, **kw).build()
        prepared: list[Prepared] = []
        threads = torch.get_num_threads()
        with tempfile.TemporaryDirectory() as tmp:
            for p in tqdm(points, desc="bench pareto", unit="config", disable=not progress):
                torch.set_num_threads(threads)  # training at full speed, timing on 1 thread
                flat = {"epochs": 1 if quick else epochs, **p.settings}
                if task != "hook_loop":
                    flat.setdefault("channels", ("all",))
                res = fit_and_evaluate(PipelineConfig.from_flat(**flat), train, test)
                folder = Path(tmp) / f"p{len(prepared)}"
                folder.mkdir()
                for r, calls in prepare_point(res.pipeline, test, folder):
                    prepared.append(({"config": p.label, **r}, calls))
            rows = time_rows(prepared, 3 if quick else repeats, rounds=1 if quick else 3)
            prepared.clear()  # the sweep's sessions and pipelines: freed before the next timing
            gc.collect()
            rt = realtime_rows(
                RT_ROWS,
                3 if quick else 4 * repeats,
                Path(tmp),
                window=400 if quick else 1000,
                rounds=1 if quick else 5,
            )
        torch.set_num_threads(threads)
        pareto_front(rows)
        result = {"task": task, "epochs": 1 if quick else epochs, "rows": rows,
                  "realtime_12_taxels_2khz_gwt_snn": rt}  # fmt: skip
        writer.write_json("pareto.json", result)
        table = format_table(rows)
        writer.file("pareto.md").write_text(table + "\n\n" + "\n".join(map(format_rt, rt)) + "\n")
        plot(rows, writer.file("pareto.png"), f"{task}: error vs run time (red: Pareto front; "
             "o torch, s ORT f32, ^ ORT int8)")  # fmt: skip
        path = writer.commit()
    except BaseException:
        writer.abort()
        raise
    print(table)
    print("\n".join(map(format_rt, rt)))
    print(f"written: {path}/pareto.json, pareto.md, pareto.png")
    return result


def format_rt(rt: dict) -> str:
    k = rt.get("touched_taxels")
    scene = "" if k is None else f", activity gate on, {k} touched"
    if rt.get("precision") == "int8":
        scene += ", int8 MatMuls"
    snn = f"SNN ({rt.get('snn_hidden', 64)} units, {rt.get('snn_dt_ms', 5.0):g} ms step)"
    form = rt.get("form", "gwt")
    name = {"gwt": f"GWT (hop {rt['gwt_hop']}) + {snn}",
            "cgwt": f"causal GWT (hop {rt['gwt_hop']}) + {snn}",
            _S: f"causal GWT stream graph (hop {rt['gwt_hop']}) + {snn}",
            _SE: f"causal GWT stream graph (hop {rt['gwt_hop']}), its encoder part alone",
            _SM: f"{snn} alone (one window's spikes in)",
            _SD: f"causal GWT stream graph (hop {rt['gwt_hop']}) + {snn}, with its early "
                 "decision (the service's stream path)",
            _SH: f"causal GWT stream graph (hop {rt['gwt_hop']}) + {snn}: its Conv, MatMul "
                 f"and LSTM nodes of >= {HEAVY_MACS:,} multiply-adds alone",
            _SF: f"causal GWT stream graph (hop {rt['gwt_hop']}) + {snn}, one frame per call "
                 "with its early decision (latency one frame)",
            _F: f"continuous code (frames, hop {rt['gwt_hop']}) + stream SNN "
                f"({rt.get('snn_hidden', 64)} units), one-frame step graph "
                f"({rt.get('nodes', '?')} nodes), one frame per call with its decision (latency "
                "one frame)",
            _FG: f"continuous code (frames, hop {rt['gwt_hop']}) + stream SNN "
                 f"({rt.get('snn_hidden', 64)} units), input layer as a gather, one frame per call "
                 "(latency one frame)",
            _FB: f"continuous code (frames, hop {rt['gwt_hop']}) + stream SNN "
                 f"({rt.get('snn_hidden', 64)} units), {rt.get('streams')} streams of 12 taxels "
                 "in one call per frame (latency one frame; per stream)",
            _FLOOR: "the floor of any onnxruntime call from Python (one Identity node, one input, "
                    "one output), one frame per call",
            _FBOUND: f"continuous code (frames, hop {rt['gwt_hop']}) + stream SNN "
                     f"({rt.get('snn_hidden', 64)} units), one-frame step graph through bound "
                     "buffers (IOBinding), one frame per call (latency one frame)",
            _FLOORB: "the floor of any onnxruntime call from Python through bound buffers "
                     "(IOBinding; one Identity node), one frame per call"}[form]  # fmt: skip
    step = rt.get("step_samples", rt["window_samples"] // 2)
    if form in _FRAME_FORMS:  # no window: a frame per call
        return (f"{name}, 12 taxels @ 2 kHz, a frame every {step} samples "
                f"({1000 * step / 2000:g} ms), onnxruntime 1 thread: "
                f"{1000 * rt['ms_per_window']:.1f} us per call, {rt['ms_per_signal_s']:.2f} ms "
                f"per second of signal = {rt['realtime_factor']:.0f}x real time")  # fmt: skip
    every = ("half window" if 2 * step == rt["window_samples"]
             else f"{step} samples ({1000 * step / 2000:g} ms)")  # fmt: skip
    return (f"{name}, 12 taxels @ 2 kHz{scene}, "
            f"{rt['window_samples']}-sample windows every {every}, "
            f"onnxruntime 1 thread batch 1: {rt['ms_per_window']:.3f} ms per window, "
            f"{rt['ms_per_signal_s']:.2f} ms per second of signal = "
            f"{rt['realtime_factor']:.0f}x real time")  # fmt: skip


def format_table(rows: list[dict]) -> str:
    def f(v, fmt):
        return "-" if v is None else format(v, fmt)

    head = ("| config | precision | test error % | ms / s signal, batch 1 | batch 64 | "
            "real-time x | encoder err ms (flips) | size kB | front |")  # fmt: skip
    lines = [head, "|" + "---|" * 9]
    for r in sorted(rows, key=lambda r: r["ms_per_signal_s_batch1"] or np.inf):
        lines.append(
            f"| {r['config']} | {r['precision']} | {100 * r['test_error']:.2f} +- "
            f"{100 * r['test_error_ci95']:.2f} | {f(r['ms_per_signal_s_batch1'], '.2f')} | "
            f"{f(r['ms_per_signal_s_batch64'], '.3f')} | {f(r['realtime_factor_batch1'], '.0f')} | "
            f"{r['encoder_max_time_err_ms']:.1e} ({r['encoder_flipped_slots']}) | "
            f"{r['size_bytes'] / 1024:.1f} | {'**yes**' if r['front'] else ''} |"
        )
    return "\n".join(lines)


def load(path: Path) -> dict:
    return json.loads(Path(path).read_text())


HELP = "run time against error of encoder x model configurations (and real-time rows)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--task", default="hook_loop", choices=sorted(TASKS),
                   help="the task whose pipelines are compared")  # fmt: skip
    p.add_argument(
        "--epochs", "--bench-epochs", type=int, default=10, help="training epochs per configuration"
    )
    p.add_argument("--quick", action="store_true", help="a few small cases (as the tests run)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out folder")


def main(out: Path | None, options: argparse.Namespace) -> int:
    from . import require_out

    run(Path(require_out(out, "pareto")), task=options.task, quick=options.quick,
        epochs=options.epochs, overwrite=options.overwrite, progress=not options.quiet)  # fmt: skip
    return 0
