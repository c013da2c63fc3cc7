"""Nothing a user wrote is lost: --overwrite replaces only what tactilesnn wrote."""

import json

import tactilesnn.app.run as app_run
from tactilesnn.cli import main

TINY = ["--task-kw", "n_planar=6", "--task-kw", "n_concave=3", "--task-kw", "n_convex=3",
        "--task-kw", "n_test=3"]  # fmt: skip


def test_overwrite_refuses_folders_and_files_it_did_not_write(tmp_path, capsys):
    mine = tmp_path / "notes"
    mine.mkdir()
    (mine / "thesis.tex").write_text("precious")
    rc = main(["train", "--epochs", "1", *TINY, "--out", str(mine), "--overwrite", "--quiet"])
    assert rc == 2 and "not a tactilesnn run folder" in capsys.readouterr().err
    assert (mine / "thesis.tex").read_text() == "precious"
    f = tmp_path / "file.txt"
    f.write_text("keep")
    rc = main(["train", "--epochs", "1", *TINY, "--out", str(f), "--overwrite", "--quiet"])
    assert rc == 2 and "is not a run folder" in capsys.readouterr().err and f.read_text() == "keep"
    rc = main(["generate", "--task", "texture", "--n", "4", "--out", str(mine), "--overwrite",
               "--quiet", "--workers", "1"])  # fmt: skip
    assert rc == 2 and "not a tactilesnn dataset" in capsys.readouterr().err
    assert (mine / "thesis.tex").read_text() == "precious"


def test_overwrite_replaces_its_own_run(tmp_path):
    out = tmp_path / "r"
    args = ["train", "--epochs", "1", *TINY, "--out", str(out), "--quiet", "--no-export"]
    assert main(args) == 0
    first = json.loads((out / "metrics.json").read_text())
    assert main([*args, "--overwrite", "--seed", "1"]) == 0
    assert json.loads((out / "config.json").read_text())["pipeline"]["train"]["seed"] == 1
    assert first != json.loads((out / "metrics.json").read_text())


def test_ctrl_c_says_how_to_resume_and_a_failed_start_needs_no_resume(tmp_path, monkeypatch,
                                                                       capsys):  # fmt: skip
    out = tmp_path / "r"
    real = app_run.save_checkpoint

    def interrupt(folder, state):
        real(folder, state)
        raise KeyboardInterrupt

    monkeypatch.setattr(app_run, "save_checkpoint", interrupt)
    args = ["train", "--epochs", "2", *TINY, "--out", str(out), "--quiet", "--no-export"]
    assert main(args) == 130
    err = capsys.readouterr().err
    assert "interrupted; the last finished epoch is saved" in err and "--resume" in err
    monkeypatch.setattr(app_run, "save_checkpoint", real)
    assert main([*args, "--resume"]) == 0

    def fail(*a, **k):
        raise ValueError("bad data")

    out2 = tmp_path / "r2"
    monkeypatch.setattr(app_run, "fit_and_evaluate", fail)
    args2 = ["train", "--epochs", "1", *TINY, "--out", str(out2), "--quiet", "--no-export"]
    assert main(args2) == 2
    monkeypatch.undo()
    assert main(args2) == 0  # the failed start left no checkpoint, so no --resume is asked for


def test_damaged_files_get_errors_not_tracebacks(tmp_path, capsys):
    import numpy as np

    out = tmp_path / "r"
    args = ["train", "--epochs", "1", *TINY, "--out", str(out), "--quiet", "--no-export"]
    assert main(args) == 0
    (out / "weights.npz").write_bytes(b"PK\x03\x04 truncated")
    assert main(["evaluate", str(out), "--quiet"]) == 2
    assert "corrupt or not a weights file" in capsys.readouterr().err
    assert main(["serve", str(tmp_path / "missing.onnx")]) == 2
    assert "does not exist" in capsys.readouterr().err
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a graph")
    assert main(["serve", str(bad)]) == 2
    assert "not a loadable ONNX model" in capsys.readouterr().err
    partial = tmp_path / "c.partial"
    partial.mkdir()
    (partial / "run.json").write_text("{}")
    (partial / "checkpoint.json").write_text("{broken")
    rc = main(
        ["train", "--epochs", "1", *TINY, "--out", str(tmp_path / "c"), "--resume", "--quiet"]
    )
    assert rc == 2 and "damaged" in capsys.readouterr().err
    # an empty batch is an empty answer, for every encoder
    from tactilesnn.app.run import load_run

    assert main([*args[:-4], "--out", str(tmp_path / "s"), "--encoder", "stft", "--quiet",
                 "--no-export"]) == 0  # fmt: skip
    pipe, _ = load_run(tmp_path / "s")
    assert pipe.scores(pipe.encode(np.zeros((0, 2, 100), np.float32))).shape == (0, 2)


def test_nan_weights_are_refused_by_evaluate_and_export(tmp_path, capsys):
    import numpy as np

    out = tmp_path / "r"
    assert main(["train", "--epochs", "1", *TINY, "--out", str(out), "--quiet",
                 "--no-export"]) == 0  # fmt: skip
    with np.load(out / "weights.npz") as f:
        arrays = {k: f[k] for k in f.files}
    key = next(k for k, v in arrays.items() if k.startswith("model.") and v.dtype.kind == "f")
    arrays[key] = arrays[key].copy()
    arrays[key].flat[0] = np.nan
    np.savez(out / "weights.npz", **arrays)
    assert main(["evaluate", str(out), "--quiet"]) == 2
    assert "NaN" in capsys.readouterr().err
    assert main(["export", str(out), "--out", str(tmp_path / "m.onnx")]) == 2
    assert "NaN" in capsys.readouterr().err and not (tmp_path / "m.onnx").exists()
