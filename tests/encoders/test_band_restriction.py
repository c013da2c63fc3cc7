"""Band restriction: bands outside the sensor's passband are not transformed and stay silent,
in torch, in the exported graph and in training's report; the other bands' code is the one a
scalogram of only those bands gives."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tactilesnn.config import PipelineConfig
from tactilesnn.core.onnx_graph import torch_to_onnx
from tactilesnn.encoders.scalogram_latency import (
    GWTConfig,
    GWTLatencyEncoder,
    STFTConfig,
    STFTLatencyEncoder,
)

FS, W = 2000.0, 400


def _windows(n: int = 12) -> np.ndarray:
    rng = np.random.default_rng(0)
    t = np.arange(W) / FS
    x = rng.standard_normal((n, 2, W)) * 0.2
    x += np.sin(2 * np.pi * rng.uniform(20, 300, (n, 2, 1)) * t)
    return x.astype(np.float32)


@pytest.mark.parametrize("kind", ["gwt", "stft"])
def test_bands_outside_the_passband_are_silent_and_the_rest_coded_alone(kind):
    cls, cfg_cls = (GWTLatencyEncoder, GWTConfig) if kind == "gwt" else (
        STFTLatencyEncoder, STFTConfig)  # fmt: skip
    kw = {"f_lo_hz": 5.0, "f_hi_hz": 800.0, "n_bands": 16}
    cut = cls(cfg_cls(**kw, passband_lo_hz=30.0, passband_hi_hz=400.0), FS, W, 2)
    full = cls(cfg_cls(**kw), FS, W, 2)
    inside = (full.freqs_hz >= 30.0) & (full.freqs_hz <= 400.0)
    assert cut.restricted and np.array_equal(cut.kept_bands, np.flatnonzero(inside))
    assert cut.n_afferents == full.n_afferents  # same layout
    x = _windows()
    got = cut.encode(x)[..., 0].reshape(len(x), 2, 2, 16).numpy()  # [n, C, stats, bands]
    assert np.isinf(got[..., ~inside]).all()
    # the transformed bands: the code of a scalogram of those bands only
    lo, hi = full.freqs_hz[inside][[0, -1]]
    only = cls(cfg_cls(f_lo_hz=lo, f_hi_hz=hi, n_bands=int(inside.sum())), FS, W, 2)
    np.testing.assert_allclose(only.freqs_hz, full.freqs_hz[inside], rtol=1e-9)
    ref = only.encode(x)[..., 0].reshape(len(x), 2, 2, -1).numpy()
    np.testing.assert_allclose(got[..., inside], ref, atol=1e-3)
    # skipping off: every band, exactly as without the restriction
    with cut.skipping(False):
        np.testing.assert_array_equal(cut.encode(x).numpy(), full.encode(x).numpy())
    st = cut.skip_stats()["band_restriction"]
    assert st["bands"] == 16 and st["bands_skipped"] == int((~inside).sum()) > 0
    assert st["passband_hz"] == [30.0, 400.0]


@pytest.mark.slow
@pytest.mark.parametrize("gate", [0.0, 0.5])
def test_the_exported_graph_transforms_only_the_passband(tmp_path, gate):
    import onnxruntime as ort

    kw = {"f_lo_hz": 5.0, "f_hi_hz": 800.0, "n_bands": 16, "hop": 10, "gate": gate}
    cut = GWTLatencyEncoder(GWTConfig(**kw, passband_lo_hz=30.0, passband_hi_hz=400.0), FS, W, 2)
    full = GWTLatencyEncoder(GWTConfig(**kw), FS, W, 2)
    x = _windows()
    x[3, 1] *= 1e-3  # a quiet channel for the gate
    cut.fit(x)
    full.fit(x)
    want = cut.encode(x).numpy()
    paths = {}
    for name, enc in (("cut", cut), ("full", full)):
        paths[name] = tmp_path / f"{name}.onnx"
        torch_to_onnx(enc.onnx_module(), (torch.from_numpy(x[:2]),), paths[name], ["window"],
                      ["spikes"])  # fmt: skip
    sess = ort.InferenceSession(str(paths["cut"]), providers=["CPUExecutionProvider"])
    got = sess.run(None, {"window": x})[0]
    assert np.array_equal(np.isinf(got), np.isinf(want))
    fin = np.isfinite(want)
    np.testing.assert_allclose(got[fin], want[fin], atol=1e-3)
    # the graph holds the transformed bands' matrices only: smaller than the full one's
    assert paths["cut"].stat().st_size < 0.8 * paths["full"].stat().st_size


def test_bad_passbands_are_refused():
    with pytest.raises(ValueError, match="passband_hi_hz"):
        GWTConfig(passband_lo_hz=100.0, passband_hi_hz=50.0)
    with pytest.raises(ValueError, match="passband_lo_hz"):
        GWTConfig(passband_lo_hz=-1.0)
    with pytest.raises(ValueError, match="no band centre"):
        GWTLatencyEncoder(GWTConfig(f_lo_hz=5, f_hi_hz=50, passband_lo_hz=100.0), FS, W, 1)


@pytest.mark.slow
def test_training_reports_what_the_restriction_skipped_and_changed(tmp_path):
    from tactilesnn.datasets_synth import HookLoopTask
    from tactilesnn.export import export_pipeline
    from tactilesnn.service.runtime import PipelineSession
    from tactilesnn.training import fit_and_evaluate

    train, test = HookLoopTask(n_planar=10, n_concave=5, n_convex=5, n_test=4).build()
    cfg = PipelineConfig.from_flat(epochs=2, passband_lo_hz=8.0)
    res = fit_and_evaluate(cfg, train, test)
    band = res.metrics["band_restriction"]
    assert band["bands_skipped"] > 0 and min(band["skipped_bands_hz"]) < 8.0
    assert 0 <= band["predictions_changed"] <= 1
    assert "activity_gate" not in res.metrics
    export_pipeline(res.pipeline, tmp_path / "m.onnx", test.X[:32])
    stats = PipelineSession(str(tmp_path / "m.onnx")).info()["stats"]
    assert stats["encoder_bands"] == 20 and stats["encoder_bands_skipped"] == band["bands_skipped"]
