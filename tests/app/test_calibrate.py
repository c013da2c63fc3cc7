"""``tactilesnn calibrate``: errors before any work, the fit file and picture written, and the
statistics-only comparison for a sensor the task cannot be fitted to."""

import json

import numpy as np
import pytest

from tactilesnn.app import calibrate as cal
from tactilesnn.cli import main
from tactilesnn.datasets_synth import get_task


def _braille_file(path, n=6):
    task = get_task("braille", seed=3, n_samples=n, fs_frames_hz=90.0, duration_s=2.0)
    X = np.stack([task.sample(i)[0] for i in range(n)]).astype(np.float32)
    np.savez(path, X=X, y=np.arange(n) % 3, fs=90.0, class_names=np.array(["A", "B", "C"]))
    return path


def test_errors_before_work(tmp_path):
    data = _braille_file(tmp_path / "b.npz")
    (tmp_path / "fit.json").write_text("{}")
    with pytest.raises(FileExistsError, match="--overwrite"):
        cal.calibrate(data, "braille", tmp_path / "fit.json")
    with pytest.raises(ValueError, match=r"distinct indices in 0\.\.5"):
        cal.calibrate(data, "braille", tmp_path / "new.json", recordings=[0, 9])
    with pytest.raises(ValueError, match="unknown task"):
        cal.calibrate(data, "nope", tmp_path / "new.json")
    with pytest.raises(ValueError, match="cannot be calibrated"):
        cal.calibrate(data, "texture", tmp_path / "new.json")
    with pytest.raises(ValueError, match="unknown fitted value 'speed'"):
        cal.calibrate(data, "braille", tmp_path / "new.json", known={"speed": 10.0})
    assert json.loads((tmp_path / "fit.json").read_text()) == {}  # left as it was
    assert not (tmp_path / "new.json").exists()


def test_known_flag_parses_name_value_pairs(capsys):
    with pytest.raises(SystemExit):
        main(["calibrate", "--data", "x.npz", "--out", "f.json", "--known", "speed_mm_s"])
    assert "expected NAME=NUMBER, got 'speed_mm_s'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["calibrate", "--data", "x.npz", "--out", "f.json", "--known", "force_N=a"])
    assert "expected NAME=NUMBER" in capsys.readouterr().err


@pytest.mark.slow
def test_calibrate_writes_a_fit_a_task_reads(tmp_path, capsys):
    data = _braille_file(tmp_path / "b.npz")
    rc = main(["calibrate", "--data", str(data), "--task", "braille", "--out",
               str(tmp_path / "fit.json"), "--recordings", "0", "1", "2", "--evaluations", "20",
               "--plot", str(tmp_path / "fit.png"), "--optimiser", "random", "--quiet",
               "--known", "speed_mm_s=10.07"])  # fmt: skip
    assert rc == 0
    out = capsys.readouterr().out
    assert "calibrated braille on 3 recordings" in out and "wrote" in out
    assert (tmp_path / "fit.png").stat().st_size > 0
    fit = json.loads((tmp_path / "fit.json").read_text())
    assert fit["fitted_on"]["recordings"] == [0, 1, 2] and fit["objective"]["evaluations"] >= 20
    assert fit["objective"]["optimiser"] == "uniform random"  # the choice reaches the search
    assert fit["scene"]["speed_mm_s"] == 10.07  # --known reaches the fit
    task = get_task("braille", calibration=str(tmp_path / "fit.json"), n_samples=6,
                    fs_frames_hz=90.0, duration_s=2.0)  # fmt: skip
    x, _, _ = task.sample(0)
    assert x.shape == (12, 180) and np.isfinite(x).all()


def test_statistics_only_says_what_the_model_cannot_express(tmp_path):
    rng = np.random.default_rng(0)
    X = 100 + rng.normal(0, 2, (12, 16, 150)).cumsum(-1) * 0.1
    np.savez(tmp_path / "r.npz", X=X.astype(np.float32), y=np.arange(12) % 2, fs=35.0,
             class_names=np.array(["Denim", "Linen"]))  # fmt: skip
    lines = cal.compare(
        tmp_path / "r.npz", "texture", tmp_path / "s.json", tmp_path / "s.png", n=24
    )
    res = json.loads((tmp_path / "s.json").read_text())
    assert any("16 channels in the recordings, 2 in the model" in g for g in res["cannot_express"])
    assert any("linen" in g for g in res["cannot_express"]) and res["shared_classes"] == ["denim"]
    assert np.isfinite(res["spectrum_shape_rms_decades"])
    assert (tmp_path / "s.png").stat().st_size > 0 and "wrote" in lines[-1]
