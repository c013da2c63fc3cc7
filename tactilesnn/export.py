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
from .models.snn import reduce_readout
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


class _LIFEncoderGraph(nn.Module):
    """The LIF-population code as a scripted loop (samples x at most k spikes per sample).

    Same arithmetic as :func:`~tactilesnn.encoders.spiking.lif_convert` with subtract reset and
    threshold 1 (exact crossings inside each held sample); only the first ``k`` spike times of each
    converter are kept, so at most ``k`` crossings per sample can matter.
    """

    def __init__(self, pipe: SpikePipeline) -> None:
        super().__init__()
        cfg = pipe.config
        self.register_buffer("channel_idx", torch.as_tensor(pipe.channel_idx, dtype=torch.long))
        self.register_buffer("ref", pipe.lif_ref.float())
        thr = np.geomspace(cfg.lif_lo, cfg.lif_hi, cfg.lif_neurons)
        self.register_buffer("inv_thr", torch.as_tensor(1.0 / thr, dtype=torch.float32))
        self.k = int(cfg.lif_max_spikes)
        self.dt = 1000.0 / pipe.fs_hz
        self.tau = float(cfg.lif_tau_ms)
        # 1.0 = scale each window by its peak |x| (lif_norm "window"), 0.0 = by the training RMS
        self.register_buffer("window_norm", torch.tensor(float(cfg.lif_norm == "window")))
        n = cfg.clock_afferents
        clock = torch.full((n, self.k), float("inf"))
        clock[:, 0] = torch.arange(n, dtype=torch.float32) * (pipe.duration_ms / max(n, 1))
        self.register_buffer("clock", clock)

    def forward(self, x: Tensor) -> Tensor:
        x = torch.index_select(x, 1, self.channel_idx)
        peak = x.abs().amax(dim=(1, 2), keepdim=True).clamp_min(1e-30)
        scale = self.window_norm * peak + (1.0 - self.window_norm) * self.ref.view(1, -1, 1)
        x = x / scale
        drive = (x.unsqueeze(2) * self.inv_thr.view(1, 1, -1, 1)).flatten(1, 2)  # [N, A, W]
        n, a = drive.shape[0], drive.shape[1]
        v = torch.zeros(n, a)
        count = torch.zeros(n, a)
        times = torch.full((n, a, self.k), float("inf"))
        slots = torch.arange(self.k, dtype=torch.float32).view(1, 1, -1)
        inf = torch.full((n, a), float("inf"))
        for i in range(drive.shape[2]):
            vi = drive[:, :, i]
            rem = torch.full((n, a), self.dt)
            for _ in range(self.k):
                above = v >= 1.0
                ratio = (v - vi) / (1.0 - vi)
                s = torch.where(
                    above, torch.zeros_like(v), self.tau * torch.log(ratio.clamp_min(1e-30))
                )
                fires = (above | (vi > 1.0)) & (s <= rem) & (rem > 0)
                s = torch.where(fires, s, inf)
                t_abs = i * self.dt + (self.dt - rem) + s
                record = fires & (count < self.k)
                hit = (slots == count.unsqueeze(-1)) & record.unsqueeze(-1)
                times = torch.where(hit, t_abs.unsqueeze(-1), times)
                count = count + fires.to(count.dtype)
                quiet = (~fires) & (rem > 0)
                decayed = vi + (v - vi) * torch.exp(-rem / self.tau)
                v = torch.where(fires, torch.maximum(v, torch.ones_like(v)) - 1.0, v)
                v = torch.where(quiet, decayed, v)
                rem = torch.where(fires, rem - s, torch.where(quiet, torch.zeros_like(rem), rem))
        return torch.cat([times, self.clock.unsqueeze(0).expand(n, -1, -1)], dim=1)


class _ModelOnSpikes(nn.Module):
    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, spikes: Tensor) -> Tensor:
        return self.model(spikes)[0]


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
        if spikes.dim() == 2:
            spikes = spikes.unsqueeze(-1)
        bins = torch.floor(spikes / self.dt)  # [B, A, K]; inf never matches a step
        steps = torch.arange(self.steps, dtype=spikes.dtype)
        raster = (bins.unsqueeze(0) == steps.view(-1, 1, 1, 1)).to(spikes.dtype).sum(-1)
        hs, h_new = self.l1(self.fc1(raster), h)
        os_, o_new = self.l2(self.fc2(hs), o)
        return reduce_readout(os_, self.readout), h_new, o_new


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
    pipe.model.eval()
    n_ch = len(pipe.channel_names)
    dummy = torch.zeros(2, n_ch, pipe.window)
    with tempfile.TemporaryDirectory() as tmp:
        enc_path = Path(tmp) / "enc.onnx"
        batch = {0: "batch"}
        lif = pipe.config.encoder == "lif"
        if pipe.config.model == "tempotron" and not lif:
            full_path = Path(tmp) / "full.onnx"
            _torch_export(
                _TempotronGraph(pipe), (dummy,), full_path, ["window"], ["scores"],
                {"window": batch, "scores": batch},
            )  # fmt: skip
            model = onnx.load(str(full_path))
        else:
            encoder = torch.jit.script(_LIFEncoderGraph(pipe)) if lif else _EncoderGraph(pipe)
            _torch_export(
                encoder, (dummy,), enc_path, ["window"], ["spikes"],
                {"window": batch, "spikes": batch},
            )  # fmt: skip
            model_path = Path(tmp) / "model.onnx"
            shape = (2, pipe.n_afferents, pipe.max_spikes) if lif else (2, pipe.n_afferents)
            if pipe.config.model == "tempotron":
                spikes = torch.rand(shape) * pipe.duration_ms
                _torch_export(
                    _ModelOnSpikes(pipe.model), (spikes,), model_path, ["spikes_in"], ["scores"],
                    {"spikes_in": batch, "scores": batch},
                )  # fmt: skip
            else:
                hid, ncls = pipe.model.hidden.fc.out_features, len(pipe.class_names)
                names_in = ["spikes_in", "h_state", "o_state"]
                names_out = ["scores", "h_state_out", "o_state_out"]
                _torch_export(
                    torch.jit.script(_SNNGraph(pipe)),
                    (torch.zeros(shape), torch.zeros(2, hid), torch.zeros(2, ncls)),
                    model_path, names_in, names_out,
                    {k: batch for k in names_in + names_out},
                )  # fmt: skip
            model = _merge(enc_path, model_path)
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


def _merge(enc_path: Path, model_path: Path) -> onnx.ModelProto:
    """Chain the encoder graph (output ``spikes``) into the model graph (input ``spikes_in``)."""
    enc = onnx.compose.add_prefix(
        onnx.load(str(enc_path)), "enc/", rename_inputs=False, rename_outputs=False
    )
    mod = onnx.compose.add_prefix(
        onnx.load(str(model_path)), "model/", rename_inputs=False, rename_outputs=False
    )
    return onnx.compose.merge_models(enc, mod, io_map=[("spikes", "spikes_in")])


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


def quantize_int8(path: Path, X: np.ndarray, y: np.ndarray, overwrite: bool = False) -> dict:
    """Dynamic int8 quantisation of the MatMul weights; reports the accuracy change on (X, y)."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    from .service.runtime import PipelineSession

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
