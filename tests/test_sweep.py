"""Sweeps: deterministic trials, resume, refused settings, and a Dask worker killed mid-sweep."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from tactilesnn.app.sweep import check_trial, load_sweep, run_sweep, trial_id, trials
from tactilesnn.cli import main

SMALL = 'task_kw = ["n_planar=16", "n_concave=8", "n_convex=8", "n_test=8"]'


def _write(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "sweep.toml"
    path.write_text(body)
    return path


def test_grid_and_random_trials_are_deterministic_and_bad_settings_refused(tmp_path):
    grid = load_sweep(_write(tmp_path, '[base]\nepochs = 1\n[grid]\nencoder = ["gwt", "stft"]\n'
                             "n_bands = [8, 12, 16]\n"))  # fmt: skip
    t = trials(grid)
    assert len(t) == 6 and t[0] == {"epochs": 1, "encoder": "gwt", "n_bands": 8}
    assert [trial_id(i, s) for i, s in enumerate(t)] == [
        trial_id(i, s) for i, s in enumerate(trials(grid))
    ]
    rnd = load_sweep(_write(tmp_path, "[random]\ntrials = 5\nseed = 3\n[random.space]\n"
                            "readout_lr = {log_uniform = [1e-3, 1e-1]}\nn_bands = [8, 16]\n"))  # fmt: skip
    a, b = trials(rnd), trials(rnd)
    assert a == b and all(1e-3 <= s["readout_lr"] <= 1e-1 for s in a)
    assert len({s["readout_lr"] for s in a}) == 5
    # a trial is a RunSpec built as train builds one (no command line in between)
    spec = check_trial({"task_kw": ["n_planar=6", "n_test=2"], "stats": ["mean", "max"],
                        "model": "snn", "snn_recurrent": False, "epochs": 2})  # fmt: skip
    assert spec.source.params["n_planar"] == 6 and spec.source.params["n_test"] == 2
    assert spec.config.encoder.stats == ("mean", "max") and spec.config.model.recurrent is False
    assert spec.config.train.epochs == 2 and spec.export
    for body, match in [
        ("[grid]\nn_bandz = [1]\n", "n_bandz"),
        ("[grid]\nout = ['x']\n", "out"),
        ("[grid]\nn_bands = []\n", "non-empty"),
        ("[base]\nepochs = 1\n", "exactly one"),
        ("[random]\ntrials = 2\n[random.space]\nlr = {uniform = [2, 1]}\n", "lo < hi"),
        ("[grid\n", "TOML"),
        ("[base]\nepochs = '3'\n[grid]\nseed = [1]\n", "integer"),
        ("[base]\nexport = 'false'\n[grid]\nseed = [1]\n", "true or false"),
        ("[random]\ntrials = 100000000\n", "1-10000"),
        (
            "[grid]\n"
            + "\n".join(
                f"{k} = {list(range(59))}" for k in ("seed", "epochs", "n_bands", "batch_size")
            ),
            "combinations",
        ),
    ]:
        with pytest.raises(ValueError, match=match):
            load_sweep(_write(tmp_path, body))
    with pytest.raises(ValueError, match="not valid train settings"):
        run_sweep(_write(tmp_path, "[grid]\nencoder = ['nope']\n"), tmp_path / "o", workers=1)


@pytest.mark.slow
def test_local_sweep_gathers_a_table_and_resumes_without_rerunning(tmp_path, capsys):
    cfg = _write(
        tmp_path,
        f"[base]\nmodel = 'readout'\nepochs = 3\n{SMALL}\n[grid]\nencoder = ['gwt', 'stft']\n",
    )
    out = tmp_path / "sweep"
    assert main(["sweep", "--config", str(cfg), "--out", str(out), "--workers", "1",
                 "--quiet"]) == 0  # fmt: skip
    rows = json.loads((out / "results.json").read_text())
    assert len(rows) == 2 and all(0.7 <= r["test_accuracy"] <= 1 for r in rows)
    assert rows[0]["test_accuracy"] >= rows[1]["test_accuracy"]
    for r in rows:  # each trial is a normal run folder
        assert (out / "trials" / r["trial"] / "model.onnx").is_file()
    assert any(r["pareto_front"] for r in rows)  # error vs training time
    assert (out / "results.png").stat().st_size > 10_000
    table = (out / "results.md").read_text()
    assert "| trial | encoder | test accuracy" in table and table.count("\n") == 4
    stamp = {p: p.stat().st_mtime_ns for p in out.glob("trials/*/metrics.json")}
    assert main(["sweep", "--config", str(cfg), "--out", str(out), "--quiet"]) == 0
    assert {p: p.stat().st_mtime_ns for p in out.glob("trials/*/metrics.json")} == stamp
    assert json.loads((out / "results.json").read_text()) == rows


@pytest.mark.slow
def test_dask_sweep_completes_when_a_worker_is_killed(tmp_path):
    distributed = pytest.importorskip("distributed")
    cfg = _write(tmp_path, f"[base]\nepochs = 3\n{SMALL}\n[grid]\nencoder = ['gwt', 'stft']\n"
                 "n_bands = [8, 16]\n")  # fmt: skip
    out = tmp_path / "sweep"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:  # fmt: skip
        result: dict = {}

        def sweep() -> None:
            try:
                result["rows"] = run_sweep(cfg, out, scheduler=cluster.scheduler_address,
                                           progress=False)  # fmt: skip
            except BaseException as e:  # reported by the assertion below
                result["error"] = e

        th = threading.Thread(target=sweep)
        th.start()
        pids = list(client.run(os.getpid).values())
        deadline = time.monotonic() + 120
        # kill a worker while it trains a trial (its checkpoint folder exists)
        while not any(out.glob("trials/*.partial")) and time.monotonic() < deadline:
            time.sleep(0.05)
        finished_at_kill = len(list(out.glob("trials/*/metrics.json")))
        os.kill(pids[0], signal.SIGKILL)
        th.join(timeout=600)
    assert finished_at_kill < 4  # the worker died mid-sweep
    assert "error" not in result, result.get("error")
    rows = result["rows"]
    assert len(rows) == 4 and all("test_accuracy" in r for r in rows)
    assert len(list(out.glob("trials/*/metrics.json"))) == 4


def test_the_shipped_sweep_files_are_valid():
    from tactilesnn.app.sweep import check_trial

    files = sorted((Path(__file__).resolve().parents[1] / "configs").glob("sweep*.toml"))
    assert files
    for f in files:
        for s in trials(load_sweep(f)):
            check_trial(s)


@pytest.mark.slow
def test_generate_on_a_dask_cluster_writes_the_same_shards(tmp_path):
    distributed = pytest.importorskip("distributed")
    from tactilesnn.datasets_synth.generate import generate

    local = generate("touch", 6, 1, tmp_path / "local", shard_size=2, workers=1, progress=False)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:  # fmt: skip
        dask = generate("touch", 6, 1, tmp_path / "dask", shard_size=2, progress=False,
                        scheduler=cluster.scheduler_address)  # fmt: skip
    assert [s["sha256"] for s in dask["shards"]] == [s["sha256"] for s in local["shards"]]


def test_demo_stream_without_a_service_is_a_clear_error(capsys):
    port = 1  # nothing listens there
    rc = main(["demo-stream", "--url", f"http://127.0.0.1:{port}", "--seconds", "1"])
    assert rc == 2 and "is tactilesnn serve running" in capsys.readouterr().err
