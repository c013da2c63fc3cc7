"""Run folders written before the component layer (flat config, old weight keys) still load.

The fixtures were written by the code on main before the refactor: ``config.json`` +
``weights.npz`` + the scores that code gave on ``windows.npy``.
"""

from pathlib import Path

import numpy as np
import pytest

from tactilesnn.app.run import load_run

FIX = Path(__file__).parent / "fixtures" / "legacy_runs"


@pytest.mark.parametrize("name", ["gwt_tempotron", "stft_snn", "lif_snn"])
def test_legacy_run_folder_loads_and_scores_as_before(name):
    pipe, cfg = load_run(FIX / name)
    assert isinstance(cfg["pipeline"]["encoder"], str)  # really the old flat form
    X = np.load(FIX / "windows.npy", allow_pickle=False)
    want = np.load(FIX / name / "scores.npy", allow_pickle=False)
    got = pipe.scores(pipe.encode(X)).numpy()
    assert np.array_equal(got.argmax(1), want.argmax(1))
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
