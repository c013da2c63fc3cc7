"""Recordings as they come: timestamped arrays in either axis order (regular or jittered), and
folders of CSV / .npy recordings labelled by sub-folder or file name; the shipped real files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tactilesnn.cli import main
from tactilesnn.readers import MAX_JITTER, read_recordings
from tactilesnn.recordings import load_data_file

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
if not SHARED.is_dir():
    SHARED = Path("/work/shared/data")


def _sines(n: int, c: int, s: int, fs: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """Two classes: a 3 Hz or a 7 Hz sine on every channel, with noise; ``X [n, c, s]``."""
    y = np.arange(n) % 2
    t = np.arange(s) / fs
    f = np.where(y == 0, 3.0, 7.0)
    X = np.sin(2 * np.pi * f[:, None, None] * t) + 0.1 * rng.normal(size=(n, c, s))
    return X.astype(np.float32), y


@pytest.mark.parametrize("order", ["samples_last", "channels_last"])
def test_timestamped_arrays_in_either_order(tmp_path, order):
    rng = np.random.default_rng(0)
    X, y = _sines(20, 3, 200, 100.0, rng)
    t = np.arange(200) / 100.0
    stored = X if order == "samples_last" else X.transpose(0, 2, 1)
    arrays, conv = read_recordings(
        tmp_path / "f.npz", {"X": stored, "y": y, "t": np.tile(t, (20, 1))}
    )
    np.testing.assert_array_equal(arrays["X"], X)
    assert float(arrays["fs"]) == pytest.approx(100.0) and conv.resampled == 0
    assert list(arrays["class_names"]) == ["0", "1"] and "[trials" in conv.layout


def test_jittered_timestamps_are_resampled_onto_a_uniform_grid(tmp_path):
    rng = np.random.default_rng(1)
    fs, s = 200.0, 400
    t = np.cumsum(np.full((4, s), 1 / fs) * (1 + 0.2 * rng.uniform(-1, 1, (4, s))), axis=1)
    X = np.sin(2 * np.pi * 5.0 * t)[:, None, :].astype(np.float32)  # the signal at its true times
    arrays, conv = read_recordings(
        tmp_path / "j.npz", {"X": X, "y": np.array([0, 1, 0, 1]), "t": t}
    )
    assert conv.resampled == 4 and conv.jitter > MAX_JITTER
    step = 1 / float(arrays["fs"])
    grid = np.arange(s) * step
    want = np.sin(2 * np.pi * 5.0 * (t[:, :1] + grid))  # the same sine on the uniform grid
    inside = grid < (t[:, -1:] - t[:, :1]).min()
    err = np.abs(arrays["X"][:, 0] - want)[:, inside]
    assert err.max() < 0.02  # linear interpolation of a 5 Hz sine sampled at ~200 Hz


@pytest.mark.parametrize(
    ("X", "t", "match"),
    [
        (np.zeros((3, 10, 10)), np.arange(10) / 10, "ambiguous"),
        (np.zeros((3, 10, 7)), np.arange(12) / 10, "no axis"),
        (np.zeros((3, 10, 7)), np.r_[np.arange(9), 3.0] / 10, "increase"),
    ],
)
def test_almost_right_files_name_the_fix(tmp_path, X, t, match):
    with pytest.raises(ValueError, match=match):
        read_recordings(tmp_path / "x.npz", {"X": X, "y": np.arange(3) % 2, "t": t})


def _write_csv(path: Path, X: np.ndarray, t0: int, step: int) -> None:
    cols = ["timestamp", *(f"channel{i + 1}" for i in range(X.shape[0]))]
    rows = np.column_stack([t0 + step * np.arange(X.shape[1]), X.T])
    fmt = ["%d", *(["%.6g"] * X.shape[0])]
    np.savetxt(path, rows, delimiter=",", header=", ".join(cols), comments="", fmt=fmt)


@pytest.mark.slow
@pytest.mark.parametrize("labels_by", ["file_name", "sub_folder"])
def test_a_folder_of_csv_recordings_of_different_lengths_trains(tmp_path, labels_by, capsys):
    rng = np.random.default_rng(2)
    folder = tmp_path / "slides"
    for i in range(16):
        name = ("Cotton", "Denim")[i % 2]
        n = 120 + 13 * i  # different lengths
        X, _ = _sines(1, 2, n, 100.0, rng)
        X = X[0] if i % 2 == 0 else _sines(2, 2, n, 100.0, rng)[0][1]
        if labels_by == "file_name":
            path = folder / f"{name}_F120_V-10mmps_{i}.csv"
        else:
            path = folder / name / f"slide{i}.csv"
        path.parent.mkdir(parents=True, exist_ok=True)
        _write_csv(path, X, 4277465, 10)  # integer ticks of unstated unit
    arrays, conv = read_recordings(folder)
    assert list(arrays["class_names"]) == ["Cotton", "Denim"]
    assert arrays["X"].shape[1:] == (2, 120) and list(arrays["channel_names"]) == ["channel1",
                                                                                    "channel2"]  # fmt: skip
    assert len(np.unique(arrays["recording"])) == 16 and "taken as ms" in conv.line()
    tr, te = load_data_file(folder, seed=0)
    assert not set(tr.scan) & set(te.scan)  # windows of one recording on one side
    out = tmp_path / "run"
    assert main(["train", "--data", str(folder), "--out", str(out), "--quiet", "--no-export",
                 "--epochs", "10"]) == 0  # fmt: skip
    text = capsys.readouterr().out
    assert "per recording" in text and (out / "metrics.json").is_file()


def test_a_folder_with_one_label_says_how_to_label(tmp_path):
    folder = tmp_path / "f"
    folder.mkdir()
    for i in range(3):
        _write_csv(folder / f"same_{i}.csv", np.zeros((2, 50)), 0, 1)
    with pytest.raises(ValueError, match="sub-folder"):
        read_recordings(folder)


@pytest.mark.data
@pytest.mark.skipif(not (SHARED / "braille_icub_abc").is_dir(), reason="shared data not here")
def test_the_shipped_braille_file_reads_as_it_comes():
    tr, te = load_data_file(SHARED / "braille_icub_abc" / "braille_abc_icub.npz", seed=0)
    assert tr.X.shape[1:] == (12, 350) and tr.fs_hz == pytest.approx(94.0, abs=0.5)
    assert tr.class_names == ("A", "B", "C") and len(tr) + len(te) == 45


@pytest.mark.data
@pytest.mark.skipif(not (SHARED / "fabric_slide").is_dir(), reason="shared data not here")
def test_the_shipped_fabric_slides_read_as_they_come():
    arrays, conv = read_recordings(SHARED / "fabric_slide" / "fabric")
    assert len(arrays["class_names"]) == 7 and len(np.unique(arrays["recording"])) == 966
    assert arrays["X"].shape[1] == 18 and arrays["X"].shape[2] == 141
    assert "taken as ms" in conv.line()


def test_convert_writes_the_documented_format_and_refuses_to_overwrite(tmp_path, capsys):
    rng = np.random.default_rng(3)
    X, y = _sines(10, 2, 120, 100.0, rng)
    src = tmp_path / "raw.npz"
    np.savez(src, X=X.transpose(0, 2, 1), y=y, t=np.arange(120) / 100.0)
    out = tmp_path / "converted.npz"
    assert main(["convert", str(src), "--out", str(out)]) == 0
    with np.load(out) as f:
        assert f["X"].shape == (10, 2, 120) and float(f["fs"]) == pytest.approx(100.0)
    assert main(["convert", str(src), "--out", str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err


def test_timestamps_stored_as_one_value_get_an_error_not_a_traceback(tmp_path):
    import numpy as np
    import pytest

    from tactilesnn.recordings import load_data_file

    path = tmp_path / "t0.npz"
    np.savez(path, X=np.zeros((4, 50, 2), np.float32), t=np.array(0.01), y=np.arange(4) % 2)
    with pytest.raises(ValueError, match="t must be the samples' times in seconds"):
        load_data_file(path, 0)
