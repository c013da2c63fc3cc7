"""The stream graph (a step per call, default half a window; every sample transformed once)
against torch, the window graph and the service runtime's stream path."""

import json

import numpy as np
import onnx
import pytest

from tactilesnn.cli import main
from tactilesnn.config import PipelineConfig
from tactilesnn.export import export_pipeline
from tactilesnn.export.stream_graph import build_stream_graph, export_stream, stream_windows
from tactilesnn.pipeline import SpikePipeline
from tactilesnn.service.runtime import InputError, PipelineSession, StreamState

FS, WINDOW = 1000.0, 200
CHANNELS = ("a", "b", "c")


def _pipe(model="snn", **kw):
    flat = {"encoder": "cgwt", "model": model, "channels": ("all",), "f_lo_hz": 5.0,
            "f_hi_hz": 300.0, **kw}  # fmt: skip
    if flat["encoder"] == "cgwt":
        flat.setdefault("cgwt_hop", 4)
    pipe = SpikePipeline(PipelineConfig.from_flat(**flat), FS, WINDOW, CHANNELS, ("x", "y"))
    pipe.calibrate(_windows(8, seed=1))
    return pipe


def _windows(n, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(WINDOW) / FS
    f = rng.uniform(10, 200, (n, len(CHANNELS), 1))
    x = np.sin(2 * np.pi * f * t) * rng.uniform(0.2, 3, (n, len(CHANNELS), 1))
    return (x + 0.3 * rng.standard_normal(x.shape) + 5.0).astype(np.float32)


@pytest.mark.slow
@pytest.mark.parametrize("model,level", [("tempotron", 0), ("snn", 0), ("readout", 2)])
def test_stream_graph_matches_torch_on_a_stream(tmp_path, model, level):
    pipe = _pipe(model, level_neurons=level)  # the level code reads the window: one more state
    rep = export_stream(pipe, tmp_path / "s.onnx", _windows(20))
    assert rep["windows_checked"] == 39 and rep["prediction_agreement"] == 1.0
    assert rep["encoder_max_time_diff_ms"] < 1e-2 and rep["encoder_cutoff_flips"] == 0
    meta = {p.key: p.value for p in onnx.load(tmp_path / "s.onnx").metadata_props}
    assert meta["stream_step_samples"] == str(WINDOW // 2)
    assert json.loads(meta["stream_state_init"]) == {"cgwt_extent": "repeat_first"}
    assert ("stream_prev" in json.loads(meta["stream_encoder_states"])) == (level > 0)
    with pytest.raises(FileExistsError, match="--overwrite"):  # nothing replaced silently
        export_stream(pipe, tmp_path / "s.onnx", _windows(20))


@pytest.mark.slow
def test_runtime_classifies_and_streams_with_the_stream_graph(tmp_path):
    pipe = _pipe("snn")
    X = _windows(6, seed=3)
    export_pipeline(pipe, tmp_path / "w.onnx", X)
    export_stream(pipe, tmp_path / "s.onnx", X)
    win, stream = (
        PipelineSession(str(tmp_path / "w.onnx")),
        PipelineSession(str(tmp_path / "s.onnx")),
    )
    # a window from a fresh state is the window graph's transform exactly (constant past), in
    # any units: 1e-30 farads or 1e30 pascals (the window graph divides samples by their peak;
    # the stream graph cannot, and takes the modulus and the code's squares scale-safely)
    for scale in (1.0, 1e-30, 1e30):
        assert np.abs(stream.run(X * scale) - win.run(X * scale)).max() < 1e-4, scale
    assert stream.classify(X[0])["classes"] == win.classify(X[0])["classes"]
    joined = np.concatenate(list(X), axis=1)
    st, results = StreamState(), []
    for i in range(0, joined.shape[1], 37):  # chunks unrelated to the step
        results += stream.feed_stream(st, joined[:, i : i + 37])
    assert [r["window_index"] for r in results] == list(range(2 * len(X) - 1))
    model, _, _ = build_stream_graph(pipe)
    want = stream_windows(model, pipe, joined)  # every state carried, as the service does
    got = np.array([r["scores"] for r in results])
    assert np.abs(got - want).max() < 1e-5
    assert np.abs(got[0] - win.run(X[:1])[0]).max() < 1e-4
    with pytest.raises(InputError, match="every 100 samples"):
        stream.feed_stream(StreamState(), joined[:, :50], hop=40)


@pytest.mark.slow
def test_stream_graph_refusals(tmp_path):
    with pytest.raises(ValueError, match="no stream form"):
        build_stream_graph(_pipe("tempotron", encoder="gwt"))
    with pytest.raises(ValueError, match="activity gate"):
        build_stream_graph(_pipe("tempotron", gate=0.5))
    with pytest.raises(ValueError, match="whole number of hops"):
        build_stream_graph(_pipe("tempotron", cgwt_hop=3))
    # a tampered step is refused when the graph is loaded, not at the first request
    pipe = _pipe("tempotron")
    path = tmp_path / "s.onnx"
    export_stream(pipe, path, _windows(4))
    m = onnx.load(path)
    for p in m.metadata_props:
        if p.key == "stream_step_samples":
            p.value = "60"
    onnx.save(m, tmp_path / "bad.onnx")
    with pytest.raises(ValueError, match="does not divide the window"):
        PipelineSession(str(tmp_path / "bad.onnx"))
    for step in (3, 30, 120, 200):  # not whole hops (4); not dividing 200; over half of it
        with pytest.raises(ValueError, match=r"does not fit.*these fit: 4, 8, 20, 40, 100\)"):
            build_stream_graph(pipe, step=step)


@pytest.mark.slow
def test_cli_exports_the_stream_graph_of_a_cgwt_run(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["train", "--encoder", "cgwt", "--epochs", "1", "--quiet", "--task-kw",
                 "n_planar=4", "--task-kw", "n_concave=2", "--task-kw", "n_convex=2", "--task-kw",
                 "n_test=2", "--out", "run"]) == 0  # fmt: skip
    assert "tactilesnn export run --stream --out run/stream.onnx" in capsys.readouterr().out
    assert main(["export", "run", "--stream", "--out", "s.onnx", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "every sample transformed once" in out and "predictions agree 100.00 %" in out
    assert main(["export", "run", "--stream", "--quantize", "--out", "q.onnx", "--quiet"]) == 2
    assert "drop --quantize" in capsys.readouterr().err
    assert main(["export", "run", "--stream-step", "10", "--out", "q.onnx", "--quiet"]) == 2
    assert "add --stream" in capsys.readouterr().err
    assert main(["export", "run", "--stream", "--stream-step", "7", "--out", "q.onnx"]) == 2
    assert "does not fit" in capsys.readouterr().err and not (tmp_path / "q.onnx").exists()
    from tactilesnn.app.run import load_run

    hop = load_run(tmp_path / "run")[0].encoder.hop
    assert main(["export", "run", "--stream", "--stream-step", str(hop), "--out", "f.onnx",
                 "--quiet"]) == 0  # fmt: skip
    assert f"{hop} samples = " in capsys.readouterr().out


@pytest.mark.slow
def test_stream_graph_is_built_by_the_supported_exporter_with_a_fallback(tmp_path, monkeypatch):
    import tactilesnn.core.onnx_graph as graph_mod

    monkeypatch.setenv("TACTILESNN_ONNX_EXPORTER", "torch.export")  # the product's default
    pipe = _pipe("tempotron")
    calls = []
    real = graph_mod.exported_to_onnx

    def spy(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(graph_mod, "exported_to_onnx", spy)
    a = export_stream(pipe, tmp_path / "a.onnx", _windows(6))
    assert len(calls) == 2  # both parts torch.export-based (onnxscript comes with the package)

    def missing(*a, **k):
        raise ImportError("No module named 'onnxscript'")

    monkeypatch.setattr(graph_mod, "exported_to_onnx", missing)
    b = export_stream(pipe, tmp_path / "b.onnx", _windows(6))  # the TorchScript exporter instead
    assert a["prediction_agreement"] == b["prediction_agreement"] == 1.0
    assert a["nodes"] <= b["nodes"]


@pytest.mark.slow
@pytest.mark.parametrize("level", [0, 2])
def test_any_step_matches_torch_and_the_runtime(tmp_path, level):
    """A window ending every step (one hop = one frame, or 40 samples): the exported graph
    against torch's bank over the whole stream, and the service runtime on it."""
    pipe = _pipe("snn", level_neurons=level)
    X = _windows(6, seed=3)
    export_pipeline(pipe, tmp_path / "w.onnx", X)
    joined = np.concatenate(list(X), axis=1)
    for step in (4, 40):
        rep = export_stream(pipe, tmp_path / f"s{step}.onnx", X, step=step)
        n = joined.shape[1] // step - WINDOW // step + 1  # a window ends every step
        assert rep["step_samples"] == step and rep["windows_checked"] == n
        assert rep["prediction_agreement"] == 1.0 and rep["encoder_cutoff_flips"] == 0
        assert rep["encoder_max_time_diff_ms"] < 1e-2
        sess = PipelineSession(str(tmp_path / f"s{step}.onnx"))
        win = PipelineSession(str(tmp_path / "w.onnx"))
        assert np.abs(sess.run(X) - win.run(X)).max() < 1e-4  # whole windows, step by step
        st, results = StreamState(), []
        for i in range(0, joined.shape[1], 37):  # chunks unrelated to the step
            results += sess.feed_stream(st, joined[:, i : i + 37], detail=True)
        assert [r["window_index"] for r in results] == list(range(n))
        model, _, _ = build_stream_graph(pipe, step=step)
        got = np.array([r["scores"] for r in results])
        assert np.abs(got - stream_windows(model, pipe, joined)).max() < 1e-5
        for k in (0, n // 2, n - 1):  # the window each result classifies
            assert np.array_equal(results[k]["window"], joined[:, k * step : k * step + WINDOW])


@pytest.mark.slow
def test_one_hop_steps_give_a_frame_s_spikes_after_its_last_sample(tmp_path):
    """Latency: with one hop per call, a burst in a frame changes the spikes of the call that
    takes that frame's samples (the window ending with it) and of no call before it."""
    pipe = _pipe("snn")
    hop = pipe.encoder.hop
    model, _, _ = build_stream_graph(pipe, step=hop)
    joined = np.concatenate(list(_windows(3, seed=5)), axis=1)
    burst = joined.copy()
    at = (
        2 * WINDOW + 7 * hop + 1
    )  # a sample inside frame 57 (frame k: samples [k hop, k hop + hop))
    burst[:, at : at + 2] += 40.0
    t0, _ = stream_windows(model, pipe, joined, spikes=True)
    t1, _ = stream_windows(model, pipe, burst, spikes=True)
    first = WINDOW // hop - 1  # the first call that completes a window
    call = at // hop  # the call that takes the burst's first sample
    changed = np.flatnonzero((t0 != t1).reshape(len(t0), -1).any(1)) + first
    assert changed.min() == call  # nothing before the burst's frame; its own call at once
