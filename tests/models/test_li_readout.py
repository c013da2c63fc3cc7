"""Leaky-integrator readout: traces against a float64 loop, many classes, export parity."""

import numpy as np
import torch

from tactilesnn.config import PipelineConfig
from tactilesnn.models import ReadoutConfig, build_model
from tactilesnn.models.li_readout import trace_features
from tactilesnn.training import Trainer, load_run, train_run


def test_traces_match_a_float64_loop():
    rng = np.random.default_rng(0)
    spikes = rng.uniform(0, 100, (3, 4, 5))
    spikes[rng.random(spikes.shape) < 0.3] = np.inf
    times = np.array([10.0, 50.0, 100.0])
    want = np.zeros((3, 4, 3))
    for b, a, k, j in np.ndindex(3, 4, 5, 3):
        if spikes[b, a, k] <= times[j]:
            want[b, a, j] += np.exp(-(times[j] - spikes[b, a, k]) / 20.0)
    got = trace_features(torch.from_numpy(spikes), torch.from_numpy(times), 20.0)
    np.testing.assert_allclose(got.numpy(), want, rtol=1e-12)


def test_trains_thirty_classes_from_spike_timing():
    # class c: afferents fire at class-specific times (a pattern a count code cannot see)
    rng = np.random.default_rng(1)
    n_cls, a, per = 30, 40, 20
    proto = rng.uniform(0, 500, (n_cls, a, 1))
    y = np.repeat(np.arange(n_cls), per)
    spikes = proto[y] + rng.normal(0, 15, (y.size, a, 1))
    spikes = torch.from_numpy(np.clip(spikes, 0, 500)).float()
    model = build_model(ReadoutConfig(), a, 1, n_cls, 500.0)
    from tactilesnn.config import TrainConfig

    Trainer(model, TrainConfig(epochs=30, batch_size=32)).fit(spikes[::2], y[::2])
    with torch.no_grad():
        acc = float((model.scores(spikes[1::2]).argmax(1).numpy() == y[1::2]).mean())
    assert acc > 0.9


def test_readout_exports_through_the_registry_only(tmp_path):
    small = {"seed": 0, "n_planar": 10, "n_concave": 5, "n_convex": 5, "n_test": 4}
    cfg = PipelineConfig.from_flat(model="readout", epochs=5)
    run, m = train_run("hook_loop", small, cfg, tmp_path / "r", progress=False, export=True)
    assert m["onnx"]["max_score_diff"] <= 1e-4 and m["test_accuracy"] > 0.8
    pipe, _ = load_run(run)
    assert pipe.config.model_type == "readout"
