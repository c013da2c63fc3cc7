"""Event input: the [N, taxels, polarity, bins] file format and the pass-through encoder."""

import numpy as np
import pytest

from tactilesnn.config import PipelineConfig
from tactilesnn.encoders import EventsConfig, build_encoder
from tactilesnn.recordings import load_data_file
from tests.helpers import run_task


def event_file(path, n=60, taxels=6, bins=50, seed=0):
    """Class c: taxel c fires ON events early, the others fire sparse noise."""
    rng = np.random.default_rng(seed)
    y = np.arange(n) % 3
    X = (rng.random((n, taxels, 2, bins)) < 0.02).astype(np.uint8)
    for i, c in enumerate(y):
        X[i, c, 0, 5:15:2] = 1
    np.savez(path, X=X, y=y, bin_ms=2.0, class_names=np.array(["a", "b", "c"]))
    return X, y


def test_event_file_becomes_channels_and_spikes_pass_through(tmp_path):
    event_file(tmp_path / "ev.npz")
    tr, _ = load_data_file(tmp_path / "ev.npz", seed=0)
    assert tr.fs_hz == 500.0 and tr.channel_names[:3] == ("taxel0:on", "taxel0:off", "taxel1:on")
    assert tr.X.shape[1:] == (12, 50)
    enc = build_encoder(EventsConfig(max_spikes=4), tr.fs_hz, 50, 12).fit(tr.X)
    x = np.zeros((1, 12, 50), np.float32)
    x[0, 3, [0, 7, 7, 40]] = [1, 2, 0, 1]  # a count of 2 is two spikes at the same time
    x[0, 3, 7] = 2
    got = enc.encode(x).numpy()
    np.testing.assert_array_equal(got[0, 3], [0.0, 14.0, 14.0, 80.0])
    assert np.isinf(np.delete(got[0], 3, axis=0)).all()
    with pytest.raises(ValueError, match="event counts"):
        build_encoder(EventsConfig(), 500.0, 50, 12).fit(x + 0.5)


@pytest.mark.slow
@pytest.mark.parametrize("model", ["snn", "readout"])
def test_events_train_and_export(tmp_path, model):
    event_file(tmp_path / "ev.npz")
    kw = {"snn_hidden": 32, "snn_dt_ms": 2.0, "snn_lr": 0.01} if model == "snn" else {}
    cfg = PipelineConfig.from_flat(encoder="events", model=model, channels=("all",), epochs=30,
                                   **kw)  # fmt: skip
    _, m = run_task(None, {}, cfg, tmp_path / "r", progress=False, data=tmp_path / "ev.npz",
                       export=True)  # fmt: skip
    assert m["test_accuracy"] >= 0.9
    assert m["onnx"]["model_max_score_diff"] <= 1e-4 and m["onnx"]["encoder_max_time_diff_ms"] == 0


@pytest.mark.slow
def test_data_defaults_follow_the_file(tmp_path):
    import json

    from tactilesnn.cli import main

    event_file(tmp_path / "ev.npz")
    out = tmp_path / "r"
    assert main(["train", "--data", str(tmp_path / "ev.npz"), "--epochs", "2", "--out", str(out),
                 "--quiet", "--no-export"]) == 0  # fmt: skip
    cfg = json.loads((out / "config.json").read_text())["pipeline"]
    assert cfg["encoder"]["type"] == "events" and cfg["channels"] == ["all"]
    assert cfg["model"]["type"] == "readout"


def _shared(rel: str):
    import os
    from pathlib import Path

    roots = [Path(os.environ.get("TACTILESNN_SHARED_DATA", "/nonexistent")),
             Path(__file__).resolve().parents[3] / "shared" / "data", Path("/work/shared/data")]  # fmt: skip
    return next((r / rel for r in roots if (r / rel).is_file()), None)


STM = _shared("st_mnist/st_mnist_events.npz")


@pytest.mark.data
@pytest.mark.skipif(STM is None, reason="real ST-MNIST events not available")
def test_real_st_mnist_events_pass_through_exactly():
    raw = np.load(STM, allow_pickle=False)
    tr, te = load_data_file(STM, seed=0)
    assert tr.y.size == int((raw["split"] == 0).sum()) and te.y.size == 1382
    assert tr.X.shape[1:] == (200, 100) and tr.fs_hz == 1000.0
    x = tr.X[:40]
    enc = build_encoder(EventsConfig(max_spikes=100), 1000.0, 100, 200).fit(x)
    got = enc.encode(x).numpy()
    n_events = (raw["X"][raw["split"] == 0][:40].reshape(40, 200, 100)).sum(-1)
    np.testing.assert_array_equal(np.isfinite(got).sum(-1), n_events)  # every event, once
    b, a, j = np.argwhere(np.isfinite(got))[0]
    assert x[b, a, int(got[b, a, j])] == 1  # at its bin (1 ms bins)


def test_spread_keeps_every_mth_event_so_long_trials_fill_the_slots():
    # afferent 0 fires 40 events over 200 bins in every training window, afferent 1 fires 3
    X = np.zeros((10, 3, 200), np.float32)
    X[:, 0, ::5] = 1
    X[:, 1, [10, 20, 30]] = 1
    enc = build_encoder(EventsConfig(max_spikes=8), 1000.0, 200, 3).fit(X)
    assert enc.every.tolist() == [5.0, 1.0, 1.0]  # ceil(40 / 8); fits; silent
    got = enc.encode(X[:1]).numpy()[0]
    # every 5th event: the 5th, 10th ... 40th, at bins 20, 45, ..., 195 (1 ms bins)
    np.testing.assert_array_equal(got[0], np.arange(20, 200, 25, dtype=np.float32))
    np.testing.assert_array_equal(got[1, :3], [10.0, 20.0, 30.0])
    first = build_encoder(EventsConfig(max_spikes=8, keep="first"), 1000.0, 200, 3).fit(X)
    np.testing.assert_array_equal(first.encode(X[:1]).numpy()[0, 0], np.arange(0, 40, 5))


def test_spread_counts_several_events_in_one_bin():
    x = np.zeros((1, 1, 6), np.float32)
    x[0, 0] = [
        3,
        0,
        1,
        4,
        0,
        2,
    ]  # running count 3, 3, 4, 8, 8, 10: multiples of 2 at bins 0, 2, 3, 5
    enc = build_encoder(EventsConfig(max_spikes=8), 1000.0, 6, 1)
    enc.fit(x)  # median 10 events / 8 slots -> every 2nd
    assert enc.every.item() == 2.0
    np.testing.assert_array_equal(enc.encode(x).numpy()[0, 0, :5], [0.0, 2.0, 3.0, 3.0, 5.0])
