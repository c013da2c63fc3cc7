"""Whole-pipeline ONNX export: parity with torch for every encoder x model, metadata, state."""

import json

import numpy as np
import onnx
import pytest

from tactilesnn.app.run import load_run
from tactilesnn.cli import main
from tactilesnn.config import PipelineConfig
from tactilesnn.datasets_synth import HookLoopTask
from tactilesnn.export import export_pipeline
from tactilesnn.pipeline import SpikePipeline
from tactilesnn.service.runtime import PipelineSession, StreamState
from tests.helpers import run_task

SMALL = {"seed": 0, "n_planar": 10, "n_concave": 5, "n_convex": 5, "n_test": 4}


#: an untrained SNN on two channels of 100 samples at 200 Hz (calibrated, not fitted)
SMALL_SNN = {"model": "snn", "channels": ("all",), "snn_hidden": 8}


def _calibrated(cfg: PipelineConfig, windows: int, seed: int):
    """An untrained pipeline on ``windows`` random 2 x 100 windows at 200 Hz, calibrated on
    them -> ``(pipe, X)``."""
    pipe = SpikePipeline(cfg, 200.0, 100, ("a", "b"), ("x", "y"))
    X = np.random.default_rng(seed).standard_normal((windows, 2, 100)).astype(np.float32)
    pipe.calibrate(X)
    return pipe, X


@pytest.fixture(scope="session")
def held_out_windows():
    return HookLoopTask(**SMALL).build()[1]


@pytest.mark.slow
@pytest.mark.parametrize("encoder", ["gwt", "stft", "lif"])
@pytest.mark.parametrize("model", ["tempotron", "snn"])
def test_export_parity_on_the_test_split(tmp_path, held_out_windows, encoder, model):
    # the LIF population code needs a shorter tempotron tau
    kw = {"snn_hidden": 16} if model == "snn" else {"tau_ms": 200.0 if encoder == "lif" else 2000.0}
    cfg = PipelineConfig.from_flat(encoder=encoder, model=model, epochs=2, **kw)
    run, _ = run_task("hook_loop", SMALL, cfg, tmp_path / "run", progress=False)
    out = tmp_path / "m.onnx"
    assert main(["export", str(run), "--out", str(out), "--quiet"]) == 0
    onnx.checker.check_model(str(out))
    pipe, _ = load_run(run)
    sess = PipelineSession(str(out))
    got = sess.run(sess.validate(held_out_windows.X))
    ref = pipe.scores(pipe.encode(held_out_windows.X)).numpy()
    assert np.array_equal(got.argmax(1), ref.argmax(1))  # same predictions
    assert np.abs(got - ref).max() <= 1e-4
    meta = sess.metadata
    assert json.loads(meta["class_names"]) == ["hook", "loop"] and float(meta["fs_hz"]) == 200.0
    assert len(meta["training_data_sha256"]) == 64 and meta["encoder"] == encoder
    with pytest.raises(FileExistsError):
        export_pipeline(pipe, out, held_out_windows.X[:2])


@pytest.mark.slow
def test_export_window_normalised_lif_on_a_trial_task(tmp_path):
    kw = {"seed": 0, "n_samples": 36}
    cfg = PipelineConfig.from_flat(encoder="lif", model="snn", epochs=1, snn_hidden=8, channels=("all",),
                         lif_norm="window", lif_lo=0.05, lif_hi=0.8, lif_neurons=3)  # fmt: skip
    run, _ = run_task("stiffness_curvature", kw, cfg, tmp_path / "run", progress=False)
    pipe, _ = load_run(run)
    from tactilesnn.datasets_synth import get_task

    X = get_task("stiffness_curvature", **kw).build()[1].X
    export_pipeline(pipe, tmp_path / "m.onnx", X)  # refuses on a parity failure
    sess = PipelineSession(str(tmp_path / "m.onnx"))
    ref = pipe.scores(pipe.encode(X)).numpy()
    assert np.abs(sess.run(sess.validate(X)) - ref).max() <= 1e-4
    # gain invariance: the window-normalised code gives the same scores at 10x the amplitude
    assert np.allclose(pipe.scores(pipe.encode(10 * X)).numpy(), ref, atol=1e-5)


@pytest.mark.slow
def test_snn_graph_size_does_not_grow_with_time_steps(tmp_path, held_out_windows):
    nodes = []
    for dt in (10.0, 2.5):  # 51 vs 201 time steps
        cfg = PipelineConfig.from_flat(model="snn", epochs=1, snn_hidden=8, snn_dt_ms=dt)
        run, _ = run_task("hook_loop", SMALL, cfg, tmp_path / f"r{dt}", progress=False)
        pipe, _ = load_run(run)
        rep = export_pipeline(pipe, tmp_path / f"m{dt}.onnx", held_out_windows.X[:16])
        nodes.append(rep["nodes"])
    # no node per step: up to 256 steps even the early decision's running maximum is one
    # max-pool (beyond, it grows by a doubling round per factor 2 of the steps)
    assert nodes[1] == nodes[0] and nodes[1] < 500


@pytest.mark.slow
def test_snn_state_is_carried_across_a_stream(tmp_path, held_out_windows):
    cfg = PipelineConfig.from_flat(model="snn", epochs=1, snn_hidden=8)
    run, _ = run_task("hook_loop", SMALL, cfg, tmp_path / "r", progress=False)
    pipe, _ = load_run(run)
    export_pipeline(pipe, tmp_path / "m.onnx", held_out_windows.X[:8])
    sess = PipelineSession(str(tmp_path / "m.onnx"))
    assert sess.stateful
    stream = np.concatenate(list(held_out_windows.X[:6]), axis=1)  # 6 windows back to back
    st = StreamState()
    out = []
    for chunk in np.array_split(stream, 7, axis=1):  # arbitrary chunk boundaries
        out += sess.feed_stream(st, chunk, hop=100)
    assert [r["window_index"] for r in out] == list(range(6))
    assert st.h is not None and np.abs(st.h).sum() >= 0


@pytest.mark.slow
def test_int8_quantisation_reports_accuracy_change(tmp_path, held_out_windows):
    from tactilesnn.export import quantize_int8

    run, _ = run_task(
        "hook_loop", SMALL, PipelineConfig.from_flat(epochs=3), tmp_path / "r", progress=False
    )
    pipe, _ = load_run(run)
    export_pipeline(pipe, tmp_path / "m.onnx", held_out_windows.X[:16])
    q = quantize_int8(tmp_path / "m.onnx", held_out_windows.X, held_out_windows.y)
    # the window-side product (the bulk of the weights) is int8; the GWT's shared-basis
    # product after it stays float32 (quantised per tensor it cost accuracy)
    assert q["int8_bytes"] < 0.75 * q["float_bytes"]
    graph = onnx.load(q["path"]).graph
    weights = {i.name: i for i in graph.initializer}
    window = pipe.window
    by_rows = {}
    for n in graph.node:
        if n.op_type in ("MatMul", "MatMulInteger") and n.input[1] in weights:
            by_rows.setdefault(weights[n.input[1]].dims[0] == window, set()).add(n.op_type)
    assert by_rows[True] == {"MatMulInteger"} and by_rows.get(False, {"MatMul"}) == {"MatMul"}
    assert abs(q["accuracy_change"]) <= 0.05
    assert q["float_accuracy"] == pytest.approx(pipe.score(held_out_windows.X, held_out_windows.y))


@pytest.mark.slow
def test_int8_quantises_the_matmuls_and_keeps_the_scalogram_convs_float(tmp_path):
    """A 2 kHz window whose high GWT bands are strided Convs: those stay float32 (onnxruntime's
    ConvInteger is slower and ~1 % of peak off); the MatMuls are quantised."""
    from tactilesnn.export import quantize_int8

    cfg = PipelineConfig.from_flat(
        model="readout", channels=("all",), f_lo_hz=5.0, f_hi_hz=800.0, gwt_hop=10
    )
    pipe = SpikePipeline(cfg, 2000.0, 1000, ("a", "b"), ("x", "y"))
    X = np.random.default_rng(0).standard_normal((8, 2, 1000)).astype(np.float32)
    pipe.calibrate(X)
    export_pipeline(pipe, tmp_path / "m.onnx", X)
    assert "Conv" in {n.op_type for n in onnx.load(tmp_path / "m.onnx").graph.node}
    q = quantize_int8(tmp_path / "m.onnx", X, np.arange(8) % 2)
    ops = {n.op_type for n in onnx.load(q["path"]).graph.node}
    assert "Conv" in ops and "ConvInteger" not in ops
    assert "DynamicQuantizeMatMul" in ops or "MatMulInteger" in ops


@pytest.mark.slow
def test_verification_checks_each_component_graph(tmp_path, held_out_windows):
    import torch

    from tactilesnn.core.onnx_graph import chain
    from tactilesnn.export.onnx import build_parts, verify

    cfg = PipelineConfig.from_flat(model="snn", epochs=1, snn_hidden=8)
    run, _ = run_task("hook_loop", SMALL, cfg, tmp_path / "r", progress=False)
    pipe, _ = load_run(run)
    X = held_out_windows.X[:32]
    enc, mod = build_parts(pipe)
    whole = chain(enc, mod, [("spikes", "spikes_in")], tags=("enc/", "model/"))
    rep = verify(whole, pipe, X, parts=(enc, mod))
    assert rep["model_max_score_diff"] <= 1e-4 and rep["encoder_max_time_diff_ms"] <= 1e-2
    assert rep["model_windows_beyond_atol"] == 0
    # a run's evaluation coded the test windows already: given, they are not coded again
    spikes, coded = pipe.encode(X), pipe.encode
    pipe.encode = lambda *a, **k: pytest.fail("the given spike times were coded again")
    assert verify(whole, pipe, X, parts=(enc, mod), spikes=spikes) == rep
    with pytest.raises(ValueError, match="spikes for 32 windows on the CPU expected"):
        verify(whole, pipe, X, parts=(enc, mod), spikes=spikes[:5])
    pipe.encode = coded
    # the whole graph gives the encoder's spike times too: two sessions (whole, model), the
    # encoder graph not run a second time on its own
    import tactilesnn.export.onnx as export_onnx

    opened, session = [], export_onnx._session
    monkey = pytest.MonkeyPatch()
    monkey.setattr(export_onnx, "_session", lambda m: opened.append(m) or session(m))
    assert verify(whole, pipe, X, parts=(enc, mod), spikes=spikes) == rep
    monkey.undo()
    assert len(opened) == 2 and [o.name for o in opened[0].graph.output][-1] == "spikes"
    # one window off (a membrane within rounding of threshold flips a spike) is allowed; two are
    # not: the torch scores of windows 0 and 1 are shifted as such a flip would shift them
    plain = pipe.scores

    def shifted(k):
        def scores(spikes):
            out = plain(spikes).clone()
            if len(out) == len(X):
                out[:k] += 0.5
            return out

        return scores

    pipe.scores = shifted(1)
    assert verify(whole, pipe, X, parts=(enc, mod))["model_windows_beyond_atol"] == 1
    pipe.scores = shifted(2)
    with pytest.raises(RuntimeError, match="on 2 of 32 windows"):
        verify(whole, pipe, X, parts=(enc, mod))
    pipe.scores = plain
    with torch.no_grad():  # the torch model drifts from the graph that was built
        pipe.model.net.out.fc.bias += 0.5
    with pytest.raises(RuntimeError, match="exported model differs"):
        verify(whole, pipe, X, parts=(enc, mod))


def test_spike_time_tolerance_grows_for_late_spikes_only():
    from tactilesnn.export.onnx import LATE_SPIKE_FACTOR, ExportError, compare_spike_times

    want = np.array([[10.0, 450.0, np.inf]], np.float32)
    # 0.05 ms off on the late spike (a band ~27 dB down): float32 rounding of a weak amplitude
    dt, flips = compare_spike_times(want + np.float32([0.0, 0.05, 0.0]), want, 500.0, 1e-2)
    assert dt == pytest.approx(0.05, abs=1e-4) and flips == 0
    assert LATE_SPIKE_FACTOR**0.9 * 1e-2 > 0.05
    with pytest.raises(ExportError, match="at 10 ms"):  # the same error on an early spike
        compare_spike_times(want + np.float32([0.05, 0.0, 0.0]), want, 500.0, 1e-2)
    with pytest.raises(ExportError, match="missing"):  # a spike lost mid-window
        compare_spike_times(np.array([[10.0, np.inf, np.inf]], np.float32), want, 500.0, 1e-2)


@pytest.mark.slow
@pytest.mark.parametrize("readout", ["count", "mean"])
def test_snn_readouts_export_as_lstm_nodes_without_loops(tmp_path, held_out_windows, readout):
    """Spiking (count) and leaky (mean) output layers: one LSTM per LIF layer, no Loop."""
    cfg = PipelineConfig.from_flat(model="snn", epochs=1, snn_hidden=8, snn_readout=readout)
    run, _ = run_task("hook_loop", SMALL, cfg, tmp_path / "r", progress=False)
    pipe, _ = load_run(run)
    rep = export_pipeline(pipe, tmp_path / "m.onnx", held_out_windows.X[:16])
    ops = [n.op_type for n in onnx.load(str(tmp_path / "m.onnx")).graph.node]
    assert "Loop" not in ops
    assert ops.count("LSTM") == (2 if readout == "count" else 1)
    assert rep["max_score_diff"] <= 1e-4 and rep["prediction_agreement"] == 1.0


def test_export_refuses_an_empty_verification_batch(tmp_path):
    pipe, X = _calibrated(PipelineConfig.from_flat(**SMALL_SNN), 4, seed=0)
    with pytest.raises(ValueError, match="no window"):
        export_pipeline(pipe, tmp_path / "m.onnx", X[:0])
    assert not (tmp_path / "m.onnx").exists()


@pytest.mark.slow
def test_session_runs_batches_over_its_budget_in_slices_with_the_same_results(tmp_path):
    """One call when the batch fits the memory budget, slices joined when it does not: same
    scores and SNN state either way."""
    pipe, X = _calibrated(PipelineConfig.from_flat(**SMALL_SNN), 10, seed=0)
    export_pipeline(pipe, tmp_path / "m.onnx", X)
    sess = PipelineSession(str(tmp_path / "m.onnx"))
    assert sess.batch >= len(X)
    sliced, whole = StreamState(), StreamState()
    ref = sess.run(X, whole)
    sess.batch = 3  # 4 slices
    got = sess.run(X, sliced)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-5)  # GEMM blocking may round apart
    assert whole.values and set(sliced.values) == set(whole.values)
    for k, v in whole.values.items():
        np.testing.assert_allclose(sliced.values[k], v, rtol=0, atol=1e-5)


@pytest.mark.slow
@pytest.mark.parametrize(("channels", "bands"), [(("b",), 2), (("a", "b"), 20)])
def test_channel_selection_and_clock_afferents_in_the_graph(tmp_path, channels, bands):
    """A channel subset (a selection node) with fewer encoder afferents than clock afferents
    (the clock expanded by size), and every channel in order (no selection node, the clock
    expanded like a slice of the spikes): the graph's scores equal torch's."""
    cfg = PipelineConfig.from_flat(channels=channels, n_bands=bands, stats=("mean",),
                                   clock_afferents=5)  # fmt: skip
    pipe, X = _calibrated(cfg, 6, seed=1)
    assert (pipe.encoder.n_afferents < pipe.n_clock) == (len(channels) == 1)
    export_pipeline(pipe, tmp_path / "m.onnx", X)
    gathers = [n for n in onnx.load(str(tmp_path / "m.onnx")).graph.node
               if n.op_type == "Gather" and "window" in n.input]  # fmt: skip
    assert len(gathers) == (len(channels) == 1)
    got = PipelineSession(str(tmp_path / "m.onnx")).run(X)
    ref = pipe.scores(pipe.encode(X)).numpy()
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-4)


@pytest.mark.slow
def test_session_zero_state_is_kept_per_batch_size_and_never_written(tmp_path):
    """Stateless calls on a stateful graph start from zeros: the arrays are reused while the
    batch size stays, rebuilt when it changes, and read-only (onnxruntime only reads them)."""
    pipe, X = _calibrated(PipelineConfig.from_flat(**SMALL_SNN), 4, seed=2)
    export_pipeline(pipe, tmp_path / "m.onnx", X)
    sess = PipelineSession(str(tmp_path / "m.onnx"))
    three = sess.run(X[:3])
    kept = sess._zeros
    np.testing.assert_array_equal(sess.run(X[:3]), three)
    assert sess._zeros is kept  # same batch size: the same arrays
    one = sess.run(X[:1])
    assert sess._zeros[0] == 1 and sess._zeros is not kept
    np.testing.assert_allclose(one, three[:1], rtol=0, atol=1e-5)
    ref = pipe.scores(pipe.encode(X[:3])).numpy()
    np.testing.assert_allclose(three, ref, rtol=0, atol=1e-4)
    for a in sess._zeros[1].values():
        assert not a.flags.writeable and not a.any()


@pytest.mark.slow
def test_a_stream_run_exports_its_window_and_frame_graphs(tmp_path, held_out_windows):
    cfg = PipelineConfig.from_flat(encoder="frames", model="stream", epochs=1, stream_epochs=1,
                                   stream_hidden=16)  # fmt: skip
    run, _ = run_task("hook_loop", SMALL, cfg, tmp_path / "run", progress=False)
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["frame_stream"]["frame_ms"] == pytest.approx(5.0)  # scored as it runs
    assert metrics["stream_training"]["epochs"] == 1  # and trained on streams
    out = tmp_path / "frames.onnx"
    assert main(["export", str(run), "--frames", "--out", str(out), "--quiet"]) == 0
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert meta["frame_step_samples"] == "1" and meta["encoder"] == "frames"
    # the window graph scores windows as torch does
    pipe, _ = load_run(run)
    export_pipeline(pipe, tmp_path / "m.onnx", held_out_windows.X)
    sess = PipelineSession(str(tmp_path / "m.onnx"))
    got = sess.run(sess.validate(held_out_windows.X))
    ref = pipe.scores(pipe.encode(held_out_windows.X)).numpy()
    assert np.abs(got - ref).max() <= 1e-3
    # --frames writes the frame graph alone: a conflicting option is refused, nothing written
    assert (
        main(["export", str(run), "--frames", "--stream", "--out", str(tmp_path / "x.onnx")]) == 2
    )
    assert not (tmp_path / "x.onnx").exists()
