"""Export a trained run to one ONNX graph: raw sensor window -> class scores.

Graph contract: input ``window`` ``[batch, channels, samples]`` float32 (the run's channels, units
and sampling rate, recorded in the metadata); output ``scores`` ``[batch, classes]``. A model with
streaming state (:attr:`~tactilesnn.models.base.SpikeModel.state_names`, e.g. the SNN's
``h_state`` / ``o_state`` / ``hs_state``, ``[batch, units]``) takes it as extra inputs and returns
``<name>_out``, so a client can carry it across consecutive windows; zeros start a fresh stream.

Each component owns its graph (``onnx_module()``), written by the ``torch.export``-based
exporter unless another is chosen (:func:`~tactilesnn.core.onnx_graph.component_to_onnx`); the
encoder's (channel selection and clock afferents added here) is chained into the model's with
``onnx.compose``; time loops become ONNX ``Scan`` nodes (``Loop`` nodes from the older exporter)
and the SNN's scans single ``LSTM`` / ``MatMul`` nodes (:mod:`~tactilesnn.models.onnx_ops`), so
the graph does not grow with the number of steps.
Every export is run in onnxruntime and compared with torch before it is written; a graph whose
state inputs do not change its outputs is refused.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import Tensor, nn

from ..core.checks import ExportError
from ..core.files import file_sha256, replace_atomically
from ..core.graph_contract import EARLY_OUTPUTS, SCORES_OUTPUT, WINDOW_INPUT, GraphContract
from ..core.onnx_graph import chain, component_to_onnx, operator_nodes
from ..core.onnx_run import run_batched
from ..core.spikes import clock_times
from ..core.version import __version__
from ..pipeline import SpikePipeline

SCORE_ATOL = 1e-4
#: ... or this fraction of the window's largest |score|, whichever is larger: a readout summing
#: 4,005 afferents into scores of ~150 rounds by 4e-4 in float32 (torch's own float32 against
#: float64: 4.1e-6 relative)
SCORE_RTOL = 2e-5


def score_tolerance(ref: np.ndarray) -> np.ndarray:
    """Per window ``[N]``: how far the exported scores may be from torch's ``ref [N, classes]``."""
    scale = np.abs(ref).max(1) if ref.size else np.zeros(len(ref))
    return np.maximum(SCORE_ATOL, SCORE_RTOL * scale)


#: the exported decision time against torch's (float32 exponentials), or TIME_RTOL of the window
DECISION_ATOL_MS = 1e-3


class PipelineEncoderGraph(nn.Module):
    """Window -> channel selection -> the encoder's own graph -> level code and clock
    afferents appended."""

    def __init__(self, pipe: SpikePipeline, encoder: nn.Module | None = None) -> None:
        super().__init__()
        self.register_buffer("channel_idx", torch.as_tensor(pipe.channel_idx, dtype=torch.long))
        # every channel of the window, in order: no selection node (a copy of the window)
        self.select = list(pipe.channel_idx) != list(range(len(pipe.channel_names)))
        self.encoder = pipe.encoder.onnx_module() if encoder is None else encoder
        self.with_level = pipe.level is not None
        self.level = pipe.level if pipe.level is not None else nn.Identity()
        self.pad = pipe.max_spikes - 1
        clock = clock_times(pipe.n_clock, pipe.max_spikes, pipe.duration_ms)
        self.register_buffer("clock", clock)
        self.with_clock = pipe.n_clock > 0
        self.clock_like_slice = pipe.encoder.n_afferents >= pipe.n_clock
        self.gain_norm = pipe.config.gain_norm
        self.rest = pipe.rest_samples if pipe.config.rest_ms else 0
        self.tiny = float(np.finfo(np.float32).tiny)

    def forward(self, x: Tensor) -> Tensor:
        x = torch.index_select(x, 1, self.channel_idx) if self.select else x
        if self.rest:  # as pipeline.rest_referenced: the mean in float64
            x = x - x[..., : self.rest].double().mean(dim=-1, keepdim=True).float()
        if self.gain_norm:  # as pipeline.gain_normalised: the level in float64, so both agree
            level = x.double().abs().mean(dim=[1, 2], keepdim=True).float()
            x = x / torch.clamp(level, min=self.tiny)
        return self.append(self.encoder(x), x)

    def append(self, s: Tensor, x: Tensor) -> Tensor:
        """The encoder's spikes ``s`` with the level code of the window ``x`` (selected
        channels) and the clock afferents appended."""
        if self.with_level:
            level = self.level(x).unsqueeze(-1)
            if self.pad > 0:
                level = nn.functional.pad(level, (0, self.pad), value=float("inf"))
            s = torch.cat([s, level], dim=1)
        if self.with_clock:
            # expand_as a slice of the same size: one Expand (expand(b, -1, -1) traces to 8 nodes)
            n, k = self.clock.shape
            clock = self.clock.unsqueeze(0)
            if self.clock_like_slice:
                clock = clock.expand_as(s[:, :n])
            else:
                clock = clock.expand(s.shape[0], n, k)
            s = torch.cat([s, clock], dim=1)
        return s


def build_graph(pipe: SpikePipeline, exporter: str | None = None) -> onnx.ModelProto:
    """The pipeline as one ONNX graph: ``window`` (+ model state) -> ``scores`` (+ new state)."""
    enc, model = build_parts(pipe, exporter)
    return chain(enc, model, [("spikes", "spikes_in")], tags=("enc/", "model/"))


def build_parts(
    pipe: SpikePipeline, exporter: str | None = None
) -> tuple[onnx.ModelProto, onnx.ModelProto]:
    """The encoder graph (``window -> spikes``) and the model graph (``spikes_in`` + state ->
    ``scores`` + state), each owned by its component, each written by
    :func:`~tactilesnn.core.onnx_graph.component_to_onnx` (``exporter``: see there)."""
    mod = build_model_part(pipe, exporter)
    # a signal, not zeros: traced on all-silent windows, the activity gate's row count
    # would be 0, a size the tracer may fix as a constant
    gen = torch.Generator().manual_seed(0)
    dummy = torch.randn(2, len(pipe.channel_names), pipe.window, generator=gen)
    enc = component_to_onnx(PipelineEncoderGraph(pipe), (dummy,), ["window"], ["spikes"],
                            pipe.encoder.onnx_scripted, exporter,
                            exportable=pipe.encoder.onnx_exportable)  # fmt: skip
    return enc, mod


def build_model_part(pipe: SpikePipeline, exporter: str | None = None) -> onnx.ModelProto:
    """The model's graph (``spikes_in`` + state -> ``scores`` + state, and the early decision
    where the model makes one), shared by the window and the stream graphs."""
    problem = pipe.model.export_problem()
    if problem:
        raise ValueError(f"cannot export this pipeline: {problem}")
    pipe.model.eval()
    states = list(pipe.model.state_names)
    spikes = torch.rand(2, pipe.n_afferents, pipe.max_spikes) * pipe.duration_ms
    args = (spikes, *(torch.zeros(2, units) for _, units in states))
    names_in = ["spikes_in", *(n for n, _ in states)]
    names_out = ["scores", *(f"{n}_out" for n, _ in states)]
    if pipe.model.decides_early:
        names_out += list(EARLY_OUTPUTS)
    return component_to_onnx(pipe.model.onnx_module(), args, names_in, names_out,
                             pipe.model.onnx_scripted, exporter,
                             exportable=pipe.model.onnx_exportable)  # fmt: skip


def export_pipeline(
    pipe: SpikePipeline,
    out: Path,
    X_check: np.ndarray,
    metadata: dict[str, str] | None = None,
    overwrite: bool = False,
    progress: bool = False,
    exporter: str | None = None,
    spikes: torch.Tensor | None = None,
) -> dict:
    """Write ``pipe`` as ONNX to ``out`` after verifying it against torch on ``X_check``
    (progress bars over the verification's batches if ``progress``; ``exporter``: see
    :func:`~tactilesnn.core.onnx_graph.chosen_exporter`; ``spikes``: the pipeline's spike times
    of ``X_check`` where the caller has them, see :func:`verify`).

    Returns a report: operator nodes (``Constant`` nodes not counted), max score difference,
    prediction agreement.
    """
    out = check_out(out, overwrite)
    if len(X_check) == 0:
        raise ValueError("X_check holds no window: the export is verified against torch on it")
    enc, mod = build_parts(pipe, exporter)
    model = chain(enc, mod, [("spikes", "spikes_in")], tags=("enc/", "model/"))
    contract = pipeline_contract(pipe, tuple(n for n, _ in pipe.model.state_names),
                                 "input in the sensor's readout units (see the run's task)",
                                 dict(metadata or {}))  # fmt: skip
    meta = contract.to_metadata()
    for k, v in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = k, str(v)
    onnx.checker.check_model(model)
    report = verify(model, pipe, X_check, parts=(enc, mod), progress=progress, spikes=spikes)
    save_atomic(model, out)
    report["nodes"] = operator_nodes(model)
    report["path"] = str(out)
    return report


def check_out(out: Path, overwrite: bool) -> Path:
    """``out`` as a Path, refused if it exists (unless ``overwrite``) or is not a file."""
    out = Path(out)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists; pass --overwrite to replace it")
    if out.exists() and not out.is_file():
        raise FileExistsError(f"{out} exists and is not a file")
    return out


def save_atomic(model: onnx.ModelProto, out: Path) -> None:
    """Write ``model`` to ``out`` through a temporary file in its folder (never half-written)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    replace_atomically(out, lambda tmp: onnx.save(model, str(tmp)))


def pipeline_contract(
    pipe: SpikePipeline, state_inputs: tuple[str, ...], input_units: str, extra: dict[str, str]
) -> GraphContract:
    """The graph contract of an export of ``pipe`` (metadata written into the file)."""
    return GraphContract(
        fs_hz=pipe.fs_hz,
        window_samples=pipe.window,
        channels=tuple(pipe.channel_names),
        class_names=tuple(pipe.class_names),
        encoder=pipe.config.encoder_type,
        model=pipe.config.model_type,
        state_inputs=state_inputs,
        bytes_per_window=pipe.graph_bytes_per_window(),
        encoder_channels=tuple(int(i) for i in pipe.channel_idx),
        units=f"{input_units}; scores: {pipe.model.score_units}",
        pipeline_config=pipe.config.to_dict(),
        version=__version__,
        extra=extra,
        **pipe.encoder.export_metadata(),
    )


#: end to end, a spike time within float rounding of a raster step boundary may fall into the
#: neighbouring step in the graph (MatMul scalogram) and in torch (FFT); in the model alone, a LIF
#: membrane within float rounding of its threshold may spike in one and not the other (the LSTM
#: node's and torch's sums round differently). Either changes a discrete-time model's score for
#: that window. Such windows may be at most this fraction of the check set, or one window.
MAX_BOUNDARY_FRACTION = 0.002


def _boundary_allowance(n: int) -> int:
    """Windows of ``n`` that may differ by a rounding-boundary flip (see above)."""
    return max(1, int(MAX_BOUNDARY_FRACTION * n))


#: spike-time tolerance of the exported encoder: 1e-2 ms, or 1e-5 of the window if longer (a latency
#: code turns a relative amplitude error e into ~0.3 e x the window: float32 sums over long
#: wavelets reach e ~ 1e-5)
TIME_ATOL_MS = 1e-2
TIME_RTOL = 1e-5
#: a late latency spike codes a weak band, whose amplitude the same float32 rounding perturbs
#: relatively more (relative error ~ 1 / amplitude): with the 30 dB log code a spike at the
#: window's end codes 31.6x less than one at its start, so the tolerance grows to this factor
LATE_SPIKE_FACTOR = 10 ** (30 / 20)


def _check_early(pipe: SpikePipeline, spikes, cls: np.ndarray, t_ms: np.ndarray) -> dict:
    """The graph's early decisions against torch's on the same spike times: decision times
    within ``DECISION_ATOL_MS`` (or ``TIME_RTOL`` of the window) and the same class, except on
    at most ``MAX_BOUNDARY_FRACTION`` of windows (two tempotron classes firing within float32
    rounding of each other, either may be first; an SNN's lead within rounding of its margin
    at some step may decide a step apart)."""
    batch = pipe.model.batch_size(spikes)
    ref_c, ref_t = [], []
    for i in range(0, len(spikes), batch):
        c, t = pipe.model.early_decision(spikes[i : i + batch])
        ref_c.append(c.numpy())
        ref_t.append(t.numpy())
    ref_c, ref_t = np.concatenate(ref_c), np.concatenate(ref_t)
    dt = np.abs(t_ms.astype(np.float64) - ref_t)
    late = dt > max(DECISION_ATOL_MS, TIME_RTOL * pipe.duration_ms)
    off = late | (cls != ref_c)
    if off.sum() > _boundary_allowance(len(cls)):
        raise ExportError(
            f"exported early decision differs from torch on {int(off.sum())} windows "
            f"({int((cls != ref_c).sum())} name another class; time up to {dt.max():.3g} ms off)"
        )
    return {"early_max_time_diff_ms": float(dt[~off].max()) if (~off).any() else 0.0,
            "early_class_agreement": float((cls == ref_c).mean()) if cls.size else 1.0,
            "early_windows_differing": int(off.sum())}  # fmt: skip


def _verify_parts(pipe: SpikePipeline, model_part: onnx.ModelProto, spikes: torch.Tensor,
                  held: list[np.ndarray], ref: np.ndarray, tol: np.ndarray, batch: int, bar,
                  report: dict) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """:func:`verify`'s checks of each part: the graph's spike times (``held``'s one array,
    handed over: released before the model's session opens) against
    torch's ``spikes``, and the model's graph on torch's very spike times against ``ref``
    (ExportError past the tolerances); fills ``report``. Returns the windows whose code flipped
    a spike on a rounding boundary and the score tolerance end to end."""
    x_n = len(ref)
    states = list(pipe.model.state_names)
    got_spikes = held.pop()
    t_tol = max(TIME_ATOL_MS, TIME_RTOL * pipe.duration_ms)
    frame_ms = pipe.encoder.frame_period_ms
    # a window whose code flipped a spike on a rounding boundary (what these checks accept)
    # may score differently end to end: the model sees another input there
    want_t = spikes.numpy()
    if frame_ms is None:
        dt, flips = compare_spike_times(got_spikes, want_t, pipe.duration_ms, t_tol)
        flipped = (np.isfinite(got_spikes) != np.isfinite(want_t)).any(axis=(1, 2))
    else:  # a code clocked by frames: the same frames must spike
        dt, flips, flipped = compare_frame_spikes(got_spikes, want_t, frame_ms)
    del got_spikes
    # with the parts checked, scores are held to the spike-time bound (1e-2) where it is the
    # looser: a degenerate file's LI read-out (a channel at +30,000 through the LIF code)
    # differs from torch by up to 1.4e-3 in float32 (tests/encoders/test_degenerate_windows.py)
    tol = np.maximum(tol, t_tol)
    mod = _session(model_part)
    feeds_m = {"spikes_in": spikes.numpy().astype(np.float32), **_zero_states(states, x_n)}
    early = list(EARLY_OUTPUTS) if pipe.model.decides_early else []
    got_m, *got_e = run_batched(mod, ["scores", *early], feeds_m, batch, bar("model"),
                                trim=True)  # fmt: skip
    per_m = np.abs(got_m - ref).max(1)
    dm, off_m = float(per_m.max()), int((~(per_m <= tol)).sum())  # NaN counts as off
    del mod
    if off_m > _boundary_allowance(x_n):
        raise ExportError(f"exported model differs from torch by up to {dm:.3g} (> "
                          f"{float(np.min(tol)):.3g}) on {off_m} of {x_n} windows")  # fmt: skip
    if early:
        report.update(_check_early(pipe, spikes, *got_e))
    report.update(
        encoder_max_time_diff_ms=dt,
        encoder_cutoff_flips=flips,
        model_max_score_diff=dm,
        model_windows_beyond_atol=off_m,
    )
    return flipped, tol


def verify(
    model: onnx.ModelProto,
    pipe: SpikePipeline,
    X: np.ndarray,
    parts: tuple[onnx.ModelProto, onnx.ModelProto] | None = None,
    progress: bool = False,
    spikes: torch.Tensor | None = None,
) -> dict:
    """Run the graph in onnxruntime on ``X`` and compare with the torch pipeline (``spikes``:
    its spike times of ``X`` where the caller has them, as :meth:`SpikePipeline.encode` gave
    them on the CPU: a run's evaluation coded the test windows already; else coded here).

    With ``parts`` each component's graph is checked on its own first: the encoder's spike times
    within ``TIME_ATOL_MS`` (the same silent slots, except spikes at the code's cutoff, see
    :func:`compare_spike_times`), the model's scores within ``SCORE_ATOL`` on the
    very spike times torch produced (or ``SCORE_RTOL`` of the window's largest score, float32
    rounding of large sums). End to end, scores must agree within the same except
    on at most ``MAX_BOUNDARY_FRACTION`` of windows (spikes on a step boundary, see above).
    """

    x = np.ascontiguousarray(X, dtype=np.float32)
    states = list(pipe.model.state_names)
    if spikes is None:
        spikes = pipe.encode(x, progress=progress)
    elif spikes.shape[0] != len(x) or spikes.device.type != "cpu":
        raise ValueError(f"spikes for {len(x)} windows on the CPU expected, got "
                         f"{tuple(spikes.shape)} on {spikes.device}")  # fmt: skip
    ref = pipe.scores(spikes).numpy()
    batch = check_batch(pipe)
    bar = (lambda name: f"verify {name}") if progress else (lambda name: None)
    report: dict = {"n_checked": len(x), "check_batch": batch}
    tol = score_tolerance(ref)
    with_parts = parts is not None and len(x) > 0
    graph = model
    if with_parts:  # the whole graph also gives its encoder's spike times: one run, not two
        graph = onnx.ModelProto()
        graph.CopyFrom(model)
        graph.graph.output.append(next(o for o in parts[0].graph.output if o.name == "spikes"))
    sess = _session(graph)
    feeds = {"window": x, **_zero_states(states, len(x))}
    got, *got_t = run_batched(sess, ["scores", *(["spikes"] if with_parts else [])], feeds,
                              batch, bar("end to end"), trim=True)  # fmt: skip
    frozen = False  # the state inputs ignored (checked while the session is open)
    if states and len(x):
        k = min(len(x), batch)
        feeds2 = {k2: (v[:k] + 0.5 if k2 != "window" else v[:k]) for k2, v in feeds.items()}
        frozen = np.array_equal(sess.run(["scores"], feeds2)[0], got[:k])
    del sess, graph  # one session at a time: each holds its own copy of the weights
    flipped = np.zeros(len(x), bool)  # windows whose code flipped a spike (with parts)
    if with_parts:
        assert parts is not None
        flipped, tol = _verify_parts(pipe, parts[1], spikes, got_t, ref, tol, batch, bar,
                                     report)  # fmt: skip
    per_window = np.abs(got - ref).max(1) if len(x) else np.zeros(0)
    beyond = ~(per_window <= tol)  # a NaN score is off, not within tolerance
    off = int((beyond & ~flipped).sum())
    if off > _boundary_allowance(len(x)):
        worst = float(per_window.max())
        raise ExportError(
            f"exported graph differs from torch by up to {worst:.3g} on {off} of {len(x)} windows"
        )
    if frozen:
        raise ExportError("exported model ignores its state inputs: the state was frozen")
    report.update(
        max_score_diff=float(per_window.max()) if len(x) else 0.0,
        windows_beyond_atol=off,
        windows_beyond_atol_after_a_code_flip=int((beyond & flipped).sum()),
        prediction_agreement=float((got.argmax(1) == ref.argmax(1)).mean()) if len(x) else 1.0,
    )
    return report


#: working memory of one onnxruntime call while verifying (windows per call follow from it)
CHECK_BUDGET_BYTES = 256 << 20


def check_batch(pipe: SpikePipeline) -> int:
    """Windows per onnxruntime call so one call stays within :data:`CHECK_BUDGET_BYTES`."""
    return max(1, min(4096, CHECK_BUDGET_BYTES // max(1, pipe.graph_bytes_per_window())))


def _session(model: onnx.ModelProto):
    """A CPU session without the growing memory arena (verification must stay in budget)."""
    import onnxruntime as ort

    from ..core.onnx_run import session_threads

    opts = ort.SessionOptions()
    opts.enable_cpu_mem_arena = False
    # as every runtime of ours runs it: one thread where a reducing scatter would race
    opts.intra_op_num_threads = session_threads(model)
    return ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])


def _zero_states(states: list[tuple[str, int]], n: int) -> dict[str, np.ndarray]:
    return {name: np.zeros((n, units), np.float32) for name, units in states}


#: a code clocked by frames may differ from torch on this fraction of its spikes (float32
#: rounding of two orders of the same sums deciding a threshold crossing on its boundary)
FRAME_FLIP_FRACTION = 1e-4


def _frame_raster(t: np.ndarray, frame_ms: float, frames: int) -> np.ndarray:
    """Spike times ``[N, A, k]`` (ms) -> ``[N, A, frames + 1]`` bool: which frames spike."""
    n, aff, _ = t.shape
    idx = np.where(np.isfinite(t), np.floor(t / frame_ms), -1).astype(np.int64)
    out = np.zeros((n, aff, frames + 1), bool)
    w, a, _ = np.nonzero(idx >= 0)
    out[w, a, np.minimum(idx[idx >= 0], frames)] = True
    return out


def compare_frame_spikes(
    got: np.ndarray, want: np.ndarray, frame_ms: float
) -> tuple[float, int, np.ndarray]:
    """For a code that spikes on a frame clock (at most once per frame and afferent): the
    frames at which each afferent spikes, compared as sets. Returns ``(0.0, flips, windows)``:
    spikes on the same frame have the same time; ``flips`` (a spike in one only) may be at most
    :data:`FRAME_FLIP_FRACTION` of torch's spikes (and at least 2 are allowed); ``windows``
    ``[N]`` bool: the windows holding a flip."""
    for name, a in (("the graph", got), ("torch", want)):
        if np.isnan(a).any():
            raise ExportError(f"exported encoder: {name} gives NaN spike times")
    frames = int(np.nanmax(np.where(np.isfinite(want), want, 0.0)) // frame_ms) + 2
    frames = max(frames, int(np.nanmax(np.where(np.isfinite(got), got, 0.0)) // frame_ms) + 2)
    diff = _frame_raster(got, frame_ms, frames) != _frame_raster(want, frame_ms, frames)
    flips = int(diff.sum())
    allowed = max(2, int(FRAME_FLIP_FRACTION * np.isfinite(want).sum()))
    if flips > allowed:
        raise ExportError(f"exported encoder: {flips} spikes differ from torch's (at most "
                          f"{allowed} allowed: threshold crossings on a rounding boundary)")  # fmt: skip
    return 0.0, flips, diff.any(axis=(1, 2))


def compare_spike_times(
    got: np.ndarray, want: np.ndarray, duration_ms: float, tol_ms: float
) -> tuple[float, int]:
    """Max spike-time difference (ms) where both spike, and the number of slots that spike in
    one and not the other. A spike at time ``t`` may differ by ``tol_ms`` x
    ``LATE_SPIKE_FACTOR ** (t / duration_ms)`` (late spikes code weak amplitudes).
    Such a flip is only accepted at the code's cutoff (the spike within
    ``tol_ms`` of the window end, where rounding decides whether it is emitted at all)."""
    for name, a in (("the graph", got), ("torch", want)):
        if np.isnan(a).any():
            raise ExportError(f"exported encoder: {name} gives NaN spike times for "
                              f"{int(np.isnan(a).sum())} slots (a spike time is finite or +inf)")  # fmt: skip
    fin_g, fin_w = np.isfinite(got), np.isfinite(want)
    flip = fin_g != fin_w
    if flip.any():
        t = np.where(fin_g, got, want)[flip]
        if (t < duration_ms - tol_ms).any():
            worst = float(t.min())
            raise ExportError(
                f"exported encoder: a spike at {worst:.4g} ms (window {duration_ms:.4g} ms) is "
                "missing in one of torch and the graph"
            )
    both = fin_g & fin_w
    if not both.any():
        return 0.0, int(flip.sum())
    t, d = want[both], np.abs(got[both] - want[both])
    tol = tol_ms * LATE_SPIKE_FACTOR ** np.clip(t / duration_ms, 0.0, 1.0)
    worst = int(np.argmax(d / tol))
    if d[worst] > tol[worst]:
        raise ExportError(
            f"exported encoder's spike times differ by {d[worst]:.3g} ms at {t[worst]:.4g} ms "
            f"(> {tol[worst]:.3g} ms there)"
        )
    return float(d.max()), int(flip.sum())


def quantize_int8(path: Path, X: np.ndarray, y: np.ndarray, overwrite: bool = False) -> dict:
    """Dynamic int8 quantisation of the window-side MatMul weights (the products after them, the
    Convs and the LSTM stay float32); reports the accuracy change on (X, y)."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    path = Path(path)
    out = path.with_name(path.stem + ".int8.onnx")
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists; pass --overwrite to replace it")
    # only the window-side MatMul weights (see _not_window_side). The SNN's LSTM node is the
    # exact LIF recurrence (models.functional.lif_lstm_parameters), which quantised gate weights
    # would no longer be.
    # The scalogram's Convs stay float32: onnxruntime's ConvInteger is 2.3x slower than
    # its float Conv there (0.56 vs 0.24 ms, 12 taxels, hop 10) and errs by 1 % of the peak,
    # while DynamicQuantizeMatMul is 2.7x faster than the float MatMul (0.19 vs 0.50 ms)
    # written beside the target, then renamed (atomic); the quantiser's per-tensor INFO lines
    # and its pre-processing hint go to the root logger, which the CLI shows: held back here
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    root = logging.getLogger()
    level = root.level
    root.setLevel(logging.ERROR)
    try:
        quantize_dynamic(str(path), str(tmp), weight_type=QuantType.QInt8,
                         op_types_to_quantize=["MatMul"],
                         nodes_to_exclude=_not_window_side(path))  # fmt: skip
        os.replace(tmp, out)
    finally:
        root.setLevel(level)
        tmp.unlink(missing_ok=True)
    acc = {name: _accuracy(p, X, y) for name, p in (("float", path), ("int8", out))}
    return {
        "path": str(out),
        "float_accuracy": acc["float"],
        "int8_accuracy": acc["int8"],
        "accuracy_change": acc["int8"] - acc["float"],
        "float_bytes": path.stat().st_size,
        "int8_bytes": out.stat().st_size,
    }


def _accuracy(path: Path, X: np.ndarray, y: np.ndarray) -> float:
    """Accuracy of the exported graph at ``path`` on windows ``X`` (zero state), in slices
    within :data:`CHECK_BUDGET_BYTES`."""
    model = onnx.load(str(path))
    contract = GraphContract.from_metadata({p.key: p.value for p in model.metadata_props})
    sess = _session(model)
    x = np.ascontiguousarray(X, np.float32)
    states = [(i.name, int(i.shape[1])) for i in sess.get_inputs() if i.name != WINDOW_INPUT]
    feeds = {WINDOW_INPUT: x, **_zero_states(states, len(x))}
    batch = max(1, CHECK_BUDGET_BYTES // max(1, contract.bytes_per_window))
    scores = run_batched(sess, [SCORES_OUTPUT], feeds, batch)[0]
    return float((scores.argmax(1) == np.asarray(y)).mean())


def _not_window_side(path: Path) -> list[str]:
    """The MatMul nodes whose weight does not take the raw window (first axis != the window's
    samples): int8 keeps them float32. The window-side products hold nearly all multiply-adds;
    the products after them (the GWT's shared-basis coefficients -> bands, the SNN's readout)
    are small and, quantised per tensor, cost accuracy: the stability suite's small GWT run went
    99.36 -> 98.73 % with the basis product quantised, 99.36 % without."""
    model = onnx.load(str(path))
    meta = {p.key: p.value for p in model.metadata_props}
    window = int(meta.get("window_samples", -1))
    shapes = {i.name: tuple(i.dims) for i in model.graph.initializer}
    return [n.name for n in model.graph.node if n.op_type == "MatMul"
            and shapes.get(n.input[1], (window,))[0] != window]  # fmt: skip


def data_hash(cfg: dict) -> str:
    """SHA-256 identifying the training data: the data file's bytes (a generated folder's
    manifest; the run's record holds it as ``data_sha256``), or the task and its settings."""
    if cfg.get("data"):
        return cfg.get("data_sha256") or file_sha256(Path(cfg["data"]))
    h = hashlib.sha256()
    h.update(json.dumps({"task": cfg["task"], **cfg["task_kwargs"]}, sort_keys=True).encode())
    return h.hexdigest()
