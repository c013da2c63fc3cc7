"""Training runs: resume after an interruption, TOML configs, real recordings (--data)."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

import tactilesnn.app.run as app_run
from tactilesnn.cli import main
from tactilesnn.config import PipelineConfig
from tactilesnn.core.files import load_arrays
from tactilesnn.data_policy import DATA_ENCODER_CANDIDATES
from tests.helpers import run_task

SMALL = {"seed": 0, "n_planar": 10, "n_concave": 5, "n_convex": 5, "n_test": 4}
_REL = Path("braille_icub_abc") / "braille_abc_icub.npz"
_ROOTS = [
    Path(os.environ.get("TACTILESNN_SHARED_DATA", "/nonexistent")),
    Path(__file__).resolve().parents[2] / "shared" / "data",  # ../shared/data beside the repo
    Path("/work/shared/data"),
]
ICUB = next((r / _REL for r in _ROOTS if (r / _REL).is_file()), _ROOTS[1] / _REL)


@pytest.mark.slow
@pytest.mark.parametrize("model", ["tempotron", "snn"])
def test_resume_after_interruption_equals_uninterrupted(tmp_path, monkeypatch, model):
    cfg = PipelineConfig.from_flat(
        model=model, epochs=4, **({"snn_hidden": 16} if model == "snn" else {})
    )
    ref_dir, _ = run_task("hook_loop", SMALL, cfg, tmp_path / "ref", progress=False)

    real_save = app_run.save_checkpoint
    calls = {"n": 0}

    def crash_after_two(folder, state):
        real_save(folder, state)
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt  # the session is cut mid-run

    monkeypatch.setattr(app_run, "save_checkpoint", crash_after_two)
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        run_task("hook_loop", SMALL, cfg, out, progress=False)
    assert not out.exists() and (tmp_path / "run.partial" / "checkpoint.json").is_file()
    monkeypatch.setattr(app_run, "save_checkpoint", real_save)
    with pytest.raises(FileExistsError, match="--resume"):
        run_task("hook_loop", SMALL, cfg, out, progress=False)
    with pytest.raises(ValueError, match="same settings"):
        run_task(
            "hook_loop",
            SMALL,
            PipelineConfig.from_flat(model=model, epochs=5),
            out,
            progress=False,
            resume=True,
        )
    path, m = run_task("hook_loop", SMALL, cfg, out, progress=False, resume=True)
    assert not (tmp_path / "run.partial").exists()
    a, b = load_arrays(ref_dir / "weights.npz"), load_arrays(path / "weights.npz")
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    assert len(m["train_error_history"]) == 4


@pytest.mark.slow
def test_toml_config_and_flag_override(tmp_path, capsys):
    toml = tmp_path / "exp.toml"
    toml.write_text('[train]\nencoder = "stft"\nepochs = 2\nn_bands = 12\nseed = 1\n')
    out = tmp_path / "r"
    assert (
        main(
            [
                "train",
                "--config",
                str(toml),
                "--epochs",
                "1",
                "--out",
                str(out),
                "--quiet",
                "--difficulty",
                "1.0",
            ]
        )
        == 0
    )
    cfg = json.loads((out / "config.json").read_text())["pipeline"]
    assert cfg["encoder"]["type"] == "stft" and cfg["encoder"]["n_bands"] == 12
    assert cfg["train"]["epochs"] == 1 and cfg["train"]["seed"] == 1
    assert (out / "config.toml").read_text() == toml.read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text("epochz = 3\n")
    assert main(["train", "--config", str(bad), "--out", str(tmp_path / "x")]) == 2
    assert "unknown setting 'epochz'" in capsys.readouterr().err


@pytest.mark.data
@pytest.mark.skipif(not ICUB.is_file(), reason="real iCub recordings not available")
def test_real_icub_recordings_through_the_data_path(tmp_path, capsys):
    raw = np.load(ICUB, allow_pickle=False)
    fs = 1.0 / float(np.median(np.diff(raw["t"], axis=1)))
    data = tmp_path / "braille.npz"
    np.savez(
        data,
        X=raw["X"].transpose(0, 2, 1).astype(np.float32),  # trials x taxels x samples
        y=raw["y"],
        fs=fs,
        class_names=np.array(["A", "B", "C"]),
        channel_names=np.array([f"taxel{i}" for i in range(12)]),
    )
    # defaults, no flag: 3.7 s rows cut into 7 windows, the encoder chosen on held-out training
    # recordings, scores summed per recording -> every test recording right (seeds 0-2 measured)
    out = tmp_path / "defaults"
    assert main(["train", "--data", str(data), "--out", str(out), "--quiet", "--no-export"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    cfg = json.loads((out / "config.json").read_text())
    assert m["n_test_windows"] == 9 * 7 and m["n_test_recordings"] == 9
    sel = m["encoder_selection"]
    assert (
        set(sel["scores"]) == set(DATA_ENCODER_CANDIDATES)
        and sel["chosen"] == cfg["pipeline"]["encoder"]["type"]
    )
    # ranked by what is printed: per window, then per recording
    key = {k: (v["per_window"], v.get("per_recording", 0.0)) for k, v in sel["scores"].items()
           if not v.get("stopped_after")}  # fmt: skip
    assert sel["chosen"] == max(key, key=key.get) and sel["seconds"] > 0
    assert m["test_accuracy_per_recording"] == 1.0 and m["test_accuracy"] > 0.85
    # the compute threads it ran on (a bit-identical rerun needs the same counts)
    assert m["compute_threads"]["counts"] and all(n >= 1 for n in m["compute_threads"]["counts"])
    # whole rows and an explicit encoder: no cut, no selection
    out = tmp_path / "braille_run"
    channels = [f"taxel{i}" for i in range(12)]
    rc = main(["train", "--data", str(data), "--data-window-s", "0", "--channels", *channels,
               "--encoder", "gwt", "--f-lo-hz", "0.5", "--epochs", "30", "--out", str(out),
               "--quiet"])  # fmt: skip
    assert rc == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["n_test_windows"] == 9 and m["test_accuracy"] > 1 / 3  # above chance on 3 letters
    assert "encoder_selection" not in m
    assert main(["evaluate", str(out), "--data", str(data), "--all", "--quiet", "--json"]) == 0
    got = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert got["n"] == 45
    bad = tmp_path / "bad.npz"
    np.savez(bad, X=np.zeros((3, 100)), y=np.zeros(3), fs=100.0, class_names=np.array(["a"]))
    assert main(["train", "--data", str(bad), "--out", str(tmp_path / "b"), "--quiet"]) == 2
    assert "X must be [N, channels, samples]" in capsys.readouterr().err


@pytest.mark.slow
def test_export_failure_keeps_the_finished_run(tmp_path, monkeypatch, capsys):
    import tactilesnn.export as export

    def boom(*a, **k):
        raise MemoryError("cannot allocate 44 GB")

    monkeypatch.setattr(export, "export_pipeline", boom)
    out = tmp_path / "r"
    rc = main(["train", "--epochs", "1", "--task-kw", "n_planar=10", "--task-kw", "n_concave=5",
               "--task-kw", "n_convex=5", "--task-kw", "n_test=4", "--out", str(out), "--quiet"])  # fmt: skip
    assert rc == 1
    assert "ONNX export failed" in capsys.readouterr().out
    m = json.loads((out / "metrics.json").read_text())
    assert "MemoryError" in m["onnx"]["error"] and m["test_accuracy"] > 0.5
    assert (out / "weights.npz").is_file() and not (out / "model.onnx").exists()
    assert not (tmp_path / "r.partial").exists()
    app_run.load_run(out)  # the run is usable


@pytest.mark.slow
def test_recordings_never_straddle_the_split_and_are_scored_whole(tmp_path):
    from tactilesnn.recordings import load_data_file

    rng = np.random.default_rng(0)
    n_rec, per = 12, 6  # 12 recordings of 6 windows, 3 classes
    rec = np.repeat(np.array([f"rec{i:02d}" for i in range(n_rec)]), per)
    y = np.repeat(np.arange(n_rec) % 3, per)
    t = np.arange(100) / 200.0
    X = np.stack([[np.sin(2 * np.pi * (5 + 10 * c) * t) + 0.3 * rng.standard_normal(100)]
                  for c in y]).astype(np.float32)  # fmt: skip
    data = tmp_path / "d.npz"
    np.savez(data, X=X, y=y, fs=200.0, class_names=np.array(["a", "b", "c"]), recording=rec)
    tr, te = load_data_file(data, seed=0)
    assert not set(tr.scan.tolist()) & set(te.scan.tolist())
    assert te.y.size % per == 0 and set(te.y.tolist()) == {0, 1, 2}
    out = tmp_path / "r"
    assert main(["train", "--data", str(data), "--channels", "ch0", "--epochs", "3",
                 "--out", str(out), "--quiet", "--no-export"]) == 0  # fmt: skip
    m = json.loads((out / "metrics.json").read_text())
    assert m["n_test_recordings"] == te.y.size // per
    assert 0.0 <= m["test_accuracy_per_recording"] <= 1.0


@pytest.mark.slow
def test_long_recordings_cut_into_windows_are_scored_per_recording(tmp_path, capsys):
    rng = np.random.default_rng(0)
    y = np.arange(24) % 3
    t = np.arange(600) / 200.0  # 3 s recordings, one frequency per class
    X = np.stack([[np.sin(2 * np.pi * (5 + 12 * c) * t) + 0.5 * rng.standard_normal(t.size)]
                  for c in y]).astype(np.float32)  # fmt: skip
    data = tmp_path / "long.npz"
    np.savez(data, X=X, y=y, fs=200.0, class_names=np.array(["a", "b", "c"]))
    out = tmp_path / "r"
    assert main(["train", "--data", str(data), "--data-window-s", "0.5", "--data-hop-s", "0.25",
                 "--epochs", "5", "--out", str(out), "--quiet", "--no-export"]) == 0  # fmt: skip
    cfg = json.loads((out / "config.json").read_text())
    assert (cfg["data_window_s"], cfg["data_hop_s"], cfg["window"]) == (0.5, 0.25, 100)
    m = json.loads((out / "metrics.json").read_text())
    assert m["n_test_windows"] == m["n_test_recordings"] * 11  # (600 - 100) / 50 + 1 windows
    assert m["test_accuracy_per_recording"] >= m["test_accuracy"] - 1e-9
    assert m["test_accuracy_per_recording"] > 0.9
    capsys.readouterr()
    assert main(["evaluate", str(out)]) == 0  # cut as in training, without repeating the flags
    text = capsys.readouterr().out
    assert f"{100 * m['test_accuracy']:.2f} %" in text
    assert f"per recording (scores summed over its windows): " \
           f"{100 * m['test_accuracy_per_recording']:.2f} %" in text  # fmt: skip
    assert main(["evaluate", str(out), "--data", str(data), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["n_test_recordings"] == m["n_test_recordings"]
    assert main(["train", "--data-window-s", "0.5", "--out", str(tmp_path / "x"), "--quiet"]) != 0
    assert "cut a --data file" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("arrays", "message"),
    [
        ({"X": np.zeros((3, 1, 50)), "y": np.array([0.5, 1, 0]), "fs": 100.0}, "integer class"),
        ({"X": np.zeros((3, 1, 50), complex), "y": np.zeros(3, int), "fs": 100.0}, "real numbers"),
        ({"X": np.zeros((3, 1, 1)), "y": np.zeros(3, int), "fs": 100.0}, ">= 2 samples"),
        (
            {"X": np.zeros((3, 1, 50)), "y": np.zeros(3, int), "fs": np.array([1.0, 2.0])},
            "one sampling",
        ),
    ],
)
def test_bad_recording_files_get_specific_errors(tmp_path, arrays, message):
    from tactilesnn.recordings import load_data_file

    path = tmp_path / "bad.npz"
    np.savez(path, class_names=np.array(["a", "b"]), **arrays)
    with pytest.raises(ValueError, match=message):
        load_data_file(path, seed=0)
    (tmp_path / "trunc.npz").write_bytes(path.read_bytes()[:100])
    with pytest.raises(ValueError, match=r"not a readable \.npz"):
        load_data_file(tmp_path / "trunc.npz", seed=0)


@pytest.mark.slow
def test_evaluate_data_with_channels_in_another_order_scores_the_same(tmp_path, capsys, caplog):
    """A user's file whose channels come in another order is reordered by name (with a warning),
    not silently scored against the wrong afferents; other channel names are refused."""
    rng = np.random.default_rng(1)
    y = np.arange(30) % 3
    t = np.arange(200) / 200.0
    # channel a carries the class frequency, b is noise: swapping them must not change the score
    X = np.stack([[np.sin(2 * np.pi * (5 + 12 * c) * t), 0.2 * rng.standard_normal(t.size)]
                  for c in y]).astype(np.float32)  # fmt: skip
    names = np.array(["a", "b"])
    data, flipped, other = tmp_path / "d.npz", tmp_path / "flip.npz", tmp_path / "other.npz"
    common = {"y": y, "fs": 200.0, "class_names": np.array(["x", "y", "z"])}
    np.savez(data, X=X, channel_names=names, **common)
    np.savez(flipped, X=X[:, ::-1], channel_names=names[::-1], **common)
    np.savez(other, X=X, channel_names=np.array(["a", "c"]), **common)
    out = tmp_path / "r"
    assert main(["train", "--data", str(data), "--encoder", "gwt", "--epochs", "5",
                 "--out", str(out), "--quiet", "--no-export"]) == 0  # fmt: skip
    capsys.readouterr()
    assert main(["evaluate", str(out), "--data", str(data), "--json"]) == 0
    same = json.loads(capsys.readouterr().out)
    with caplog.at_level("WARNING", logger="tactilesnn"):
        assert main(["evaluate", str(out), "--data", str(flipped), "--json"]) == 0
    rev = json.loads(capsys.readouterr().out)
    assert "another order" in caplog.text
    assert same["test_accuracy"] > 0.6 and rev["test_accuracy"] == same["test_accuracy"]
    assert main(["evaluate", str(out), "--data", str(other), "--json"]) != 0
    assert "not the run's" in capsys.readouterr().err


def test_transfer_pipeline_is_the_adapt_finetune_and_blend_steps():
    """``transfer_pipeline`` (used by ``finetune`` and ``bench sim2real``) gives the same read-out
    as adapting, fine-tuning on the labels and on the class share apart, and blending; its
    stages are reported in order; ``adapt_only`` fits no weights."""
    import copy
    from dataclasses import replace

    import torch

    from tactilesnn.core.data import WindowDataset
    from tactilesnn.models.base import seeded
    from tactilesnn.training import (
        adapt_pipeline,
        blend_finetuned,
        finetune_pipeline,
        fit_pipeline,
        transfer_pipeline,
    )

    rng = np.random.default_rng(0)

    def windows(levels, n, seed):
        r = np.random.default_rng(seed)
        y = np.arange(n) % 2
        X = levels[y][:, :, None] + r.normal(0, 1.0, (n, 2, 64))
        return WindowDataset(X.astype(np.float32), y, np.arange(n), 100.0, ("a", "b"), ("u", "v"))

    source = windows(np.array([[5.0, 1.0], [1.0, 5.0]]), 24, 1)
    target = windows(np.array([[7.0, 2.0], [2.0, 8.0]]), 8, 2)
    share = replace(target, confidence=rng.uniform(0.2, 1.0, 8).astype(np.float32))
    cfg = PipelineConfig.from_flat(encoder="lif", model="readout", epochs=2, channels=("all",))
    with seeded(0):
        pre = fit_pipeline(cfg, source, with_past=False).pipeline
    by_hand, soft = copy.deepcopy(pre), None
    adapt_pipeline(by_hand, target)
    soft = copy.deepcopy(by_hand)
    with seeded(3):
        finetune_pipeline(soft, share)
    with seeded(3):
        finetune_pipeline(by_hand, target)
    blend_finetuned(by_hand, soft)
    stages = []
    report = transfer_pipeline(pre, share, share, seed=3,
                               on_arm=lambda s, p: stages.append(s))  # fmt: skip
    assert stages == ["adapted", "class_share", "labels", "blend"]
    assert set(report) == {"adapt", "finetune", "finetune_class_share"}
    for a, b in zip(pre.model.finetune_parameters(), by_hand.model.finetune_parameters(),
                    strict=True):  # fmt: skip
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    kept = copy.deepcopy(pre)
    only = transfer_pipeline(kept, target, seed=3, adapt_only=True)
    assert set(only) == {"adapt"}
    for a, b in zip(kept.model.finetune_parameters(), pre.model.finetune_parameters(),
                    strict=True):  # fmt: skip
        torch.testing.assert_close(a, b)
