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
    with pytest.raises(ValueError, match="do not match"):
        grid_layout(200, "4x3")
    assert grid_layout(85, "10x10", taxels=40) == (2, 10, 10, 5)  # 40 taxels placed on cells
    with pytest.raises(ValueError, match="distinct cells"):
        ConvSNNConfig(grid="2x2", cells=(0, 0))
    with pytest.raises(ValueError, match="distinct cells"):
        ConvSNNConfig(grid="2x2", cells=(0, 4))
    with pytest.raises(ValueError, match="explicit grid"):
        ConvSNNConfig(cells=(0, 1))
    with pytest.raises(ValueError, match="ROWSxCOLS"):
        ConvSNNConfig(grid="ten by ten")


@pytest.mark.parametrize("readout", ["max", "mean"])
def test_scores_equal_a_step_by_step_float64_reference(readout):
    rng = np.random.default_rng(0)
    cfg = ConvSNNConfig(grid="4x4", channels=3, dt_ms=5.0, tau_ms=20.0, readout=readout)
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
        best, total = np.full(4, -np.inf), np.zeros(4)
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
            best, total = np.maximum(best, v), total + v
        want = best if readout == "max" else total / 10
        np.testing.assert_allclose(got[b], want, rtol=1e-4, atol=1e-4)


@pytest.mark.slow
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


def test_shift_augmentation_moves_each_sample_whole_and_only_in_training():
    from tactilesnn.models.conv_snn import random_shift

    torch.manual_seed(0)
    g = torch.rand(3, 40, 2, 5, 6)  # [T, B, P, R, C]
    out = random_shift(g, 1)
    for b in range(40):  # one offset per sample, the same at every step, zeros shifted in
        match = []
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                want = torch.zeros_like(g[:, b])
                src = g[:, b, :, max(0, dr) : 5 + min(0, dr), max(0, dc) : 6 + min(0, dc)]
                want[:, :, max(0, -dr) : 5 + min(0, -dr), max(0, -dc) : 6 + min(0, -dc)] = src
                match.append(bool(torch.equal(out[:, b], want)))
        assert sum(match) == 1
    model = build_model(ConvSNNConfig(grid="4x4", channels=2), 32, 2, 3, 20.0, seed=0)
    spikes = torch.rand(4, 32, 2) * 20
    assert torch.equal(model.scores(spikes), model.scores(spikes))  # inference is deterministic


@pytest.mark.slow
def test_event_files_with_a_taxel_grid_default_to_the_conv_snn(tmp_path, capsys):
    from tactilesnn.recordings import event_layout

    def event_grid(path):
        layout = event_layout(path)
        return None if layout is None else layout[0]

    rng = np.random.default_rng(0)
    X = (rng.random((24, 12, 2, 20)) < 0.1).astype(np.uint8)
    kw = {"y": np.arange(24) % 2, "bin_ms": 1.0, "class_names": np.array(["a", "b"])}
    declared, square, line = tmp_path / "g.npz", tmp_path / "s.npz", tmp_path / "l.npz"
    np.savez(declared, X=X, grid=np.array([3, 4]), **kw)
    np.savez(square, X=X[:, :9], **kw)
    np.savez(line, X=X[:, :7], **kw)
    assert (event_grid(declared), event_grid(square), event_grid(line)) == ("3x4", "3x3", None)
    np.savez(tmp_path / "bad.npz", X=X, grid=np.array([5, 5]), **kw)
    with pytest.raises(ValueError, match="rows x cols = 12"):
        event_grid(tmp_path / "bad.npz")
    for path, model in ((declared, "csnn"), (line, "readout")):
        out = tmp_path / f"r_{path.stem}"
        assert main(["train", "--data", str(path), "--epochs", "1", "--out", str(out),
                     "--quiet", "--no-export"]) == 0  # fmt: skip
        pipe = json.loads((out / "config.json").read_text())["pipeline"]
        assert pipe["model"]["type"] == model
    assert pipe["encoder"]["type"] == "events"
    # a model chosen by the user drops the grid default instead of failing on it
    out = tmp_path / "r_user"
    assert main(["train", "--data", str(declared), "--model", "readout", "--epochs", "1",
                 "--out", str(out), "--quiet", "--no-export"]) == 0  # fmt: skip


@pytest.mark.parametrize("shape", [(3, 4, 10, 10), (2, 3, 2, 6), (1, 2, 4, 4)])
def test_the_halves_pool_is_the_op_s(shape):
    from tactilesnn.models.conv_snn import halves_pool

    x = torch.randn(*shape, dtype=torch.float64)
    ref = torch.nn.functional.avg_pool2d(x, 2, ceil_mode=True)
    torch.testing.assert_close(halves_pool(x), ref, rtol=0, atol=1e-12)
