"""Send-on-delta encoder: against a plain NumPy loop, gain invariance, training and export."""

import numpy as np
import pytest

from tactilesnn.app.run import load_run
from tactilesnn.config import PipelineConfig
from tactilesnn.encoders import DeltaConfig, build_encoder
from tactilesnn.service.runtime import PipelineSession
from tests.helpers import run_task


def reference(x: np.ndarray, delta: np.ndarray, fs: float, k: int) -> np.ndarray:
    """Level crossings sample by sample in float64 (independent of the torch code)."""
    n, c, w = x.shape
    out = np.full((n, 2 * c, k), np.inf)
    for b in range(n):
        for ch in range(c):
            level = np.round(x[b, ch, 0] / delta[ch])
            got = {0: [], 1: []}
            for i in range(1, w):
                new = np.round(x[b, ch, i] / delta[ch])
                side = 0 if new > level else 1
                got[side] += [1000.0 * i / fs] * int(abs(new - level))
                level = new
            for side in (0, 1):
                times = got[side][:k]
                out[b, 2 * ch + side, : len(times)] = times
    return out


def test_matches_reference_and_is_gain_invariant():
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.standard_normal((6, 3, 80)), axis=-1).astype(np.float32)
    x[:, 2] = 5.0  # a constant channel: no spikes, no division by zero
    enc = build_encoder(DeltaConfig(threshold=0.7, max_spikes=5), 500.0, 80, 3).fit(x)
    got = enc.encode(x).numpy()
    want = reference(x.astype(np.float64), enc.delta.double().numpy(), 500.0, 5)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-4)
    assert np.isinf(got[:, 4:]).all()
    big = build_encoder(DeltaConfig(threshold=0.7, max_spikes=5), 500.0, 80, 3).fit(1e6 * x)
    np.testing.assert_array_equal(big.encode(1e6 * x).numpy(), got)
    with pytest.raises(RuntimeError, match="not fitted"):
        build_encoder(DeltaConfig(), 500.0, 80, 3).encode(x)


@pytest.mark.slow
def test_trains_and_exports_through_the_registry_only(tmp_path):
    small = {"seed": 0, "n_planar": 10, "n_concave": 5, "n_convex": 5, "n_test": 4}
    cfg = PipelineConfig.from_flat(encoder="delta", model="snn", channels=("all",), epochs=3,
                                   snn_hidden=16)  # fmt: skip
    run, m = run_task("hook_loop", small, cfg, tmp_path / "r", progress=False, export=True)
    assert m["onnx"]["max_score_diff"] <= 1e-4 and m["test_accuracy"] > 0.5
    pipe, _ = load_run(run)
    from tactilesnn.datasets_synth import HookLoopTask

    X = HookLoopTask(**small).build()[1].X
    sess = PipelineSession(str(run / "model.onnx"))
    assert sess.metadata["encoder"] == "delta"
    np.testing.assert_allclose(sess.run(sess.validate(X)), pipe.scores(pipe.encode(X)).numpy(),
                               atol=1e-4)  # fmt: skip
