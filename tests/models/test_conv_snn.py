"""Convolutional SNN for taxel arrays: layout, a step-by-step float64 reference, learning, export."""

import json

import numpy as np
import pytest
import torch

from tactilesnn.cli import main
from tactilesnn.models import ConvSNNConfig, build_model
from tactilesnn.models.conv_snn import grid_layout


def test_grid_layout_from_the_afferents():
    assert grid_layout(205, "auto") == (2, 10, 10, 5)  # ST-MNIST: 10 x 10 ON/OFF + 5 clocks
    assert grid_layout(200, "auto") == (2, 10, 10, 0)
    assert grid_layout(100, "auto") == (1, 10, 10, 0)  # an exact fit beats 7 x 7 x 2 + 2
    assert grid_layout(50, "auto") == (2, 5, 5, 0)
    assert grid_layout(24, "4x3") == (2, 4, 3, 0)
    assert grid_layout(12, "4x3") == (1, 4, 3, 0)
    with pytest.raises(ValueError, match="square taxel grid"):
        grid_layout(3, "auto")
    with pytest.raises(ValueError, match="does not match"):
        grid_layout(200, "4x3")
    with pytest.raises(ValueError, match="ROWSxCOLS"):
        ConvSNNConfig(grid="ten by ten")


def test_scores_equal_a_step_by_step_float64_reference():
    rng = np.random.default_rng(0)
    cfg = ConvSNNConfig(grid="4x4", channels=3, dt_ms=5.0, tau_ms=20.0)
    model = build_model(cfg, 2 * 16 + 1, 3, 4, 50.0, seed=1)
    with torch.no_grad():  # large weights so that both layers spike
        for p in model.parameters():
            p.mul_(4.0)
    spikes = rng.uniform(0, 50, (2, 33, 3)).astype(np.float32)
    spikes[rng.random(spikes.shape) < 0.5] = np.inf
    got = model.scores(torch.from_numpy(spikes)).detach().numpy()

    c = model.core
    beta = np.exp(-5.0 / 20.0)
    w1, b1 = c.conv1.weight.detach().double(), c.conv1.bias.detach().double()
    w2, b2 = c.conv2.weight.detach().double(), c.conv2.bias.detach().double()
    wo, bo = c.out.weight.detach().double().numpy(), c.out.bias.detach().double().numpy()
    for b in range(2):
        u1, u2, v = np.zeros((3, 4, 4)), np.zeros((6, 2, 2)), np.zeros(4)
        best = np.full(4, -np.inf)
        for t in range(10):
            counts = ((spikes[b] >= 5 * t) & (spikes[b] < 5 * (t + 1))).sum(-1).astype(float)
            img = np.zeros((2, 4, 4))
            for taxel in range(16):  # taxel-major, row-major taxels, polarities interleaved
                for pol in range(2):
                    img[pol, taxel // 4, taxel % 4] = counts[2 * taxel + pol]
            cur1 = torch.nn.functional.conv2d(torch.from_numpy(img)[None], w1, b1, padding=1)[0]
            u1 = beta * u1 + cur1.numpy()
            s1 = (u1 >= 1.0).astype(float)
            u1 = u1 - s1
            pooled = s1.reshape(3, 2, 2, 2, 2).mean(axis=(2, 4))
            cur2 = torch.nn.functional.conv2d(torch.from_numpy(pooled)[None], w2, b2, padding=1)[0]
            u2 = beta * u2 + cur2.numpy()
            s2 = (u2 >= 1.0).astype(float)
            u2 = u2 - s2
            v = beta * v + wo @ np.concatenate([s2.ravel(), counts[32:]]) + bo
            best = np.maximum(best, v)
        np.testing.assert_allclose(got[b], best, rtol=1e-4, atol=1e-4)


def test_learns_where_on_the_array_the_touch_is_and_exports(tmp_path, capsys):
    """Event file, 6 x 6 taxels: the class is the quadrant that fires. Trained through
    ``--data`` (events encoder by default), exported to ONNX with parity checked."""
    rng = np.random.default_rng(0)
    n, side, bins = 160, 6, 40
    y = np.arange(n) % 4
    X = (rng.random((n, side * side, 2, bins)) < 0.01).astype(np.uint8)  # background events
    for i, c in enumerate(y):
        r0, c0 = 3 * (c // 2), 3 * (c % 2)
        for r in range(r0, r0 + 3):
            for col in range(c0, c0 + 3):
                X[i, r * side + col, 0] |= (rng.random(bins) < 0.3).astype(np.uint8)
    data = tmp_path / "touch_events.npz"
    np.savez(data, X=X, y=y, bin_ms=1.0, class_names=np.array(["tl", "tr", "bl", "br"]))
    out = tmp_path / "r"
    assert main(["train", "--data", str(data), "--model", "csnn", "--epochs", "6",
                 "--out", str(out), "--quiet"]) == 0  # fmt: skip
    m = json.loads((out / "metrics.json").read_text())
    assert m["test_accuracy"] > 0.9
    assert m["onnx"]["model_max_score_diff"] < 1e-4 and m["onnx"]["prediction_agreement"] == 1.0
