"""The supported ``torch.export``-based exporter (the product's default; the rest of the suite
exports with the TorchScript-based one for speed, see ``tests/conftest.py``): every traced
component and the stream graph, with the same parity checks and no more operator nodes."""

import logging

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from tactilesnn.config import PipelineConfig
from tactilesnn.core.onnx_graph import chosen_exporter, component_to_onnx, operator_nodes
from tactilesnn.export import export_pipeline
from tactilesnn.export.onnx import build_graph
from tactilesnn.export.stream_graph import export_stream, stream_windows
from tactilesnn.pipeline import SpikePipeline
from tactilesnn.service.runtime import PipelineSession


def _calibrated(fs: float, window: int, channels: int, seed: int = 0, **flat):
    cfg = PipelineConfig.from_flat(channels=("all",), **flat)
    names = tuple(f"c{i}" for i in range(channels))
    pipe = SpikePipeline(cfg, fs, window, names, ("x", "y", "z"))
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((24, channels, window)).astype(np.float32)
    X *= rng.uniform(0.2, 3.0, (24, channels, 1)).astype(np.float32)
    if flat.get("encoder") == "events":  # event counts per bin
        X = (np.abs(X) > 1.5).astype(np.float32)
    pipe.calibrate(X)
    return pipe, X


def _opset(model: onnx.ModelProto) -> int:
    return {o.domain: o.version for o in model.opset_import}[""]


#: encoder x model pairs: the activity gate's data-dependent row count, the conv SNN and the LIF
#: population (scripted for the older exporter: their loops as Scan nodes here; bands' default
#: code is the LIF population)
PIPELINES = [
    {"encoder": "delta", "model": "csnn", "csnn_channels": 2},
    {"encoder": "gwt", "model": "tempotron", "gate": 0.5},
    {"encoder": "stft", "model": "readout"},
    {"encoder": "bands", "model": "readout"},
    {"encoder": "events", "model": "snn", "snn_hidden": 8},
    {"encoder": "delta", "model": "snn", "snn_hidden": 8, "snn_recurrent": True},
    {"encoder": "cgwt", "model": "snn", "snn_hidden": 8},
    {"encoder": "lif", "model": "snn", "snn_hidden": 8},
]


@pytest.mark.slow
@pytest.mark.parametrize("flat", PIPELINES, ids=lambda f: f"{f['encoder']}+{f['model']}")
def test_the_supported_exporter_writes_every_traced_component_with_parity(tmp_path, flat):
    pipe, X = _calibrated(400.0, 200, 3, **flat)
    if flat.get("gate"):
        X[:8, 1:] *= 1e-3  # windows with silent channels: the gate drops their rows
    legacy = build_graph(pipe, exporter="torchscript")
    rep = export_pipeline(pipe, tmp_path / "m.onnx", X, exporter="torch.export")  # verified
    model = onnx.load(str(tmp_path / "m.onnx"))
    ops = [n.op_type for n in model.graph.node]
    assert "Loop" not in ops
    assert ("Scan" in ops) == (flat["model"] == "csnn" or flat["encoder"] in ("lif", "bands"))
    assert _opset(model) == 18
    if flat["encoder"] not in ("lif", "bands"):  # (their Scan form reads the slots after the
        # loop, with more nodes outside it and fewer in it than the scripted Loop)
        assert rep["nodes"] <= operator_nodes(legacy)
    assert rep["prediction_agreement"] == 1.0
    session = PipelineSession(str(tmp_path / "m.onnx"))
    # the service batches by the graph's own memory (the LIF code's Scan holds more than eager)
    assert session.contract.bytes_per_window == pipe.graph_bytes_per_window()
    assert (pipe.graph_bytes_per_window() > pipe.bytes_per_window()) == (
        flat["encoder"] in ("lif", "bands")
    )
    got = session.run(X)
    ref = pipe.scores(pipe.encode(X)).numpy()
    assert np.abs(got - ref).max() <= 1e-4 * max(1.0, np.abs(ref).max())


@pytest.mark.slow
def test_a_window_too_long_for_the_histogram_keeps_the_lif_slots_in_the_loop(tmp_path, monkeypatch):
    """Past GRAPH_HISTOGRAM_BYTES per window the LIF graph updates its slots in the loop (memory
    of the slots alone), states the eager bytes, and keeps parity."""
    from tactilesnn.encoders import lif_population

    pipe, X = _calibrated(400.0, 200, 3, encoder="lif", model="readout")
    fast = pipe.graph_bytes_per_window()
    assert not pipe.encoder.graph_slots_in_loop and fast > pipe.bytes_per_window()
    monkeypatch.setattr(lif_population, "GRAPH_HISTOGRAM_BYTES", 1000)
    assert pipe.encoder.graph_slots_in_loop
    assert pipe.graph_bytes_per_window() == pipe.bytes_per_window() < fast
    rep = export_pipeline(pipe, tmp_path / "m.onnx", X, exporter="torch.export")  # verified
    assert rep["prediction_agreement"] == 1.0
    session = PipelineSession(str(tmp_path / "m.onnx"))
    assert session.contract.bytes_per_window == pipe.bytes_per_window()
    nodes = onnx.load(str(tmp_path / "m.onnx")).graph.node
    (scan,) = [n for n in nodes if n.op_type == "Scan"]
    body = next(a.g for a in scan.attribute if a.name == "body")
    assert "ScatterElements" not in {n.op_type for n in nodes}
    assert len(body.node) > 22  # the slots' arithmetic in the body
    ref = pipe.scores(pipe.encode(X)).numpy()
    assert np.abs(session.run(X) - ref).max() <= 1e-4 * max(1.0, np.abs(ref).max())


@pytest.mark.slow
def test_a_part_only_the_older_exporter_writes_is_chained_at_the_newer_opset(tmp_path):
    """A component that cannot trace under torch.export (``onnx_exportable`` False) is written
    by the TorchScript-based exporter (opset 17, Loops) and chained to a torch.export part."""
    pipe, X = _calibrated(400.0, 200, 3, encoder="lif", model="snn", snn_hidden=8)
    pipe.encoder.onnx_exportable = False
    rep = export_pipeline(pipe, tmp_path / "m.onnx", X, exporter="torch.export")  # verified
    model = onnx.load(str(tmp_path / "m.onnx"))
    assert "Loop" in [n.op_type for n in model.graph.node] and _opset(model) == 18
    assert rep["prediction_agreement"] == 1.0


@pytest.mark.slow
def test_the_stream_graph_from_the_supported_exporter_matches_the_legacy_one(tmp_path):
    pipe, X = _calibrated(400.0, 200, 3, encoder="cgwt", model="snn", snn_hidden=8)
    a = export_stream(pipe, tmp_path / "a.onnx", X, exporter="torch.export")
    b = export_stream(pipe, tmp_path / "b.onnx", X, exporter="torchscript")
    assert a["nodes"] <= b["nodes"]
    stream = np.concatenate(list(X[:6]), axis=1)
    ga = stream_windows(onnx.load(str(tmp_path / "a.onnx")), pipe, stream)
    gb = stream_windows(onnx.load(str(tmp_path / "b.onnx")), pipe, stream)
    assert np.abs(ga - gb).max() <= 1e-5 * max(1.0, np.abs(gb).max())


def test_the_exporter_is_chosen_by_name_and_an_unknown_one_is_refused(monkeypatch):
    monkeypatch.delenv("TACTILESNN_ONNX_EXPORTER", raising=False)
    assert chosen_exporter() == "torch.export"
    monkeypatch.setenv("TACTILESNN_ONNX_EXPORTER", "torchscript")
    assert chosen_exporter() == "torchscript"
    assert chosen_exporter("torch.export") == "torch.export"
    monkeypatch.setenv("TACTILESNN_ONNX_EXPORTER", "dynamo")
    with pytest.raises(
        ValueError, match=r"unknown ONNX exporter 'dynamo' \(from TACTILESNN_ONNX_EXPORTER\)"
    ):
        chosen_exporter()


class _DataDependent(torch.nn.Module):
    """A branch on a tensor's value: torch.export cannot trace it, TorchScript traces one side."""

    def forward(self, x):
        if float(x.abs().max()) > 0:
            return x * 2.0
        return x


@pytest.mark.slow
def test_a_component_torch_export_refuses_falls_back_to_the_older_exporter(caplog):
    x = torch.ones(2, 3)
    with caplog.at_level(logging.WARNING, logger="tactilesnn.core.onnx_graph"):
        model = component_to_onnx(_DataDependent(), (x,), ["x"], ["y"], exporter="torch.export")
    assert "torch.export could not export _DataDependent" in caplog.text
    assert _opset(model) == 17  # the TorchScript-based exporter's
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    assert np.allclose(sess.run(None, {"x": x.numpy()})[0], 2.0)
