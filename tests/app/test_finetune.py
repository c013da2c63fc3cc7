"""``tactilesnn finetune``: a run pretrained on one domain adapted to a few recordings of
another, written as a new run folder that ``evaluate`` reads; the pretrained run untouched."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tactilesnn.cli import main
from tactilesnn.core.files import file_sha256

#: each class's level per channel (counts); the "real" domain swaps classes 0 and 1
LEVELS = np.array([[10, 20, 30, 40], [40, 30, 20, 10], [20, 40, 10, 30]], np.float32)


def _file(path: Path, levels: np.ndarray, seed: int, fs: float = 100.0, per: int = 20,
          classes: tuple[str, ...] = ("a", "b", "c"), **names: np.ndarray) -> Path:  # fmt: skip
    rng = np.random.default_rng(seed)
    y = np.repeat(np.arange(3), per)
    X = levels[y][:, :, None] + rng.normal(0, 2.0, (y.size, 4, 100)).astype(np.float32)
    np.savez(path, X=X.astype(np.float32), y=y, fs=fs, class_names=np.array(classes), **names)
    return path


@pytest.fixture(scope="module")
def pretrained(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("finetune")
    src = _file(root / "source.npz", LEVELS, 0, channel_names=np.array(["t0", "t1", "t2", "t3"]))
    run = root / "pretrained"
    assert main(["train", "--data", str(src), "--encoder", "lif", "--model", "readout",
                 "--epochs", "2", "--quiet", "--no-export", "--out", str(run)]) == 0  # fmt: skip
    return run


def test_finetune_adapts_a_run_to_another_domain_and_writes_a_run(pretrained, tmp_path, capsys):
    shifted = LEVELS[[1, 0, 2]] + 3.0  # a and b swapped, every level 3 counts up
    # the real file names no channels (taken in the run's order) and its classes in capitals
    real = _file(tmp_path / "real.npz", shifted, 1, classes=("A", "B", "C"))
    before = file_sha256(pretrained / "weights.npz")
    out = tmp_path / "tuned"
    capsys.readouterr()
    assert main(["finetune", str(pretrained), "--data", str(real), "--out", str(out),
                 "--quiet", "--json"]) == 0  # fmt: skip
    m = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert m["path"] == str(out)
    # the swap costs the pretrained run two classes of three; the fine-tune wins them back
    assert m["pretrained"]["test_accuracy"] < 0.5
    assert m["test_accuracy"] >= 0.9
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["pretrained_run"]["weights_sha256"] == before
    assert cfg["data"] == str(real.resolve()) and cfg["window"] == 100
    assert (out / "model.onnx").is_file()
    assert file_sha256(pretrained / "weights.npz") == before  # the pretrained run is kept
    metrics = json.loads((out / "metrics.json").read_text())
    assert "max_score_diff" in metrics["onnx"], metrics["onnx"]
    # evaluate reads the new run: the same test split, the same accuracy
    assert main(["evaluate", str(out), "--json", "--quiet"]) == 0
    ev = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert ev["test_accuracy"] == pytest.approx(m["test_accuracy"])
    # an existing folder is refused without --overwrite
    assert main(["finetune", str(pretrained), "--data", str(real), "--out", str(out),
                 "--quiet"]) != 0  # fmt: skip
    assert "already exists; pass --overwrite" in capsys.readouterr().err


def test_finetune_refuses_what_it_cannot_use(pretrained, tmp_path):
    from tactilesnn.app.finetune import finetune_run

    real = _file(tmp_path / "real.npz", LEVELS, 2)
    with pytest.raises(ValueError, match="the pretrained run itself"):
        finetune_run(pretrained, real, pretrained, overwrite=True, export=False, progress=False)
    fast = _file(tmp_path / "fast.npz", LEVELS, 2, fs=200.0)
    with pytest.raises(ValueError, match="200 Hz, the run at 100 Hz"):
        finetune_run(pretrained, fast, tmp_path / "x", export=False, progress=False)
    rng = np.random.default_rng(3)
    np.savez(tmp_path / "other.npz", X=rng.normal(size=(20, 4, 100)).astype(np.float32),
             y=np.arange(20) % 2, fs=100.0, class_names=np.array(["a", "z"]))  # fmt: skip
    with pytest.raises(ValueError, match=r"classes \['z'\]"):
        finetune_run(pretrained, tmp_path / "other.npz", tmp_path / "y", export=False,
                     progress=False)  # fmt: skip
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_class_share_weights_the_real_windows_by_the_generated_class_signal(pretrained, tmp_path):
    """Pretrained on a generated Braille folder (whose shards hold each slide's letter signal),
    fine-tuned with --class-share on plain recordings of the same protocol: a second fine-tune
    in which the training windows before the letter get no share of it (soft targets), the
    others some, blended with the labels' one; a run whose data holds no signal, and
    recordings of another length, are refused by name."""
    from tactilesnn.app.finetune import finetune_run
    from tactilesnn.core.dataset_folder import read_dataset_folder
    from tactilesnn.datasets_synth.generate import generate

    kw = {"letters": "abc", "duration_s": 2.0}
    generate("braille", 24, 0, tmp_path / "synth", workers=1, progress=False, task_kwargs=kw)
    generate("braille", 24, 1, tmp_path / "real", workers=1, progress=False, task_kwargs=kw)
    real = read_dataset_folder(tmp_path / "real")
    np.savez(tmp_path / "real.npz", X=real["X"], y=real["y"], fs=real["fs"],
             class_names=np.char.upper(real["class_names"].astype(str)))  # fmt: skip
    window = real["X"].shape[-1] / 4 / float(real["fs"])
    run = tmp_path / "pre"
    assert main(["train", "--data", str(tmp_path / "synth"), "--data-window-s", str(window),
                 "--encoder", "lif", "--quiet", "--no-export", "--out", str(run)]) == 0  # fmt: skip
    m = finetune_run(run, tmp_path / "real.npz", tmp_path / "tuned", export=False,
                     class_share=True, progress=False)  # fmt: skip
    c = m["train_window_confidence"]
    assert 0.0 < c["none"] < 1.0 and 0.0 < c["mean"] < 1.0
    plain = finetune_run(run, tmp_path / "real.npz", tmp_path / "plain", export=False,
                         progress=False)  # fmt: skip
    assert "train_window_confidence" not in plain
    assert plain["pretrained"] == m["pretrained"]  # the same split, the same pretrained run
    # the labels' fine-tune is the plain run's; the kept read-out is the mean of the two
    assert m["finetuned_on_labels"]["test_accuracy"] == plain["test_accuracy"]
    assert m["finetuned_on_class_share"]["test_accuracy"] != plain["test_accuracy"] or (
        m["finetune_class_share"]["loss_after"] != m["finetune"]["loss_after"])  # fmt: skip
    src = _file(tmp_path / "levels.npz", LEVELS, 5)  # the fixture's run: a file, no signal
    with pytest.raises(ValueError, match="holds no class signal"):
        finetune_run(pretrained, src, tmp_path / "x", export=False, class_share=True,
                     progress=False)  # fmt: skip
    np.savez(tmp_path / "short.npz", X=real["X"][..., :-10], y=real["y"], fs=real["fs"],
             class_names=real["class_names"])  # fmt: skip
    with pytest.raises(ValueError, match="the same length"):
        finetune_run(run, tmp_path / "short.npz", tmp_path / "y", export=False,
                     class_share=True, progress=False)  # fmt: skip


def test_adapt_only_rescales_the_inputs_and_keeps_the_weights(pretrained, tmp_path, capsys):
    """``--adapt-only``: the read-out's input scaling re-estimated on the training split (labels
    unused), the weights written as pretrained, the test split scored before and after; what
    fits weights (--class-share, --choose-prior) is refused with it."""
    from tactilesnn.app.finetune import finetune_run

    moved = _file(tmp_path / "moved.npz", LEVELS + 3.0, 4)
    out = tmp_path / "adapted"
    capsys.readouterr()
    assert main(["finetune", str(pretrained), "--data", str(moved), "--out", str(out),
                 "--adapt-only", "--quiet", "--no-export"]) == 0  # fmt: skip
    assert "labels unused" in capsys.readouterr().out
    m = json.loads((out / "metrics.json").read_text())
    assert m["adapt_only"] and "finetune" not in m and m["adapt"]["windows"] == m["n_train_windows"]
    assert 0.0 <= m["test_accuracy"] <= 1.0 and 0.0 <= m["pretrained"]["test_accuracy"] <= 1.0
    with np.load(pretrained / "weights.npz") as a, np.load(out / "weights.npz") as b:
        assert np.array_equal(a["model.linear.weight"], b["model.linear.weight"])
        assert not np.array_equal(a["model.feat_mean"], b["model.feat_mean"])
    with pytest.raises(ValueError, match="--adapt-only fits no weights"):
        finetune_run(pretrained, moved, tmp_path / "z", export=False, progress=False,
                     adapt_only=True, class_share=True)  # fmt: skip
