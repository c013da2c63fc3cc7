"""Sharded generation: determinism across worker counts, manifest, no overwrite, resume."""

import json

import numpy as np
import pytest

import tactilesnn.datasets_synth.generate as gen
from tactilesnn.cli import main
from tactilesnn.core.dataset_folder import ShardDataset
from tactilesnn.datasets_synth import HookLoopTask
from tactilesnn.datasets_synth.generate import generate


def test_workers_do_not_change_the_data(tmp_path):
    a = generate("hook_loop", 6, 3, tmp_path / "a", shard_size=2, workers=1, progress=False)
    b = generate("hook_loop", 6, 3, tmp_path / "b", shard_size=2, workers=2, progress=False)
    assert [s["sha256"] for s in a["shards"]] == [s["sha256"] for s in b["shards"]]
    ds = ShardDataset(tmp_path / "a")
    task = HookLoopTask(seed=3)
    X, y = task.windows(*task.scan(4)[:2])
    first = int(ds.offsets[2])  # shard 2 starts with sample 4
    np.testing.assert_array_equal(ds[first][0], X[0])
    assert ds[first][1] == y[0] and len(ds) == a["n_windows"]
    m = json.loads((tmp_path / "a" / "manifest.json").read_text())
    assert m["fs_hz"] == 200.0 and m["class_names"] == ["hook", "loop"] and m["generator"]


def test_refuses_overwrite_and_resumes_after_interruption(tmp_path, monkeypatch, capsys):
    out = tmp_path / "d"
    real = gen._render_shard
    calls = {"n": 0}

    def crash_on_third(job):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return real(job)

    monkeypatch.setattr(gen, "_render_shard", crash_on_third)
    with pytest.raises(KeyboardInterrupt):
        generate("hook_loop", 8, 0, out, shard_size=2, workers=1, progress=False)
    monkeypatch.setattr(gen, "_render_shard", real)
    assert (out / "manifest.partial.json").exists() and not (out / "manifest.json").exists()
    with pytest.raises(FileExistsError, match="--resume"):
        generate("hook_loop", 8, 0, out, shard_size=2, workers=1, progress=False)
    done = generate("hook_loop", 8, 0, out, shard_size=2, workers=1, progress=False, resume=True)
    ref = generate("hook_loop", 8, 0, tmp_path / "ref", shard_size=2, workers=1, progress=False)
    assert [s["sha256"] for s in done["shards"]] == [s["sha256"] for s in ref["shards"]]
    assert main(["generate", "--n", "2", "--out", str(out), "--quiet"]) == 2
    assert "already holds a dataset" in capsys.readouterr().err
    with pytest.raises(FileNotFoundError, match="manifest"):
        ShardDataset(tmp_path)
