"""Export a trained run to one ONNX graph: raw sensor window -> class scores.

Graph contract: input ``window`` ``[batch, channels, samples]`` float32 (the run's channels, units
and sampling rate, recorded in the metadata); output ``scores`` ``[batch, classes]``. A model with
streaming state (:attr:`~tactilesnn.models.base.SpikeModel.state_names`, e.g. the SNN's
``h_state`` / ``o_state`` / ``hs_state``, ``[batch, units]``) takes it as extra inputs and returns
``<name>_out``, so a client can carry it across consecutive windows; zeros start a fresh stream.

Each component owns its graph (``onnx_module()``): the encoder's (channel selection and clock
afferents added here) is chained into the model's with ``onnx.compose``; scripted components
(time loops) become ONNX ``Loop``s, so the graph does not grow with the
number of steps. Every export is run in onnxruntime and compared with torch before it is
written; a graph whose state inputs do not change its outputs is refused.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import Tensor, nn

from .. import __version__
from ..pipeline import SpikePipeline
from ..spikes import clock_times
from .graph import chain, torch_to_onnx

SCORE_ATOL = 1e-4


class PipelineEncoderGraph(nn.Module):
    """Window -> channel selection -> the encoder's own graph -> clock afferents appended."""

    def __init__(self, pipe: SpikePipeline) -> None:
        super().__init__()
        self.register_buffer("channel_idx", torch.as_tensor(pipe.channel_idx, dtype=torch.long))
        self.encoder = pipe.encoder.onnx_module()
        clock = clock_times(pipe.n_clock, pipe.max_spikes, pipe.duration_ms)
        self.register_buffer("clock", clock)
        self.with_clock = pipe.n_clock > 0

    def forward(self, x: Tensor) -> Tensor:
        s = self.encoder(torch.index_select(x, 1, self.channel_idx))
        if self.with_clock:
            s = torch.cat([s, self.clock.unsqueeze(0).expand(s.shape[0], -1, -1)], dim=1)
        return s


def export_problem(pipe: SpikePipeline) -> str | None:
    """Why ``pipe`` cannot be exported (None: it can); checked before training starts."""
    return pipe.model.export_problem()


def build_graph(pipe: SpikePipeline) -> onnx.ModelProto:
    """The pipeline as one ONNX graph: ``window`` (+ model state) -> ``scores`` (+ new state)."""
    problem = export_problem(pipe)
    if problem:
        raise ValueError(f"cannot export this pipeline: {problem}")
    pipe.model.eval()
    states = list(pipe.model.state_names)
    with tempfile.TemporaryDirectory() as tmp:
        enc_path, model_path = Path(tmp) / "enc.onnx", Path(tmp) / "model.onnx"
        dummy = torch.zeros(2, len(pipe.channel_names), pipe.window)
        torch_to_onnx(PipelineEncoderGraph(pipe), (dummy,), enc_path, ["window"], ["spikes"],
                      scripted=pipe.encoder.onnx_scripted)  # fmt: skip
        spikes = torch.rand(2, pipe.n_afferents, pipe.max_spikes) * pipe.duration_ms
        args = (spikes, *(torch.zeros(2, units) for _, units in states))
        names_in = ["spikes_in", *(n for n, _ in states)]
        names_out = ["scores", *(f"{n}_out" for n, _ in states)]
        torch_to_onnx(pipe.model.onnx_module(), args, model_path, names_in, names_out,
                      scripted=pipe.model.onnx_scripted)  # fmt: skip
        return chain(onnx.load(str(enc_path)), onnx.load(str(model_path)),
                     [("spikes", "spikes_in")], tags=("enc/", "model/"))  # fmt: skip


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
    if out.exists() and not out.is_file():
        raise FileExistsError(f"{out} exists and is not a file")
    model = build_graph(pipe)
    meta = {
        "tactilesnn_version": __version__,
        "fs_hz": repr(pipe.fs_hz),
        "window_samples": str(pipe.window),
        "channels": json.dumps(list(pipe.channel_names)),
        "class_names": json.dumps(list(pipe.class_names)),
        "units": "input in the sensor's readout units (see the run's task); scores: "
        + pipe.model.score_units,
        "encoder": pipe.config.encoder_type,
        "model": pipe.config.model_type,
        "state_inputs": json.dumps([n for n, _ in pipe.model.state_names]),
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
    states = list(pipe.model.state_names)
    for name, units in states:
        feeds[name] = np.zeros((len(x), units), np.float32)
    got = sess.run(["scores"], feeds)[0]
    ref = pipe.scores(pipe.encode(x)).numpy()
    diff = float(np.abs(got - ref).max()) if len(x) else 0.0
    agree = float((got.argmax(1) == ref.argmax(1)).mean()) if len(x) else 1.0
    if diff > SCORE_ATOL:
        raise RuntimeError(f"exported graph differs from torch by {diff:.3g} (> {SCORE_ATOL})")
    if states and len(x):
        feeds2 = {k: (v + 0.5 if k != "window" else v) for k, v in feeds.items()}
        if np.array_equal(sess.run(["scores"], feeds2)[0], got):
            raise RuntimeError("exported SNN ignores its state inputs: the state was frozen")
    return {"max_score_diff": diff, "prediction_agreement": agree, "n_checked": len(x)}


def quantize_int8(path: Path, X: np.ndarray, y: np.ndarray, overwrite: bool = False) -> dict:
    """Dynamic int8 quantisation of the MatMul weights; reports the accuracy change on (X, y)."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    from ..service.runtime import PipelineSession

    path = Path(path)
    out = path.with_name(path.stem + ".int8.onnx")
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists; pass --overwrite to replace it")
    quantize_dynamic(str(path), str(out), weight_type=QuantType.QInt8)
    acc = {}
    for name, p in (("float", path), ("int8", out)):
        sess = PipelineSession(str(p))
        acc[name] = float((sess.run(sess.validate(X)).argmax(1) == np.asarray(y)).mean())
    return {
        "path": str(out),
        "float_accuracy": acc["float"],
        "int8_accuracy": acc["int8"],
        "accuracy_change": acc["int8"] - acc["float"],
        "float_bytes": path.stat().st_size,
        "int8_bytes": out.stat().st_size,
    }


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
