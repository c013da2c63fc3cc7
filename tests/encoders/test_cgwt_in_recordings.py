"""The cgwt encoder on recordings: windows coded with their past (as the stream graph serves
them), the level taken off before the bank (constant channels silent), and training on both
codes."""

import json

import numpy as np
import pytest
import torch

from tactilesnn.cli import main
from tactilesnn.config import PipelineConfig
from tactilesnn.core.data import join_run, recording_runs
from tactilesnn.export.stream_graph import export_stream
from tactilesnn.pipeline import SpikePipeline

FS, WINDOW = 1000.0, 200


def _pipe(channels=("a", "b", "c"), **kw):
    cfg = PipelineConfig.from_flat(encoder="cgwt", model="tempotron", channels=("all",),
                                   f_lo_hz=5.0, f_hi_hz=300.0, cgwt_hop=4, **kw)  # fmt: skip
    return SpikePipeline(cfg, FS, WINDOW, channels, ("x", "y"))


def _recording(samples, seed=0, channels=3):
    rng = np.random.default_rng(seed)
    t = np.arange(samples) / FS
    f = rng.uniform(10, 200, (channels, 1))
    x = np.sin(2 * np.pi * f * t) * (1 + 0.5 * np.sin(2 * np.pi * 3 * t))
    return (x + 0.2 * rng.standard_normal(x.shape) + 5.0).astype(np.float32)


def _cut(rec, shift):
    n = (rec.shape[1] - WINDOW) // shift + 1
    return np.stack([rec[:, k * shift : k * shift + WINDOW] for k in range(n)])


def test_recording_runs_find_windows_that_tile_a_recording():
    a, b = _recording(1000, seed=1), _recording(700, seed=2)
    wa, wb = _cut(a, 100), _cut(b, 40)
    trials = np.stack([_recording(WINDOW, seed=s) for s in range(3)])  # independent windows
    broken = _cut(_recording(600, seed=3), 100)  # 5 windows
    broken[2, 0, -1] += 1.0  # one sample off: windows 0-2 tile, 3-4 tile, 2-3 do not
    X = np.concatenate([wa, trials, wb, broken])
    scan = np.repeat([0, 1, 2, 3], [len(wa), len(trials), len(wb), len(broken)])
    runs = recording_runs(X, scan)
    n0 = len(wa) + 3 + len(wb)
    assert [(list(i), s) for i, s in runs] == [
        (list(range(len(wa))), 100),
        (list(range(len(wa) + 3, n0)), 40),
        ([n0, n0 + 1, n0 + 2], 100),
        ([n0 + 3, n0 + 4], 100),
    ]
    assert np.array_equal(join_run(X, *runs[0]), a[:, : WINDOW + 100 * (len(wa) - 1)])
    assert np.array_equal(join_run(X, *runs[1]), b[:, : WINDOW + 40 * (len(wb) - 1)])


@pytest.mark.slow
def test_the_level_is_taken_off_and_a_constant_channel_is_silent():
    """A status column stuck at 65,535 is silent (it was float32 rounding coded as spikes,
    differently in torch, onnxruntime and float64), and the same ripple on a large level is
    coded as without it."""
    pipe = _pipe()
    x = np.stack([_recording(WINDOW, seed=s) for s in range(6)])
    x[:, 1] = 65535.0
    x[:, 2] = x[:, 0] - 5.0 + 30000.0  # channel 0's ripple on a large level
    pipe.calibrate(x)
    s32 = pipe.encoder.encode(x)[:, :, 0].reshape(6, 3, -1)
    assert torch.isinf(s32[:, 1]).all()
    assert torch.equal(torch.isinf(s32[:, 2]), torch.isinf(s32[:, 0]))
    both = torch.isfinite(s32[:, 0])
    # float32 holds 30,000 + ripple to ~2e-3: the inputs differ by that rounding, no more
    assert (s32[:, 2][both] - s32[:, 0][both]).abs().max() < 0.5  # ms of 500
    enc64 = pipe.encoder.double()
    s64 = enc64.encode_batch(torch.from_numpy(x.astype(np.float64)))[:, :, 0].reshape(6, 3, -1)
    assert torch.equal(torch.isinf(s64), torch.isinf(s32))  # no flips against float64
    fin = torch.isfinite(s64)
    assert (s64[fin] - s32[fin].double()).abs().max() < 1e-2  # on the same (float32) input
    huge = np.where(np.arange(WINDOW) % 2, 3.4e38, -3.4e38).astype(np.float32)
    x[:, 0] = huge  # the float32 extremes: differences taken halved, no overflow
    assert not torch.isnan(pipe.encoder.encode(x)).any()
    # the stream graph codes it alike (its export compares it with torch in float64)
    pipe = _pipe()
    X = np.stack([_recording(WINDOW, seed=s) for s in range(8)])
    X[:, 1] = 65535.0
    pipe.calibrate(X)
    rep = export_stream(pipe, _tmp() / "s.onnx", X)
    assert rep["encoder_cutoff_flips"] == 0 and rep["prediction_agreement"] == 1.0


def _tmp():
    import tempfile
    from pathlib import Path

    return Path(tempfile.mkdtemp())


@pytest.mark.slow
def test_windows_with_their_past_are_the_stream_graph_s():
    pipe = _pipe()
    rec = _recording(1400, seed=4)
    pipe.calibrate(_cut(rec, 100))
    half = WINDOW // 2
    starts = half * np.arange((rec.shape[1] - WINDOW) // half + 1)
    got = pipe.encoder.encode_recording(rec, starts)
    want = pipe.encoder.stream_reference(torch.from_numpy(rec[None].astype(np.float64)), half)
    fin = torch.isfinite(want)
    assert torch.equal(torch.isfinite(got), fin)
    assert (got[fin] - want[fin]).abs().max() < 1e-2  # ms: float32 against float64
    alone = pipe.encoder.encode(_cut(rec, half))
    assert (got[0] - alone[0])[torch.isfinite(alone[0])].abs().max() < 1e-2  # no past: alike
    later = torch.isfinite(got[1:]) != torch.isfinite(alone[1:])
    moved = (got[1:] - alone[1:])[torch.isfinite(got[1:]) & torch.isfinite(alone[1:])].abs()
    assert later.any() or moved.max() > 1.0  # with a past the code differs (the bank rings)
    odd = pipe.encoder.encode_recording(rec, [3, 57])  # off the frame grid: its own phase
    ref = pipe.encoder.encode_recording(rec[:, 3:], [0])
    assert (odd[0] - ref[0])[torch.isfinite(ref[0])].abs().max() < 1e-2


def test_recordings_coded_together_are_each_coded_alone():
    """:meth:`encode_recordings` runs recordings through the bank together (in batches of a
    byte budget, each padded to its batch's longest); each one's code is what it gets alone."""
    pipe = _pipe()
    recs = [_recording(900, seed=s) for s in range(5)] + [_recording(700, seed=9)]
    pipe.calibrate(_cut(recs[0], 100))
    starts = [[100, 350, 500]] * 4 + [[0, 101]] + [[200, 498]]  # phases 0, 2, 1 of hop 4
    enc = pipe.encoder
    for budget in (1 << 26, 1):  # all together / one at a time
        got = enc.encode_recordings(recs, starts, budget_bytes=budget)
        for r, s, g in zip(recs, starts, got, strict=True):
            want = enc.encode_recording(r, s)
            assert g.shape == want.shape == (len(s), enc.n_afferents, 1)
            assert torch.equal(torch.isfinite(g), torch.isfinite(want))
            fin = torch.isfinite(want)
            assert (g[fin] - want[fin]).abs().max() < 1e-3  # ms: float rounding only
    with pytest.raises(ValueError, match="2 recordings but 1"):
        enc.encode_recordings(recs[:2], starts[:1])
    with pytest.raises(ValueError, match="do not all lie"):
        enc.encode_recordings(recs[:1], [[850]])
    with pytest.raises(ValueError, match=r"\[3 channels, samples\], got shape \(2, 900\)"):
        enc.encode_recordings([recs[0][:2]], [[0]])


@pytest.mark.slow
def test_training_on_recordings_learns_both_codes(tmp_path, capsys):
    rng = np.random.default_rng(0)
    y = np.arange(12) % 2
    t = np.arange(1200) / FS
    X = np.stack([[np.sin(2 * np.pi * (20 + 60 * c) * t) + 0.3 * rng.standard_normal(t.size)]
                  for c in y]).astype(np.float32)  # fmt: skip
    data = tmp_path / "long.npz"
    np.savez(data, X=X, y=y, fs=FS, class_names=np.array(["a", "b"]))
    common = ["--data", str(data), "--data-window-s", "0.2", "--data-hop-s", "0.1", "--epochs",
              "3", "--quiet", "--no-export"]  # fmt: skip
    assert main(["train", *common, "--encoder", "cgwt", "--out", str(tmp_path / "c")]) == 0
    out = capsys.readouterr().out
    m = json.loads((tmp_path / "c" / "metrics.json").read_text())
    st = m["in_stream"]
    per = 11  # (1200 - 200) / 100 + 1 windows per recording, all but the first with a past
    assert st["train_windows_added"] == m["n_train_windows"] - m["n_train_windows"] // per
    assert st["test_windows_with_past"] == m["n_test_windows"] - m["n_test_windows"] // per
    assert 0.0 <= st["test_accuracy"] <= 1.0 and "as a stream serves them" in out
    assert main(["evaluate", str(tmp_path / "c"), "--json"]) == 0  # the same split, both ways
    ev = json.loads(capsys.readouterr().out)
    assert ev["in_stream"]["test_accuracy"] == st["test_accuracy"]
    assert ev["test_accuracy"] == m["test_accuracy"]
    # a run saved before the level was taken off loads with it on (its spikes as they were),
    # codes no window with its past and refuses the stream graph rather than change them
    cfg_path = tmp_path / "c" / "config.json"
    cfg = json.loads(cfg_path.read_text())
    assert cfg["pipeline"]["encoder"].pop("level_off") is True
    cfg_path.write_text(json.dumps(cfg))
    from tactilesnn.app.run import load_run

    old, _ = load_run(tmp_path / "c")
    assert old.encoder.config.level_off is False and not old.streams_recordings
    assert main(["export", str(tmp_path / "c"), "--stream", "--out", str(tmp_path / "s.onnx"),
                 "--quiet"]) == 2  # fmt: skip
    assert "trained before the cgwt encoder took" in capsys.readouterr().err
    assert main(["train", *common, "--encoder", "gwt", "--out", str(tmp_path / "g")]) == 0
    assert "in_stream" not in json.loads((tmp_path / "g" / "metrics.json").read_text())


def test_recordings_are_coded_a_bounded_share_at_a_time(monkeypatch):
    """SpikePipeline.encode_in_recordings joins and codes the recordings a byte budget at a
    time (not all held at once): the same codes whatever the budget."""
    import tactilesnn.pipeline as pipeline

    pipe = _pipe()
    recs = [_recording(600 + 100 * s, seed=s) for s in range(4)]
    X = np.concatenate([_cut(r, 100) for r in recs])
    scan = np.repeat(np.arange(4), [len(_cut(r, 100)) for r in recs])
    pipe.calibrate(X)
    at, whole = pipe.encode_in_recordings(X, scan)
    monkeypatch.setattr(pipeline, "JOINED_RECORDINGS_BYTES", 1)  # one recording at a time
    calls = []
    coded = pipe.encoder.encode_recordings
    monkeypatch.setattr(pipe.encoder, "encode_recordings",
                        lambda r, s: calls.append(len(r)) or coded(r, s))  # fmt: skip
    at1, one = pipe.encode_in_recordings(X, scan)
    assert calls == [1, 1, 1, 1] and np.array_equal(at, at1)
    fin = torch.isfinite(whole)
    assert torch.equal(fin, torch.isfinite(one)) and (whole[fin] - one[fin]).abs().max() < 1e-3
