"""Nothing a user wrote is lost: --overwrite replaces only what tactilesnn wrote."""

import json
import os

import pytest

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


@pytest.mark.slow
def test_overwrite_replaces_its_own_run(tmp_path):
    out = tmp_path / "r"
    args = ["train", "--epochs", "1", *TINY, "--out", str(out), "--quiet", "--no-export"]
    assert main(args) == 0
    first = json.loads((out / "metrics.json").read_text())
    assert main([*args, "--overwrite", "--seed", "1"]) == 0
    assert json.loads((out / "config.json").read_text())["pipeline"]["train"]["seed"] == 1
    assert first != json.loads((out / "metrics.json").read_text())


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
def test_a_users_partial_folder_symlink_or_file_is_never_removed(tmp_path, capsys):
    out = tmp_path / "r"
    args = ["train", "--epochs", "1", *TINY, "--out", str(out), "--quiet", "--no-export"]
    partial = tmp_path / "r.partial"
    partial.mkdir()  # the user's own folder of that name, with their notes
    (partial / "notes.txt").write_text("mine")
    for extra in ([], ["--overwrite"]):
        assert main([*args, *extra]) == 2
        assert "did not write" in capsys.readouterr().err
        assert (partial / "notes.txt").read_text() == "mine"
    (partial / "notes.txt").unlink()
    assert main(args) == 2  # an empty folder tactilesnn did not make is not removed either
    assert "did not make" in capsys.readouterr().err and partial.is_dir()
    partial.rmdir()
    target = tmp_path / "elsewhere"
    target.mkdir()
    (target / "keep").write_text("x")
    partial.symlink_to(target)
    assert main(args) == 2 and "a link or a file" in capsys.readouterr().err
    assert (target / "keep").read_text() == "x"
    partial.unlink()
    partial.write_text("a file")
    assert main([*args, "--overwrite"]) == 2 and "a link or a file" in capsys.readouterr().err
    assert partial.read_text() == "a file"
    partial.unlink()
    assert main(args) == 0  # and with the way clear, it trains


@pytest.mark.slow
def test_overwrite_keeps_the_users_files_inside_a_run_folder(tmp_path, capsys):
    out = tmp_path / "r"
    args = ["train", "--epochs", "1", *TINY, "--out", str(out), "--quiet", "--no-export"]
    assert main(args) == 0
    (out / "my_notes.md").write_text("findings")
    assert main([*args, "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert "my_notes.md" in err and "did not write" in err
    assert (out / "my_notes.md").read_text() == "findings"
    (out / "my_notes.md").unlink()
    assert main([*args, "--overwrite"]) == 0


@pytest.mark.slow
def test_two_trainings_into_one_out_are_refused_up_front(tmp_path, capsys):
    import os

    from tactilesnn.app.runs import OutLock

    out = tmp_path / "r"
    with OutLock(out):  # another process (here: this one) is writing --out
        rc = main(["train", "--epochs", "1", *TINY, "--out", str(out), "--quiet", "--no-export"])
        assert rc == 2 and f"pid {os.getpid()}" in capsys.readouterr().err
        assert not out.exists() and not (tmp_path / "r.partial").exists()
    # a lock left by a process that is gone is taken over
    (tmp_path / "r.lock").write_text(json.dumps({"pid": 2**22 + 12345, "token": "0" * 32}))
    assert main(["train", "--epochs", "1", *TINY, "--out", str(out), "--quiet",
                 "--no-export"]) == 0  # fmt: skip
    assert not (tmp_path / "r.lock").exists()


@pytest.mark.parametrize("content", ["my notes\n", "", '{"pid": 1}', '{"other": "json"}'])
def test_a_file_at_the_lock_name_that_is_not_ours_is_refused_and_kept(tmp_path, content):
    """A user's file at ``<out>.lock`` (or an empty one: a lock of ours always holds its pid and
    token, written in one step) is never taken for a stale lock and deleted."""
    from tactilesnn.app.runs import OutLock, RunExistsError

    lock = tmp_path / "r.lock"
    lock.write_text(content)
    with pytest.raises(RunExistsError, match="is not a tactilesnn lock"), OutLock(tmp_path / "r"):
        pass
    assert lock.read_text() == content
    assert not list(tmp_path.glob("*.tmp"))  # the lock's temporary file is gone too


def test_temporary_folders_of_a_killed_run_are_cleaned_and_foreign_ones_kept(tmp_path):
    from tactilesnn.app.runs import MARKER, RunWriter

    stale = tmp_path / ".r.abc123"
    stale.mkdir()
    (stale / "weights.npz").write_bytes(b"x")
    (stale / MARKER).write_text(json.dumps({"kind": "tmp", "token": "1" * 32, "pid": 2**22 + 7,
                                            "files": ["weights.npz"]}))  # fmt: skip
    foreign = tmp_path / ".r.users"
    foreign.mkdir()
    (foreign / "data.bin").write_bytes(b"y")
    w = RunWriter(tmp_path / "r")
    w.abort()
    assert not stale.exists() and (foreign / "data.bin").read_bytes() == b"y"


@pytest.mark.slow
def test_resume_refuses_changed_data_and_evaluate_uses_the_trained_file(tmp_path, capsys):
    import numpy as np

    rng = np.random.default_rng(0)
    X = rng.normal(size=(24, 2, 64)).astype(np.float32)
    y = np.repeat([0, 1], 12)
    X[y == 1, 0] += 2.0
    split = np.tile([0, 0, 1], 8)  # the same split whatever the class order
    data = tmp_path / "d.npz"
    np.savez(data, X=X, y=y, fs=np.float64(100.0), class_names=np.array(["a", "b"]), split=split)
    out = tmp_path / "r"
    args = ["train", "--data", str(data), "--encoder", "lif", "--epochs", "3", "--out", str(out),
            "--quiet", "--no-export"]  # fmt: skip
    real = app_run.save_checkpoint

    def interrupt(folder, state):
        real(folder, state)
        raise KeyboardInterrupt

    import pytest

    mp = pytest.MonkeyPatch()
    mp.setattr(app_run, "save_checkpoint", interrupt)
    assert main(args) == 130
    mp.undo()
    X2 = X.copy()
    X2[0, 0, 0] += 1.0  # the file changed since
    np.savez(data, X=X2, y=y, fs=np.float64(100.0), class_names=np.array(["a", "b"]), split=split)
    assert main([*args, "--resume"]) == 2 and "same data" in capsys.readouterr().err
    np.savez(data, X=X, y=y, fs=np.float64(100.0), class_names=np.array(["a", "b"]), split=split)
    assert main([*args, "--resume"]) == 0
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["data"] == str(data.resolve()) and len(cfg["data_sha256"]) == 64
    # evaluated from another directory: the run's own (absolute) file
    here = tmp_path / "elsewhere"
    here.mkdir()
    (here / "d.npz").write_bytes(b"not the data")
    cwd = os.getcwd()
    try:
        os.chdir(here)
        assert main(["evaluate", str(out), "--quiet", "--json"]) == 0
    finally:
        os.chdir(cwd)
    # the same recordings with their classes listed in the other order score the same
    before = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["test_accuracy"]
    swapped = tmp_path / "swapped.npz"
    np.savez(
        swapped, X=X, y=1 - y, fs=np.float64(100.0), class_names=np.array(["b", "a"]), split=split
    )
    assert main(["evaluate", str(out), "--data", str(swapped), "--quiet", "--json"]) == 0
    after = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["test_accuracy"]
    assert after == before
    other = tmp_path / "other.npz"
    np.savez(other, X=X, y=y, fs=np.float64(100.0), class_names=np.array(["a", "zz"]), split=split)
    assert main(["evaluate", str(out), "--data", str(other), "--quiet"]) == 2
    assert "not among the run's" in capsys.readouterr().err
    # the data file changed after training: evaluate says so instead of scoring it
    np.savez(data, X=X2, y=y, fs=np.float64(100.0), class_names=np.array(["a", "b"]), split=split)
    assert main(["evaluate", str(out), "--quiet"]) == 2
    assert "changed since the run was trained" in capsys.readouterr().err


def test_a_full_disk_is_an_error_not_a_traceback_and_leaves_no_temporaries(tmp_path, monkeypatch,
                                                                          capsys):  # fmt: skip
    import errno

    import numpy as np

    from tactilesnn.app import runs

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device", str(a[0]))

    monkeypatch.setattr(np, "savez", full)
    out = tmp_path / "r"
    rc = main(["train", "--epochs", "1", *TINY, "--out", str(out), "--quiet", "--no-export"])
    assert rc == 2 and "No space left on device" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob(".r.*"))
    assert not list(tmp_path.glob("r.partial/*.tmp*")) and not (tmp_path / "r.lock").exists()
    assert runs.MARKER  # the checkpoint folder left behind is marked as tactilesnn's own


def test_toml_types_and_nesting_are_checked(tmp_path, capsys):
    cases = {
        'overwrite = "false"\n': "must be true or false",
        "resume = 1\n": "must be true or false",
        "out = 5\n": "must be text",
        "epochs = 1e9\n": "must be an integer",
        "clock_afferents = 1000000000\n": "at most 1024",
        "x = " + "[" * 5000 + "]" * 5000 + "\n": "nested",
        "task = 3\n": "must be text",
    }
    for body, match in cases.items():
        cfg = tmp_path / "c.toml"
        cfg.write_text(body)
        rc = main(["train", "--config", str(cfg), "--out", str(tmp_path / "o"), "--quiet"])
        err = capsys.readouterr().err
        assert rc == 2 and match in err, (body[:30], err)
        assert "Traceback" not in err


def test_a_load_failure_leaves_nothing_behind(tmp_path, capsys):
    import numpy as np

    bad = tmp_path / "bad.npz"
    np.savez(bad, X=np.zeros((4, 2, 50), np.float32), y=np.array([0, 1, 0, 1]))  # no fs, no t
    out = tmp_path / "r"
    assert main(["train", "--data", str(bad), "--out", str(out), "--quiet"]) == 2
    assert "missing" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npz"]


def test_a_model_too_large_for_memory_is_refused_before_it_is_built(tmp_path, monkeypatch, capsys):
    import numpy as np

    import tactilesnn.core.checks as checks

    monkeypatch.setattr(checks, "memory_limit_bytes", lambda: 4 << 30)
    wide = tmp_path / "wide.npz"
    np.savez(wide, X=np.random.default_rng(0).random((6, 200_000, 2), np.float32),
             y=np.array([0, 1] * 3), fs=np.array(100.0), class_names=np.array(["a", "b"]))  # fmt: skip
    rc = main(["train", "--data", str(wide), "--out", str(tmp_path / "r"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "select fewer with 'channels'" in err and "GiB" in err
    assert not (tmp_path / "r").exists() and not (tmp_path / "r.partial").exists()


@pytest.mark.parametrize("pipeline", ["[]", '"gwt"', "null"])
def test_a_damaged_run_config_is_an_error_naming_it(tmp_path, pipeline):
    from tactilesnn.app.run import load_run

    run = tmp_path / "run"
    run.mkdir()
    cfg = {"fs_hz": 100, "window": 50, "channel_names": ["a"], "class_names": ["x", "y"]}
    (run / "config.json").write_text(json.dumps(cfg)[:-1] + f', "pipeline": {pipeline}}}')
    (run / "weights.npz").write_bytes(b"")
    with pytest.raises(ValueError, match=r"config.json is damaged \(pipeline"):
        load_run(run)


@pytest.mark.slow
def test_a_full_disk_during_an_export_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch,
                                                                           capsys):  # fmt: skip
    """The graph half-written when the disk fills: the error names it, the file already at
    ``--out`` is untouched and no ``.m.onnx.tmp`` is left (every atomic write goes through
    ``core.files.replace_atomically``)."""
    import errno

    import onnx

    run = tmp_path / "r"
    assert main(["train", "--epochs", "1", *TINY, "--out", str(run), "--quiet", "--no-export"]) == 0
    target = tmp_path / "m.onnx"
    target.write_bytes(b"the user's previous export")

    def full(model, path, *a, **k):
        with open(path, "wb") as f:
            f.write(b"half a graph")
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(onnx, "save", full)
    rc = main(["export", str(run), "--out", str(target), "--overwrite", "--quiet"])
    assert rc == 2 and "No space left on device" in capsys.readouterr().err
    assert target.read_bytes() == b"the user's previous export"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.onnx", "r"]
