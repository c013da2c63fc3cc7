"""Export a trained run to one ONNX graph: raw sensor window -> class scores.

Graph contract: input ``window`` ``[batch, channels, samples]`` float32 (the run's channels, units
and sampling rate, recorded in the metadata); output ``scores`` ``[batch, classes]`` (tempotron:
V_max per class; SNN: readout). SNN graphs also take and return their state (``h_state``,
``o_state``, ``[batch, units]``) so a client can carry it across consecutive windows of a stream;
zeros start a fresh stream.

The encoder is exported as MatMuls (:class:`~tactilesnn.encoders.export.WindowEncoder`); the
exact tempotron has no time loop (a fixed graph of sorts, exponentials and maxima); the SNN time
loop is an ONNX ``Loop`` from a scripted recurrence, so the graph size does not grow with the
number of time steps. Every export is run in onnxruntime and compared with torch before it is
written; a graph whose state inputs do not change its outputs is refused.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import warnings
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import Tensor, nn

from . import __version__
from .encoders.export import WindowEncoder
from .pipeline import SpikePipeline

SCORE_ATOL = 1e-4


class _EncoderGraph(nn.Module):
    """Window -> spike times ``[B, afferents]`` including the clock afferents."""

    def __init__(self, pipe: SpikePipeline) -> None:
        super().__init__()
        self.enc = WindowEncoder(pipe.encoder, pipe.code, pipe.window, pipe.channel_idx)
        n = pipe.config.clock_afferents
        clock = torch.arange(n, dtype=torch.float32) * (pipe.duration_ms / max(n, 1))
        self.register_buffer("clock", clock)

    def forward(self, x: Tensor) -> Tensor:
        s = self.enc(x)
        if self.clock.numel():
            s = torch.cat([s, self.clock.unsqueeze(0).expand(s.shape[0], -1)], dim=1)
        return s


class _TempotronGraph(nn.Module):
    def __init__(self, pipe: SpikePipeline) -> None:
        super().__init__()
        self.enc = _EncoderGraph(pipe)
        self.model = pipe.model

    def forward(self, x: Tensor) -> Tensor:
        return self.model(self.enc(x))[0]


class _LIFLoop(nn.Module):
    def __init__(self, beta: float, theta: float, subtract: bool) -> None:
        super().__init__()
        self.beta, self.theta, self.subtract = beta, theta, subtract

    def forward(self, cur: Tensor, u: Tensor) -> tuple[Tensor, Tensor]:
        outs = []
        for t in range(cur.shape[0]):
            u = self.beta * u + cur[t]
            s = (u >= self.theta).to(cur.dtype)
            u = u - s * self.theta if self.subtract else u * (1.0 - s)
            outs.append(s)
        return torch.stack(outs), u


class _LILoop(nn.Module):
    def __init__(self, beta: float) -> None:
        super().__init__()
        self.beta = beta

    def forward(self, cur: Tensor, v: Tensor) -> tuple[Tensor, Tensor]:
        outs = []
        for t in range(cur.shape[0]):
            v = self.beta * v + cur[t]
            outs.append(v)
        return torch.stack(outs), v


class _SNNGraph(nn.Module):
    """Spike times -> raster -> hoisted projections -> ONNX Loops -> readout (scripted)."""

    def __init__(self, pipe: SpikePipeline) -> None:
        super().__init__()
        m = pipe.model
        if m.hidden.rec is not None:
            raise ValueError("export of recurrent SNN layers is not supported yet")
        self.steps = int(np.ceil(pipe.duration_ms / pipe.config.snn_dt_ms)) + 1
        self.dt = float(pipe.config.snn_dt_ms)
        self.fc1, self.fc2 = m.hidden.fc, m.out.fc
        self.l1 = _LIFLoop(m.hidden.beta, m.hidden.theta, m.hidden.reset == "subtract")
        self.readout = m.readout
        if m.readout == "count":
            self.l2 = _LIFLoop(m.out.beta, m.out.theta, m.out.reset == "subtract")
        else:
            self.l2 = _LILoop(m.out.beta)

    def forward(self, spikes: Tensor, h: Tensor, o: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        bins = torch.floor(spikes / self.dt)  # [B, A]; inf never matches a step
        steps = torch.arange(self.steps, dtype=spikes.dtype)
        raster = (bins.unsqueeze(0) == steps.view(-1, 1, 1)).to(spikes.dtype)  # [T, B, A]
        hs, h_new = self.l1(self.fc1(raster), h)
        os_, o_new = self.l2(self.fc2(hs), o)
        if self.readout == "count":
            scores = os_.sum(0)
        elif self.readout == "max":
            scores = os_.amax(0)
        else:
            scores = os_.mean(0)
        return scores, h_new, o_new


def _torch_export(module, args, path, inputs, outputs, dynamic) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            module,
            args,
            str(path),
            input_names=inputs,
            output_names=outputs,
            dynamic_axes=dynamic,
            opset_version=17,
            dynamo=False,
        )


def export_pipeline(
    pipe: SpikePipeline,
    out: Path,
    X_check: np.ndarray,
    metadata: dict[str, str] | None = None,
    overwrite: bool = False,
) -> dict:
    """Write ``pipe`` as ONNX to ``out`` after verifying it against torch on ``X_check``.

    Returns a report: node count, max score difference, prediction agreement.
    """

    out = Path(out)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists; pass --overwrite to replace it")
    if pipe.config.encoder not in ("gwt", "stft"):
        raise ValueError(
            f"export of the {pipe.config.encoder!r} encoder is not supported: its LIF converter "
            "has data-dependent spike counts per sample; use gwt or stft"
        )
    pipe.model.eval()
    n_ch = len(pipe.channel_names)
    dummy = torch.zeros(2, n_ch, pipe.window)
    with tempfile.TemporaryDirectory() as tmp:
        enc_path, full_path = Path(tmp) / "enc.onnx", Path(tmp) / "full.onnx"
        batch = {0: "batch"}
        if pipe.config.model == "tempotron":
            _torch_export(
                _TempotronGraph(pipe),
                (dummy,),
                full_path,
                ["window"],
                ["scores"],
                {"window": batch, "scores": batch},
            )
            model = onnx.load(str(full_path))
        else:
            _torch_export(
                _EncoderGraph(pipe),
                (dummy,),
                enc_path,
                ["window"],
                ["spikes"],
                {"window": batch, "spikes": batch},
            )
            snn = torch.jit.script(_SNNGraph(pipe))
            a = pipe.n_afferents
            hid, ncls = pipe.model.hidden.fc.out_features, len(pipe.class_names)
            snn_path = Path(tmp) / "snn.onnx"
            _torch_export(
                snn,
                (torch.zeros(2, a), torch.zeros(2, hid), torch.zeros(2, ncls)),
                snn_path,
                ["spikes_in", "h_state", "o_state"],
                ["scores", "h_state_out", "o_state_out"],
                {
                    k: batch
                    for k in (
                        "spikes_in",
                        "h_state",
                        "o_state",
                        "scores",
                        "h_state_out",
                        "o_state_out",
                    )
                },
            )
            enc = onnx.compose.add_prefix(
                onnx.load(str(enc_path)), "enc/", rename_inputs=False, rename_outputs=False
            )
            snn_m = onnx.compose.add_prefix(
                onnx.load(str(snn_path)), "snn/", rename_inputs=False, rename_outputs=False
            )
            model = onnx.compose.merge_models(enc, snn_m, io_map=[("spikes", "spikes_in")])
    meta = {
        "tactilesnn_version": __version__,
        "fs_hz": repr(pipe.fs_hz),
        "window_samples": str(pipe.window),
        "channels": json.dumps(list(pipe.channel_names)),
        "class_names": json.dumps(list(pipe.class_names)),
        "units": "input in the sensor's readout units (see the run's task); scores: "
        + ("tempotron V_max (threshold 1)" if pipe.config.model == "tempotron" else "SNN readout"),
        "encoder": pipe.config.encoder,
        "model": pipe.config.model,
        "pipeline_config": json.dumps(pipe.config.to_dict()),
        **(metadata or {}),
    }
    for k, v in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = k, str(v)
    onnx.checker.check_model(model)
    report = verify(model, pipe, X_check)
    tmp_out = out.with_name(f".{out.name}.tmp")
    out.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(model, str(tmp_out))
    os.replace(tmp_out, out)
    report["nodes"] = len(model.graph.node)
    report["path"] = str(out)
    return report


def verify(model: onnx.ModelProto, pipe: SpikePipeline, X: np.ndarray) -> dict:
    """Run the graph in onnxruntime on ``X`` and compare with the torch pipeline."""
    import onnxruntime as ort

    sess = ort.InferenceSession(model.SerializeToString())
    x = np.ascontiguousarray(X, dtype=np.float32)
    feeds = {"window": x}
    names = [i.name for i in sess.get_inputs()]
    if "h_state" in names:
        hid, ncls = pipe.model.hidden.fc.out_features, len(pipe.class_names)
        feeds["h_state"] = np.zeros((len(x), hid), np.float32)
        feeds["o_state"] = np.zeros((len(x), ncls), np.float32)
    got = sess.run(["scores"], feeds)[0]
    ref = pipe.scores(pipe.encode(x)).numpy()
    diff = float(np.abs(got - ref).max()) if len(x) else 0.0
    agree = float((got.argmax(1) == ref.argmax(1)).mean()) if len(x) else 1.0
    if diff > SCORE_ATOL:
        raise RuntimeError(f"exported graph differs from torch by {diff:.3g} (> {SCORE_ATOL})")
    if "h_state" in names and len(x):
        feeds2 = dict(feeds, h_state=feeds["h_state"] + 0.5, o_state=feeds["o_state"] + 0.5)
        if np.array_equal(sess.run(["scores"], feeds2)[0], got):
            raise RuntimeError("exported SNN ignores its state inputs: the state was frozen")
    return {"max_score_diff": diff, "prediction_agreement": agree, "n_checked": len(x)}


def data_hash(cfg: dict) -> str:
    """SHA-256 identifying the training data: the data file's bytes or the task and its settings."""
    h = hashlib.sha256()
    if cfg.get("data"):
        with open(cfg["data"], "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    else:
        h.update(json.dumps({"task": cfg["task"], **cfg["task_kwargs"]}, sort_keys=True).encode())
    return h.hexdigest()
