"""GWT-vs-STFT benchmark: outputs, and the task is not solvable from amplitude alone."""

import json

import numpy as np
import pytest

from tactilesnn.baselines import linear_amplitude_baseline
from tactilesnn.bench import gwt_vs_stft
from tactilesnn.config import PipelineConfig
from tactilesnn.datasets_synth import HookLoopTask
from tactilesnn.training import fit_and_evaluate


@pytest.fixture(scope="session")
def data():
    return HookLoopTask(seed=0).build()


@pytest.mark.slow
def test_spectral_pipeline_beats_amplitude_baseline(data):
    train, test = data
    baseline = linear_amplitude_baseline(train.X, train.y, test.X, test.y)
    res = fit_and_evaluate(PipelineConfig.from_flat(epochs=8), train, test)
    gwt = res.metrics["test_accuracy"]
    assert gwt >= 0.98
    assert baseline <= 0.93, "amplitude statistics alone must not solve the task"
    assert gwt - baseline >= 0.05


@pytest.mark.slow
def test_bench_writes_results_and_plot(tmp_path, capsys):
    out = tmp_path / "bench"
    res = gwt_vs_stft.run(seeds=2, out=out, epochs=1, progress=False)
    printed = capsys.readouterr().out
    assert "GWT" in printed and "STFT" in printed and "99.45" in printed
    saved = json.loads((out / "results.json").read_text())
    assert len(saved["seeds"]) == 2 and (out / "training_error.png").stat().st_size > 1000
    s = res["summary"]["gwt"]
    accs = [r["gwt"]["test_accuracy"] for r in saved["seeds"]]
    assert s["mean"] == pytest.approx(np.mean(accs)) and s["min"] == min(accs)
    with pytest.raises(FileExistsError):
        gwt_vs_stft.run(seeds=1, out=out, epochs=1, progress=False)
