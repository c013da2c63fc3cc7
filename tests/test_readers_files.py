"""Folders of recordings as people save them (issue 44/45): headerless CSVs, no time column
(``--fs``), spreadsheet exports, decimal commas, timestamps in ns, mixed rates, symbolic links,
forged ``.npy`` headers; each refusal names the file and what to do."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from tactilesnn.app.convert import convert
from tactilesnn.cli import main
from tactilesnn.readers import read_recordings
from tactilesnn.recordings import load_data_file, read_data_arrays

FREQS = {"Velvet": 4.0, "Denim": 9.0, "Silk": 15.0}


def _signal(cls: str, n: int, fs: float, channels: int, rng) -> np.ndarray:
    """``[n, channels]``: the class's sine (Hz) on every channel with a per-channel phase."""
    t = np.arange(n) / fs
    phase = rng.uniform(0, 2 * np.pi, channels)
    return (
        100
        + 20 * np.sin(2 * np.pi * FREQS[cls] * t[:, None] + phase)
        + rng.normal(0, 1, (n, channels))
    )


def headerless_folder(root: Path, fs: float = 357.0, per_class: int = 6) -> Path:
    """16 taxel columns of integers, no header, no time column; label = name before the first
    ``_`` (``Velvet_12.5_-0.02.csv``)."""
    rng = np.random.default_rng(0)
    root.mkdir()
    for cls in FREQS:
        for r in range(per_class):
            n = int(rng.integers(700, 900))
            X = np.round(_signal(cls, n, fs, 16, rng)).astype(int)
            np.savetxt(root / f"{cls}_{12.5 + r}_-0.02.csv", X, fmt="%d", delimiter=",")
    return root


def spreadsheet_folder(root: Path, fs: float = 100.0) -> Path:
    """What a spreadsheet saves: a byte-order mark, a title line, ~1,000 columns of which 35
    hold numbers (time + 34 sensors), one sub-folder per class, names with spaces, one file
    much shorter than the others."""
    rng = np.random.default_rng(1)
    for cls in FREQS:
        (root / f"class {cls}").mkdir(parents=True)
        for r in range(5):
            n = 60 if (cls, r) == ("Silk", 4) else 400
            X = _signal(cls, n, fs, 34, rng)
            lines = ["Measurement export, sensor array" + "," * 998,
                     ",".join(["Time (s)", *(f"sensor {i}" for i in range(34))]) + "," * 965]  # fmt: skip
            lines += [",".join([f"{i / fs:.4f}", *(f"{v:.4f}" for v in row)]) + "," * 965
                      for i, row in enumerate(X)]  # fmt: skip
            (root / f"class {cls}" / f"recording {r}.csv").write_text(
                "\r\n".join(lines) + "\r\n", encoding="utf-8-sig"
            )
    return root


def _timed_folder(root: Path, rates: dict[str, float], fmt) -> Path:
    """A folder of CSVs with a time column written by ``fmt(t_seconds)``; ``rates``: file
    stem -> Hz."""
    rng = np.random.default_rng(2)
    root.mkdir()
    for stem, fs in rates.items():
        cls = stem.split("_")[0]
        n = int(2.0 * fs)
        X = _signal(cls, n, fs, 3, rng)
        t = 1_764_000_000.0 + np.arange(n) / fs
        rows = [f"{fmt(t[i])},{X[i, 0]:.4f},{X[i, 1]:.4f},{X[i, 2]:.4f}" for i in range(n)]
        (root / f"{stem}.csv").write_text("\n".join(["timestamp,a,b,c", *rows]) + "\n")
    return root


@pytest.mark.slow
def test_a_headerless_folder_needs_fs_and_then_trains(tmp_path, capsys):
    folder = headerless_folder(tmp_path / "slides")
    with pytest.raises(ValueError, match=r"Denim_12.5_-0.02.csv: no time column .* --fs HZ"):
        read_data_arrays(folder)
    assert main(["train", "--data", str(folder), "--out", str(tmp_path / "run")]) == 2  # read error
    assert "--fs HZ" in capsys.readouterr().err
    arrays = read_data_arrays(folder, fs_hz=357.0)
    assert arrays["X"].shape[1] == 16 and float(arrays["fs"]) == 357.0
    assert list(arrays["channel_names"]) == [f"col{i}" for i in range(1, 17)]
    assert list(arrays["class_names"]) == ["Denim", "Silk", "Velvet"]
    out = tmp_path / "run"
    rc = main(["train", "--data", str(folder), "--fs", "357", "--out", str(out), "--no-export",
               "--epochs", "2"])  # fmt: skip
    assert rc == 0 and (out / "metrics.json").is_file()
    assert '"data_fs_hz": 357.0' in (out / "config.json").read_text()
    assert main(["evaluate", str(out), "--json"]) == 0  # the run's rate is remembered


@pytest.mark.slow
def test_a_spreadsheet_export_converts_and_round_trips(tmp_path):
    folder = spreadsheet_folder(tmp_path / "sheets")
    report = convert(folder, None, dry_run=True)
    text = "\n".join(report.lines())
    assert "byte-order mark" in text and "title line" in text
    assert "recording 4.csv" in text and "left out" in text  # the one short file
    assert report.fs_hz == pytest.approx(100.0) and len(report.channels) == 34
    assert report.channels[0] == "sensor 0" and set(report.classes) == {
        "class Denim", "class Silk", "class Velvet"}  # fmt: skip
    assert not (tmp_path / "out.npz").exists()
    convert(folder, tmp_path / "out.npz")
    again = read_data_arrays(tmp_path / "out.npz")
    first = read_data_arrays(folder)
    for key in ("X", "y", "recording", "class_names", "channel_names"):
        np.testing.assert_array_equal(again[key], first[key])


def test_decimal_commas_and_semicolons(tmp_path):
    rng = np.random.default_rng(3)
    root = tmp_path / "eu"
    root.mkdir()
    for cls in ("Velvet", "Denim"):
        for r in range(3):
            X = _signal(cls, 300, 200.0, 2, rng)
            rows = [
                f"{i / 200:.4f};{X[i, 0]:.3f};{X[i, 1]:.3f}".replace(".", ",") for i in range(300)
            ]
            (root / f"{cls}-{r}.csv").write_text("\n".join(["Zeit;Kraft 1;Kraft 2", *rows]))
    arrays, conv = read_recordings(root)
    assert float(arrays["fs"]) == pytest.approx(200.0)
    assert list(arrays["channel_names"]) == ["Kraft 1", "Kraft 2"]
    assert any("decimal comma" in n for n in conv.notes)


@pytest.mark.parametrize(
    "unit,scale", [("ns", 1e9), ("us", 1e6), ("ms", 1e3)], ids=["ns", "us", "ms"]
)
def test_epoch_timestamps_in_any_unit_give_the_true_rate(tmp_path, unit, scale):
    folder = _timed_folder(tmp_path / unit, {"Velvet_0": 250.0, "Denim_0": 250.0},
                           lambda t: f"{round(t * scale)}")  # fmt: skip
    arrays, conv = read_recordings(folder)
    assert float(arrays["fs"]) == pytest.approx(250.0, rel=1e-3)
    assert "epoch time" in conv.line()


def test_a_named_unit_is_taken_at_its_word(tmp_path):
    folder = _timed_folder(tmp_path / "named", {"Velvet_0": 500.0, "Denim_0": 500.0},
                           lambda t: f"{(t - 1_764_000_000.0) * 1e3:.3f}")  # fmt: skip
    for p in folder.iterdir():
        p.write_text(p.read_text().replace("timestamp,", "time_ms,", 1))
    arrays, _ = read_recordings(folder)
    assert float(arrays["fs"]) == pytest.approx(500.0, rel=1e-3)


def test_recordings_at_other_rates_are_resampled_and_said(tmp_path):
    rates = {"Velvet_0": 1000.0, "Velvet_1": 1000.0, "Denim_0": 1000.0, "Denim_1": 100.0}
    folder = _timed_folder(tmp_path / "mixed", rates, lambda t: f"{t - 1_764_000_000.0:.6f}")
    arrays, conv = read_recordings(folder)
    assert float(arrays["fs"]) == pytest.approx(1000.0)
    assert "Denim_1.csv at 100 Hz" in conv.line() and conv.resampled == 1
    # the resampled recording keeps its 9 Hz line at 9 Hz
    rec = arrays["X"][arrays["recording"] == 0][0, 0]  # Denim_1 sorts first
    spectrum = np.abs(np.fft.rfft(rec - rec.mean()))
    assert np.fft.rfftfreq(rec.size, 1 / 1000.0)[spectrum.argmax()] == pytest.approx(9.0, abs=1.0)


def test_an_npz_with_trials_at_two_rates_is_refused(tmp_path):
    t = np.stack([np.arange(100) / 100.0, np.arange(100) / 1000.0])
    with pytest.raises(ValueError, match="trials at different rates"):
        read_recordings(tmp_path / "m.npz", {"X": np.zeros((2, 1, 100)), "y": [0, 1], "t": t})


def test_fs_that_contradicts_the_data_is_refused(tmp_path):
    path = tmp_path / "d.npz"
    np.savez(path, X=np.zeros((4, 1, 64), np.float32), y=np.array([0, 1, 0, 1]), fs=200.0,
             class_names=np.array(["a", "b"]))  # fmt: skip
    with pytest.raises(ValueError, match="states fs = 200 Hz; --fs says 100 Hz"):
        load_data_file(path, 0, fs_hz=100.0)
    assert load_data_file(path, 0, fs_hz=200.0)[0].fs_hz == 200.0
    assert len(load_data_file(path)[0]) > 0  # the README's `load_data_file("my.npz")`


@pytest.mark.slow
def test_a_symlinked_class_folder_is_followed_and_a_broken_link_named(tmp_path):
    folder = spreadsheet_folder(tmp_path / "store")
    data = tmp_path / "data"
    data.mkdir()
    for sub in folder.iterdir():
        os.symlink(sub, data / sub.name)
    arrays, conv = read_recordings(data)
    assert len(arrays["class_names"]) == 3 and "symbolic link(s) followed" in conv.line()
    os.symlink(tmp_path / "missing.csv", data / "class Silk" / "gone.csv")
    with pytest.raises(ValueError, match=r"gone\.csv: a symbolic link to nothing"):
        read_recordings(data)


def test_a_forged_npy_header_is_refused_before_any_allocation(tmp_path):
    root = tmp_path / "npy"
    root.mkdir()
    np.save(root / "a_0.npy", np.zeros((50, 2), np.float32))
    with open(root / "b_0.npy", "wb") as f:
        np.lib.format.write_array_header_1_0(
            f, {"descr": "<f4", "fortran_order": False, "shape": (10**12, 2)}
        )
    with pytest.raises(ValueError, match=r"b_0.npy: its header declares \(1000000000000, 2\)"):
        read_recordings(root)


def test_a_single_csv_file_says_to_use_a_folder(tmp_path):
    (tmp_path / "one.csv").write_text("t,a\n0,1\n")
    with pytest.raises(ValueError, match=r"one \.csv file is one recording; --data takes a folder"):
        read_data_arrays(tmp_path / "one.csv")


def test_a_sample_number_column_is_no_rate(tmp_path):
    root = tmp_path / "idx"
    root.mkdir()
    rng = np.random.default_rng(4)
    for stem in ("Velvet_0", "Denim_0"):
        X = _signal(stem.split("_")[0], 200, 100.0, 2, rng)
        rows = [f"{i},{X[i, 0]:.3f},{X[i, 1]:.3f}" for i in range(200)]
        (root / f"{stem}.csv").write_text("\n".join(["index,a,b", *rows]))
    with pytest.raises(ValueError, match="--fs HZ"):
        read_recordings(root)
    arrays, conv = read_recordings(root, fs_hz=100.0)
    assert list(arrays["channel_names"]) == ["a", "b"] and "sample numbers" in conv.line()
