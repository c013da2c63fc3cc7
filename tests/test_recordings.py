"""Recordings with sensors at several sampling rates form one recording (resampled channels)."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactilesnn.recordings import load_data_file


def _two_rate_file(path: Path, span_s: float = 2.0, slow_samples: int | None = None) -> None:
    rng = np.random.default_rng(0)
    n, fs, fs_slow = 20, 1000.0, 100.0
    t = np.arange(int(span_s * fs)) / fs
    ts = np.arange(slow_samples or int(span_s * fs_slow)) / fs_slow
    y = np.arange(n) % 2
    f0 = np.where(y == 0, 3.0, 7.0)[:, None]  # the class is in the slow stream's frequency
    np.savez(
        path,
        X=(0.1 * rng.standard_normal((n, 1, t.size))).astype(np.float32),
        fs=fs,
        y=y,
        class_names=np.array(["slow3", "slow7"]),
        channel_names=np.array(["vib"]),
        recording=np.arange(n),
        **{"X@imp": np.sin(2 * np.pi * f0 * ts)[:, None, :], "fs@imp": fs_slow,
           "channel_names@imp": np.array(["e0"])},
    )  # fmt: skip


def test_slow_stream_is_resampled_and_appended(tmp_path: Path) -> None:
    _two_rate_file(tmp_path / "d.npz")
    train, test = load_data_file(tmp_path / "d.npz", seed=0)
    assert train.channel_names == ("vib", "imp:e0") and train.fs_hz == 1000.0
    assert train.X.shape[1:] == (2, 2000)
    # the 100 Hz sine, resampled to 1 kHz, is the sine at 1 kHz (away from the edges)
    t = np.arange(2000) / 1000.0
    for ds in (train, test):
        f0 = np.where(ds.y == 0, 3.0, 7.0)[:, None]
        want = np.sin(2 * np.pi * f0 * t)
        assert np.abs(ds.X[:, 1, 100:-100] - want[:, 100:-100]).max() < 0.02


def test_streams_must_cover_the_same_time(tmp_path: Path) -> None:
    _two_rate_file(tmp_path / "d.npz", slow_samples=150)  # 1.5 s against 2 s
    with pytest.raises(ValueError, match="same time"):
        load_data_file(tmp_path / "d.npz", seed=0)


def test_stream_without_rate_is_refused(tmp_path: Path) -> None:
    np.savez(tmp_path / "d.npz", X=np.zeros((4, 1, 10)), fs=10.0, y=np.array([0, 1, 0, 1]),
             class_names=np.array(["a", "b"]), **{"X@b": np.zeros((4, 1, 5))})  # fmt: skip
    with pytest.raises(ValueError, match="fs@b"):
        load_data_file(tmp_path / "d.npz", seed=0)


def test_cut_windows_are_the_recordings_slices_and_keep_their_ids() -> None:
    from tactilesnn.datasets_synth import WindowDataset
    from tactilesnn.recordings import cut_windows

    rng = np.random.default_rng(0)
    X = rng.standard_normal((3, 2, 100)).astype(np.float32)
    ds = WindowDataset(X, np.array([0, 1, 1]), np.array([7, 8, 9]), 50.0, ("a", "b"), ("u", "v"))
    cut = cut_windows(ds, 0.5, 0.2)  # 25 samples every 10: starts 0..70 -> 8 per recording
    assert cut.X.shape == (24, 2, 25) and cut.X.flags.c_contiguous
    for i in range(3):
        for k, start in enumerate(range(0, 76, 10)):
            np.testing.assert_array_equal(cut.X[8 * i + k], X[i, :, start : start + 25])
    np.testing.assert_array_equal(cut.scan, np.repeat([7, 8, 9], 8))
    np.testing.assert_array_equal(cut.y, np.repeat([0, 1, 1], 8))
    assert cut_windows(ds, 1.0).X.shape[0] == 3 * 3  # default hop: half a window
    with pytest.raises(ValueError, match=r"must be 2\.\.100"):
        cut_windows(ds, 3.0)
    with pytest.raises(ValueError, match="finite positive"):
        cut_windows(ds, 0.5, -1.0)


def test_a_windows_confidence_is_its_share_of_the_class_signal_and_travels_with_it() -> None:
    from tactilesnn.datasets_synth import WindowDataset
    from tactilesnn.recordings import FULL_CONFIDENCE_SHARE, cut_windows

    X = np.zeros((2, 1, 40), np.float32)
    ds = WindowDataset(X, np.array([0, 1]), np.array([3, 4]), 10.0, ("a", "b"), ("u",))
    sig = np.zeros((2, 40), np.float32)
    sig[0, 30:] = 1.0  # recording 0: its class's signal in the last quarter only
    cut = cut_windows(ds, 1.0, 1.0, class_signal=sig)  # 10 samples every 10: 4 windows each
    share = np.array([0, 0, 0, 1.0])
    expect = np.concatenate([np.minimum(1, share / FULL_CONFIDENCE_SHARE), np.ones(4)])
    np.testing.assert_allclose(cut.confidence, expect)  # recording 1 has none: all 1
    sig[0, 25:30] = 0.05  # half a window's worth of a faint tail before it
    part = cut_windows(ds, 1.0, 1.0, class_signal=sig).confidence[:4]
    tail = 0.25 / 10.25
    np.testing.assert_allclose(part, [0, 0, min(1, tail / FULL_CONFIDENCE_SHARE), 1], rtol=1e-6)
    # a subset, a concatenation and a second cut carry the confidences with their windows
    np.testing.assert_array_equal(cut.subset(np.array([3, 4])).confidence, [1, 1])
    both = cut.concat(cut_windows(ds, 1.0, 1.0))
    assert both.confidence.shape == (16,) and (both.confidence[8:] == 1).all()
    again = cut_windows(replace(ds, confidence=np.array([0.5, 1.0], np.float32)), 2.0, 2.0)
    np.testing.assert_array_equal(again.confidence, [0.5, 0.5, 1, 1])
    with pytest.raises(ValueError, match="class_signal"):
        cut_windows(ds, 1.0, 1.0, class_signal=-sig)
    with pytest.raises(ValueError, match="confidence must be"):
        replace(ds, confidence=np.ones(3, np.float32))


def test_real_windows_take_the_confidence_of_their_classs_rendered_signal() -> None:
    """``expected_class_signal``: each recording gets the mean rendered signal of its class, and
    ``cut_windows`` turns it into the confidences a rendered recording of that class gets on
    average; a class nothing was rendered for is refused by name."""
    from tactilesnn.datasets_synth import WindowDataset
    from tactilesnn.recordings import cut_windows, expected_class_signal

    sig = np.zeros((3, 40))
    sig[0, 30:], sig[1, 20:30], sig[2, 0:10] = 1.0, 2.0, 4.0  # classes 0, 0, 1
    out = expected_class_signal(sig, np.array([0, 0, 1]), np.array([1, 0, 0]))
    assert out.dtype == np.float32 and out.shape == (3, 40)
    np.testing.assert_allclose(out[0], sig[2])
    np.testing.assert_allclose(out[1], (sig[0] + sig[1]) / 2)
    np.testing.assert_array_equal(out[1], out[2])
    real = WindowDataset(np.zeros((3, 1, 40), np.float32), np.array([1, 0, 0]), np.arange(3),
                         10.0, ("a", "b"), ("u",))  # fmt: skip
    conf = cut_windows(real, 1.0, 1.0, class_signal=out).confidence.reshape(3, 4)
    np.testing.assert_array_equal(conf[0], [1, 0, 0, 0])  # class 1: its signal in window 0
    np.testing.assert_array_equal(conf[1], [0, 0, 1, 1])  # class 0: windows 2 and 3
    assert expected_class_signal(sig, np.array([0, 0, 1]), np.zeros(0, int)).shape == (0, 40)
    with pytest.raises(ValueError, match=r"class\(es\) \[2\]"):
        expected_class_signal(sig, np.array([0, 0, 1]), np.array([0, 2]))
    with pytest.raises(ValueError, match=">= 0"):
        expected_class_signal(-sig, np.array([0, 0, 1]), np.array([0]))


def test_windows_cut_at_load_never_straddle_the_split(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    y = np.arange(20) % 2
    path = tmp_path / "long.npz"
    np.savez(path, X=rng.standard_normal((20, 1, 400)).astype(np.float32), y=y, fs=100.0,
             class_names=np.array(["a", "b"]))  # fmt: skip
    tr, te = load_data_file(path, seed=0, window_s=1.0, hop_s=0.5)
    assert tr.X.shape[1:] == (1, 100) and tr.y.size == 16 * 7 and te.y.size == 4 * 7
    assert not set(tr.scan.tolist()) & set(te.scan.tolist())
    with pytest.raises(ValueError, match="needs a window length"):
        load_data_file(path, seed=0, hop_s=0.5)


def test_auto_cut_rule_and_file_probe(tmp_path: Path) -> None:
    from tactilesnn.recordings import auto_cut, auto_window

    assert auto_cut(350, 94.0, False) == pytest.approx((87 / 94.0, 43 / 94.0))  # 3.7 s rows
    assert auto_cut(350, 94.0, True) is None  # the file already says what a recording is
    assert auto_cut(200, 50.0, False) is None  # 4 s but too few samples to cut
    assert auto_cut(2000, 4000.0, False) is None  # 0.5 s: already a window
    path = tmp_path / "a.npz"
    X = np.zeros((4, 2, 600), np.float32)
    np.savez(path, X=X, y=np.zeros(4, int), fs=100.0, class_names=np.array(["a"]))
    assert auto_window(path) == pytest.approx((1.5, 0.75))
    np.savez(path, X=X, y=np.zeros(4, int), fs=100.0, class_names=np.array(["a"]),
             recording=np.arange(4))  # fmt: skip
    assert auto_window(path) is None
    np.savez(path, X=np.zeros((4, 2, 2, 600), np.uint8), y=np.zeros(4, int), bin_ms=1.0,
             class_names=np.array(["a"]))  # fmt: skip
    assert auto_window(path) is None  # event data are not cut
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    assert auto_window(tmp_path / "junk.npz") is None  # the loader reports it


def test_encoder_selection_picks_the_code_that_keeps_what_separates_the_classes() -> None:
    """Classes that differ only in level: the window-normalised latency codes (GWT, STFT)
    cannot see it, the LIF population (levels calibrated on training data) can."""
    from tactilesnn.config import PipelineConfig
    from tactilesnn.datasets_synth import WindowDataset
    from tactilesnn.selection import select_encoder

    rng = np.random.default_rng(0)
    y = np.arange(60) % 2
    t = np.arange(200) / 200.0
    shape = np.sin(2 * np.pi * 8 * t + rng.uniform(0, 6, (60, 1, 1)))
    shape = shape + 0.05 * rng.standard_normal(shape.shape)  # same waveforms and SNR in both
    X = ((1 + 2 * y)[:, None, None] * shape).astype(np.float32)
    train = WindowDataset(X, y, np.arange(60), 200.0, ("lo", "hi"), ("ch0",))
    cfg = PipelineConfig.from_flat(channels=("all",), model="readout", epochs=10)
    best, report = select_encoder(cfg, train, ("gwt", "stft", "lif"))
    scores = {k: v["per_window"] for k, v in report["scores"].items()}
    assert best.encoder_type == "lif" and set(scores) == {"gwt", "stft", "lif"}
    assert scores["lif"] > 0.9 and scores["lif"] > max(scores["gwt"], scores["stft"]) + 0.2
    assert best.model == cfg.model and best.train == cfg.train  # only the encoder changes
    assert best.model.choose  # the readout's own cross-validation kept for the final training
    # the calibrated level code gives the window-normalised codes the level back
    _, report = select_encoder(cfg.replace(level_neurons=4), train, ("gwt", "stft"))
    assert min(v["per_window"] for v in report["scores"].values()) > 0.9


def test_candidates_are_fitted_as_the_model_asks_while_selecting(monkeypatch) -> None:
    """The readout's cross-validation is skipped while encoders are compared (its
    ``WHILE_SELECTING``), not in the chosen configuration."""
    from tactilesnn import selection
    from tactilesnn.config import PipelineConfig
    from tactilesnn.datasets_synth import WindowDataset

    seen = []
    real = selection.fit_and_evaluate

    def spy(cfg, *a, **k):
        seen.append(cfg.model.choose)
        return real(cfg, *a, **k)

    monkeypatch.setattr(selection, "fit_and_evaluate", spy)
    rng = np.random.default_rng(1)
    X = rng.standard_normal((24, 1, 100)).astype(np.float32)
    train = WindowDataset(X, np.arange(24) % 2, np.arange(24), 100.0, ("a", "b"), ("ch0",))
    cfg = PipelineConfig.from_flat(channels=("all",), model="readout")
    best, _ = selection.select_encoder(cfg, train, ("gwt", "lif"))
    assert seen == [False, False] and best.model.choose


def test_hopeless_needs_both_points_and_standard_errors() -> None:
    from tactilesnn.selection import hopeless

    assert hopeless(0.5, 0.9, 100)  # 40 points, 3 SE = 18
    assert not hopeless(0.87, 0.9, 10_000)  # under the 5-point floor, however many windows
    assert not hopeless(0.8, 0.9, 30)  # 10 points but 3 SE = 27: could be noise
    assert hopeless(0.8, 0.9, 1000)


def test_hopeless_candidates_stop_after_the_first_round(monkeypatch) -> None:
    """Classes that differ only in level: the window-normalised codes stop after a first round on
    half the last round's windows; the one left is not fitted again (its final training
    follows), and the windows are coded alone (their past joins the final fit only)."""
    from tactilesnn import selection
    from tactilesnn.config import PipelineConfig
    from tactilesnn.datasets_synth import WindowDataset

    calls = []
    real = selection.fit_and_evaluate

    def spy(cfg, fit, val, **k):
        calls.append((cfg.encoder_type, fit.y.size, val.y.size, k.get("with_past")))
        return real(cfg, fit, val, **k)

    monkeypatch.setattr(selection, "fit_and_evaluate", spy)
    monkeypatch.setattr(selection, "FIRST_ROUND_MIN_WINDOWS", 20)
    rng = np.random.default_rng(0)
    y = np.arange(400) % 2
    t = np.arange(200) / 200.0
    shape = np.sin(2 * np.pi * 8 * t + rng.uniform(0, 6, (400, 1, 1)))
    X = ((1 + 2 * y)[:, None, None] * shape).astype(np.float32)
    train = WindowDataset(X, y, np.arange(400), 200.0, ("lo", "hi"), ("ch0",))
    cfg = PipelineConfig.from_flat(channels=("all",), model="readout")
    best, report = selection.select_encoder(cfg, train, ("gwt", "stft", "lif"))
    assert best.encoder_type == "lif" and report["rounds"][0]["fit_windows"] == 150
    assert [c[0] for c in calls] == ["gwt", "stft", "lif"] and {c[1] for c in calls} == {150}
    assert {c[3] for c in calls} == {False}
    sc = report["scores"]
    assert sc["gwt"]["stopped_after"] == 1 and sc["stft"]["stopped_after"] == 1
    assert "stopped_after" not in sc["lif"] and sc["lif"]["per_window"] > 0.9


def test_successive_halving_keeps_the_better_half_on_twice_the_windows(monkeypatch) -> None:
    """Three candidates none of them hopeless: all on half the windows, the better two on all of
    them; a budget cuts the last round, never below SELECT_MIN_WINDOWS."""
    from tactilesnn import selection

    assert selection.rounds_for(3, 1000) == [(3, 500), (2, 1000)]
    assert selection.rounds_for(2, 1000) == [(2, 1000)]
    assert selection.rounds_for(5, 1000) == [(5, 250), (3, 500), (2, 1000)]
    budget = selection.SelectionBudget({"a": 1e-3, "b": 1e-3, "c": 1e-3}, rest_s=3.0)
    # 3 x 500 + 2 x 1000 windows x (1 + 0.5) x 2 ms = 10.5 s > 1 s: cut to the floor
    monkeypatch.setattr(selection, "SELECT_MIN_WINDOWS", 600)
    assert selection.planned_rounds(3, 1000, 0.5, budget) == [(3, 300), (2, 600)]
    assert budget.seconds == pytest.approx(1.0)  # a quarter of the run: a third of the rest
    generous = selection.SelectionBudget({"a": 1e-3}, rest_s=1e4)
    assert selection.planned_rounds(3, 1000, 0.5, generous) == [(3, 500), (2, 1000)]
    # too few windows for two rounds: one
    assert selection.planned_rounds(3, 400, 0.5, None) == [(3, 400)]


def test_selection_subset_takes_whole_recordings_of_every_class_up_to_the_cap() -> None:
    from tactilesnn.datasets_synth import WindowDataset
    from tactilesnn.selection import selection_subset

    scan = np.repeat(np.arange(40), 5)  # 40 recordings of 5 windows, 4 classes
    y = scan % 4
    data = WindowDataset(
        np.zeros((200, 1, 8), np.float32), y, scan, 100.0, ("a", "b", "c", "d"), ("x",)
    )
    sub = selection_subset(data, 52, seed=0)
    assert sub.y.size == 50 and np.bincount(sub.y).tolist() == [15, 15, 10, 10]
    assert all((sub.scan == s).sum() == 5 for s in np.unique(sub.scan))  # whole recordings
    assert selection_subset(data, 500, seed=0) is data


@pytest.mark.slow
def test_a_generated_folder_is_data_whose_scans_never_straddle_the_split(tmp_path: Path) -> None:
    from tactilesnn.cli import main
    from tactilesnn.datasets_synth.generate import generate

    out = tmp_path / "gen"
    m = generate("hook_loop", 12, 0, out, shard_size=5, progress=False)
    train, test = load_data_file(out, seed=0)
    assert len(train.y) + len(test.y) == m["n_windows"]
    assert not set(train.scan.tolist()) & set(test.scan.tolist())  # one scan, one side
    assert train.fs_hz == m["fs_hz"] and train.class_names == tuple(m["class_names"])
    assert train.channel_names == tuple(m["channel_names"])
    # identical to the shards' own content, in order
    with np.load(out / "shard-00000.npz") as z:
        X0, s0 = z["X"], z["sample"]
    keep = np.isin(s0, train.scan)
    np.testing.assert_array_equal(train.X[: keep.sum()], X0[keep])
    run = tmp_path / "run"
    assert main(["train", "--data", str(out), "--epochs", "1", "--quiet", "--out", str(run)]) == 0
    assert (run / "model.onnx").is_file()
    # a damaged shard is refused, not read
    shard = out / "shard-00001.npz"
    shard.write_bytes(shard.read_bytes()[:-10])
    with pytest.raises(ValueError, match="SHA-256"):
        load_data_file(out, seed=0)
    with pytest.raises(FileNotFoundError, match="not a generated dataset"):
        load_data_file(tmp_path, seed=0)


def test_a_generated_trial_folder_carries_its_class_signal_into_window_confidences(tmp_path):
    """``generate`` writes a trial task's class signal (Braille: the slide minus the same slide
    without its letter) beside ``X``; ``load_data_file`` cut into windows gives each window its
    share of it as a confidence (the windows before the letter none); whole rows, a task that
    cannot render one, and a user's file without one carry none; a malformed one is refused."""
    from tactilesnn.datasets_synth import get_task
    from tactilesnn.datasets_synth.generate import generate

    out = tmp_path / "braille"
    m = generate("braille", 12, 0, out, shard_size=3, workers=1, progress=False,
                 task_kwargs={"letters": "abc"})  # fmt: skip
    assert all(sh["class_signal"] for sh in m["shards"])
    task = get_task("braille", seed=0, letters="abc")
    _, _, info = task.sample(4, class_signal=True)
    with np.load(out / "shard-00001.npz") as z:
        np.testing.assert_array_equal(z["class_signal"][1], info["class_signal"])
        assert z["class_signal"].shape == (3, task.window)
    whole, _ = load_data_file(out, seed=0)
    assert whole.confidence is None
    window_s = task.window / 4 / task.fs_hz
    train, test = load_data_file(out, seed=0, window_s=window_s)
    assert train.confidence is not None and test.confidence is not None
    assert train.confidence.min() == 0.0 and train.confidence.max() == 1.0
    from tactilesnn.cli import main  # train --data on it: the read-out on the soft targets

    run = tmp_path / "run"
    assert main(["train", "--data", str(out), "--data-window-s", str(window_s), "--encoder",
                 "lif", "--quiet", "--no-export", "--out", str(run)]) == 0  # fmt: skip
    soft = json.loads((run / "metrics.json").read_text())["train_window_confidence"]
    assert 0.0 < soft["none"] < 1.0 and 0.0 < soft["mean"] < 1.0
    from tactilesnn.core.dataset_folder import read_dataset_folder

    plain = generate("texture", 2, 0, tmp_path / "texture", workers=1, progress=False)
    assert not any(sh["class_signal"] for sh in plain["shards"])
    assert "class_signal" not in read_dataset_folder(tmp_path / "texture")
    # a user's file: the signal is optional, checked where given
    rng = np.random.default_rng(0)
    X = rng.normal(size=(8, 2, 400)).astype(np.float32)
    base = {"X": X, "y": np.arange(8) % 2, "fs": 100.0, "class_names": np.array(["a", "b"])}
    sig = np.zeros((8, 400))
    sig[:, 300:] = 1.0  # the class shows in the last quarter
    np.savez(tmp_path / "f.npz", class_signal=sig, **base)
    tr, _ = load_data_file(tmp_path / "f.npz", seed=0, window_s=1.0, hop_s=1.0)
    np.testing.assert_array_equal(tr.confidence.reshape(-1, 4), [[0, 0, 0, 1]] * (tr.y.size // 4))
    np.savez(tmp_path / "g.npz", class_signal=-sig, **base)
    with pytest.raises(ValueError, match="class_signal must be finite and >= 0"):
        load_data_file(tmp_path / "g.npz", seed=0, window_s=1.0)
    np.savez(tmp_path / "h.npz", class_signal=sig[:, :10], **base)
    with pytest.raises(ValueError, match=r"class_signal must be \[N=8, samples=400\]"):
        load_data_file(tmp_path / "h.npz", seed=0)


def test_sizes_no_sensor_has_are_refused_before_anything_is_built(tmp_path):
    import numpy as np

    from tactilesnn.recordings import load_data_file

    cases = {"empty events": np.zeros((0, 24773, 18770, 0), np.float32),
             "polarities": np.zeros((2, 3, 40, 10), np.float32),
             "channels": np.zeros((2, (1 << 20) + 1, 2), np.uint8)}  # fmt: skip
    for what, X in cases.items():
        path = tmp_path / f"{what}.npz"
        np.savez(
            path, X=X, y=np.array([0, 1]), fs=np.array(100.0), class_names=np.array(["a", "b"])
        )
        with pytest.raises(ValueError, match=r"no data|polarities|channels"):
            load_data_file(path, seed=0)


@pytest.mark.parametrize(
    "labels, names",
    [(np.array([0, 1, 2] * 8), ["0", "1", "2"]),
     (np.array([3, 7, 9] * 8), ["3", "7", "9"]),
     (np.array(["soft", "hard", "mid"] * 8), ["hard", "mid", "soft"])],
)  # fmt: skip
def test_class_names_are_optional(tmp_path, labels, names):
    """A file with X, y and fs only: the classes are named by the labels' values (integer
    labels keep their values, text labels are numbered in sorted order)."""
    rng = np.random.default_rng(0)
    X = rng.normal(size=(24, 2, 50)).astype(np.float32)
    np.savez(tmp_path / "f.npz", X=X, y=labels, fs=100.0)
    train, test = load_data_file(tmp_path / "f.npz", seed=0)
    assert list(train.class_names) == names
    y = np.concatenate([train.y, test.y])
    X_all = np.concatenate([train.X, test.X])
    for k, name in enumerate(names):  # every window keeps its own label
        rows = [i for i in range(24) if str(labels[i]) == name]
        want = {X[i].tobytes() for i in rows}
        assert {x.tobytes() for x in X_all[y == k]} == want


def _tiny_arrays(n=24):
    rng = np.random.default_rng(0)
    return {"X": rng.normal(size=(n, 2, 50)).astype(np.float32), "y": np.arange(n) % 2}


@pytest.mark.parametrize("fs", [1e-291, 1e-4, 5e9])
def test_rates_outside_what_a_sensor_samples_at_are_refused(tmp_path, fs):
    np.savez(tmp_path / "f.npz", **_tiny_arrays(), fs=fs)
    with pytest.raises(ValueError, match=r"outside 0\.001 \.\. 1e\+09 Hz"):
        load_data_file(tmp_path / "f.npz", seed=0)


def test_timestamps_in_the_wrong_units_are_refused_naming_the_file(tmp_path):
    a = _tiny_arrays()
    t = np.tile(np.arange(50) * 1e300, (24, 1))  # steps of 1e300 s: a rate of 1e-300 Hz
    np.savez(tmp_path / "f.npz", X=a["X"].transpose(0, 2, 1), y=a["y"], t=t)
    with pytest.raises(ValueError, match=r"f\.npz.*sampling rate"):
        load_data_file(tmp_path / "f.npz", seed=0)


def test_an_archive_holding_a_member_twice_is_refused(tmp_path):
    import io
    import warnings
    import zipfile

    with zipfile.ZipFile(tmp_path / "f.npz", "w") as z, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (zipfile warns of the duplicate name)
        for k, v in {**_tiny_arrays(), "fs": np.float64(100.0), "X2": _tiny_arrays()["X"]}.items():
            buf = io.BytesIO()
            np.save(buf, v)
            z.writestr(("X" if k == "X2" else k) + ".npy", buf.getvalue())
    with pytest.raises(ValueError, match=r"holds 'X\.npy' 2 times"):
        load_data_file(tmp_path / "f.npz", seed=0)


@pytest.mark.parametrize("far", [1e300, -2e6])
def test_taxel_positions_beyond_a_kilometre_are_refused(tmp_path, far):
    rng = np.random.default_rng(0)
    X = rng.poisson(0.3, size=(24, 4, 2, 30)).astype(np.float32)
    xy = np.array([[0.0, 0.0], [far, 0.0], [0.0, 1.0], [1.0, 1.0]])
    np.savez(tmp_path / "e.npz", X=X, y=np.arange(24) % 2, fs=50.0, taxel_xy=xy)
    with pytest.raises(ValueError, match=r"taxel 1 at .* beyond"):
        load_data_file(tmp_path / "e.npz", seed=0)


def test_a_generated_shard_without_a_member_is_named(tmp_path):
    import hashlib
    import json

    from tactilesnn.datasets_synth.generate import generate

    out = tmp_path / "gen"
    generate("touch", 8, 0, out, shard_size=4, progress=False)
    shard = out / "shard-00001.npz"
    arrays = dict(np.load(shard))
    arrays.pop("y")
    np.savez(shard, **arrays)
    m = json.loads((out / "manifest.json").read_text())  # its hash rewritten with it
    for s in m["shards"]:
        s["sha256"] = hashlib.sha256((out / s["file"]).read_bytes()).hexdigest()
    (out / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(ValueError, match=r"shard-00001\.npz: lacks \['y'\]"):
        load_data_file(out, seed=0)


def test_folders_named_in_another_encoding_train_and_stay_distinct(tmp_path):
    """Class folders whose names are not UTF-8 (written under another locale): read as \\xff
    escapes, distinct, and the run's files can be written (hashing them failed before)."""
    import os

    from tactilesnn.core.files import file_sha256

    root = os.fsencode(tmp_path / "d")
    rng = np.random.default_rng(0)
    for c in (b"caf\xe9", b"caf\xe8"):
        os.makedirs(root + b"/" + c)
        for i in range(3):
            with open(root + b"/" + c + b"/r%d.npy" % i, "wb") as f:
                np.save(f, rng.normal(size=(400, 2)).astype(np.float32))
    folder = tmp_path / "d"
    train, _ = load_data_file(folder, seed=0, fs_hz=100.0)
    assert sorted(train.class_names) == ["caf\\xe8", "caf\\xe9"]
    assert len(file_sha256(folder)) == 64


@settings(max_examples=50, deadline=None)
@given(labels=st.lists(st.integers(-1000, 1000), min_size=2, max_size=40).filter(
    lambda v: len(set(v)) >= 2), text=st.booleans())  # fmt: skip
def test_labels_alone_name_their_classes_consistently(labels, text):
    """Without ``class_names`` every window keeps its own label: the name of its new index is
    its old label, whatever the values (integers or text)."""
    from tactilesnn.recordings import _classes_from_labels

    y = np.array([f"c{v}" for v in labels]) if text else np.array(labels)
    out = _classes_from_labels(y, "f.npz")
    names = out["class_names"]
    assert [names[i] for i in out["y"]] == [str(v) for v in y]
    assert len(names) == len(set(y.tolist()))


@pytest.mark.parametrize("dtype", [np.uint8, np.int16, np.float64, np.float32])
def test_a_split_is_converted_to_float32_block_by_block(monkeypatch, dtype):
    """The same windows as converting the whole file first, at any block size (one row per
    block here), for every dtype a file may hold."""
    from tactilesnn import recordings

    monkeypatch.setattr(recordings, "CONVERT_ROWS_BYTES", 1)
    rng = np.random.default_rng(0)
    X = (rng.uniform(0, 200, size=(13, 3, 7))).astype(dtype)
    mask = rng.uniform(size=13) < 0.6
    got = recordings.rows_as_float32(X, mask)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, X.astype(np.float32)[mask])
