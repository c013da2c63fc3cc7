"""Hardening IV: files read exactly as saved, or refused by name; nothing hangs."""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np
import pytest

from tactilesnn.readers import read_recordings
from tactilesnn.recordings import read_data_arrays


def _two_classes(root: Path, header: str, row, n: int = 120) -> Path:
    """A folder of two CSV recordings per class written line by line by ``row(i, x0, x1)``."""
    rng = np.random.default_rng(0)
    root.mkdir()
    for stem in ("Velvet_0", "Velvet_1", "Denim_0", "Denim_1"):
        x = rng.normal(size=(n, 2)) + (stem.startswith("Velvet"))
        lines = [row(i, x[i, 0], x[i, 1]) for i in range(n)]
        (root / f"{stem}.csv").write_text("\n".join([header, *lines]) + "\n")
    return root


def test_a_sample_counter_beside_a_time_column_is_dropped(tmp_path):
    root = _two_classes(tmp_path / "d", "sample,time_ms,a,b",
                        lambda i, a, b: f"{i},{5 * i},{a:.4f},{b:.4f}")  # fmt: skip
    arrays, conv = read_recordings(root)
    assert list(arrays["channel_names"]) == ["a", "b"]
    assert float(arrays["fs"]) == pytest.approx(200.0)
    assert "'sample' holds row numbers" in conv.line()


def test_pandas_default_csv_keeps_its_header_and_drops_its_index(tmp_path):
    root = _two_classes(tmp_path / "d", ",time,a,b",
                        lambda i, a, b: f"{i},{0.01 * i:.2f},{a:.4f},{b:.4f}")  # fmt: skip
    arrays, _ = read_recordings(root)
    assert list(arrays["channel_names"]) == ["a", "b"]
    assert float(arrays["fs"]) == pytest.approx(100.0)


def test_quoted_decimal_commas_in_a_comma_separated_file(tmp_path):
    def row(i: int, a: float, b: float) -> str:
        return f'"{0.005 * i:.3f}","{a:.4f}","{b:.4f}"'.replace(".", ",")

    root = _two_classes(tmp_path / "d", "time_s,a,b", row)
    arrays, _ = read_recordings(root)
    assert list(arrays["channel_names"]) == ["a", "b"]
    assert float(arrays["fs"]) == pytest.approx(200.0)
    rows = (root / "Denim_0.csv").read_text().splitlines()[1:3]
    first = [float(c.strip('"').replace(",", ".")) for c in rows[0].split('","')]
    assert arrays["X"].shape[1] == 2
    assert np.isclose(arrays["X"][0, 0, 0], first[1], atol=1e-4)


def test_whole_unit_timestamps_without_a_unit_are_refused_unless_fs_says(tmp_path):
    root = _two_classes(tmp_path / "d", "time,a,b", lambda i, a, b: f"{i + 3},{a:.4f},{b:.4f}")
    with pytest.raises(ValueError, match="time_s or time_ms"):
        read_recordings(root)
    arrays, _ = read_recordings(root, fs_hz=1.0)
    assert float(arrays["fs"]) == 1.0


def test_an_npz_with_x_twice_is_refused(tmp_path):
    path = tmp_path / "two.npz"
    np.savez(path, X=np.zeros((4, 2, 8), np.float32), y=np.arange(4) % 2, fs=np.asarray(100.0))
    with zipfile.ZipFile(path, "a") as z:
        with z.open("X", "w") as f:
            np.lib.format.write_array(f, np.ones((4, 2, 8), np.float32))
    with pytest.raises(ValueError, match=r"'X\.npy' and 'X'"):
        read_data_arrays(path)


def test_labels_longer_than_x_are_refused_from_the_headers(tmp_path):
    path = tmp_path / "long_y.npz"
    np.savez(path, X=np.zeros((4, 2, 8), np.float32), y=np.zeros(40_000, np.int64),
             fs=np.asarray(100.0))  # fmt: skip
    with pytest.raises(ValueError, match="'y' must hold one value per window of X \\(4\\)"):
        read_data_arrays(path)


def test_unknown_compression_and_encryption_are_refused_by_member(tmp_path):
    path = tmp_path / "odd.npz"
    np.savez(path, X=np.zeros((4, 2, 8), np.float32), y=np.arange(4) % 2, fs=np.asarray(100.0))
    raw = bytearray(path.read_bytes())
    # the central directory's compression method of the first member -> 99
    at = raw.find(b"PK\x01\x02")
    raw[at + 10 : at + 12] = (99).to_bytes(2, "little")
    path.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match="zip method 99"):
        read_data_arrays(path)
    raw[at + 10 : at + 12] = (0).to_bytes(2, "little")
    raw[at + 8 : at + 10] = (1).to_bytes(2, "little")  # general-purpose flag: encrypted
    path.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match="encrypted"):
        read_data_arrays(path)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_fifo_or_a_link_to_a_device_is_refused_not_read(tmp_path):
    root = _two_classes(tmp_path / "d", "time_ms,a,b", lambda i, a, b: f"{5 * i},{a:.4f},{b:.4f}")
    os.mkfifo(root / "Velvet_pipe.csv")
    with pytest.raises(ValueError, match="not a regular file"):
        read_recordings(root)
    os.remove(root / "Velvet_pipe.csv")
    os.symlink("/dev/zero", root / "Denim_zero.csv")
    with pytest.raises(ValueError, match="not a regular file"):
        read_recordings(root)
    os.symlink("/dev/zero", tmp_path / "zero.npz")
    with pytest.raises(ValueError, match="not a regular file"):
        read_data_arrays(tmp_path / "zero.npz")


def test_the_median_power_frequency_reads_one_window_at_a_time():
    from tactilesnn.selection import median_power_frequency

    rng = np.random.default_rng(1)
    fs, n = 200.0, 400
    t = np.arange(n) / fs
    X = (np.sin(2 * np.pi * 12.5 * t) + 0.01 * rng.normal(size=(30, 3, n))).astype(np.float32)
    assert median_power_frequency(X, fs) == pytest.approx(12.5, abs=fs / n)


def test_predict_refuses_a_dataset_whose_names_or_rate_disagree():
    from dataclasses import replace

    from tactilesnn import SpikeClassifier
    from tactilesnn.core.data import WindowDataset

    rng = np.random.default_rng(0)
    y = np.arange(40) % 2
    X = (rng.normal(size=(40, 2, 64)) + 2.0 * y[:, None, None]).astype(np.float32)
    clf = SpikeClassifier(model="readout", epochs=2).fit(X, y, fs_hz=200.0)
    ds = WindowDataset(X, y, np.arange(40), 200.0, ("0", "1"), tuple(clf.channel_names_))
    assert clf.predict(ds).shape == (40,)
    three = replace(ds, X=np.concatenate([X, X[:, :1]], axis=1))
    with pytest.raises(ValueError, match="3 channels but 2 channel names"):
        clf.predict(three)
    with pytest.raises(ValueError, match="fs_hz=400 but the dataset says 200 Hz"):
        clf.predict(ds, fs_hz=400)


def test_a_json_body_with_window_and_windows_is_refused():
    from tactilesnn.service.app import HTTPError, _parse

    body = b'{"window": [[1.0, 2.0]], "windows": [[[3.0, 4.0]]]}'
    with pytest.raises(HTTPError, match="both 'window' and 'windows'") as e:
        _parse(body, "application/json", "window")
    assert e.value.status == 422


def test_a_task_that_renders_scans_cannot_be_calibrated_or_compared(tmp_path):
    from tactilesnn.app.calibrate import calibrate, compare

    data = tmp_path / "r.npz"
    with pytest.raises(ValueError, match="hook_loop task cannot be calibrated; tasks that can"):
        calibrate(data, "hook_loop", tmp_path / "fit.json")
    with pytest.raises(ValueError, match="hook_loop task cannot be compared"):
        compare(data, "hook_loop", tmp_path / "fit.json")


def test_a_damaged_config_json_is_named(tmp_path):
    from tactilesnn.core.files import read_json

    bad = tmp_path / "config.json"
    bad.write_bytes(b"\xff\xfe\x00junk")
    with pytest.raises(ValueError, match=r"config\.json: not a readable JSON file"):
        read_json(bad)
    bad.write_text("[1, 2]")
    with pytest.raises(ValueError, match="a JSON object expected"):
        read_json(bad)


def test_an_export_never_replaces_the_run_s_own_files(tmp_path):
    from tactilesnn.app.commands import export_run

    run = tmp_path / "run"
    run.mkdir()
    for name in ("weights.npz", "config.json"):
        with pytest.raises(ValueError, match=f"the run's own {name}"):
            export_run(run, run / name, overwrite=True)
    with pytest.raises(ValueError, match=r"the run's own config\.json"):
        export_run(run, run / "sub" / ".." / "config.json", overwrite=True)


def test_a_split_and_its_cut_windows_are_checked_together_before_any_copy(monkeypatch):
    """An .npz that inflates to most of the memory: the split's float32 copy and its cut
    windows beside the recordings already read are refused before any is made."""
    from tactilesnn.core import checks
    from tactilesnn.recordings import datasets_from_arrays

    X = np.zeros((40, 4, 10_000), np.float32)  # 6.4 MB
    X[:, :, :50] = 1.0
    arrays = {"X": X, "y": np.arange(40) % 2, "fs": np.asarray(1000.0),
              "class_names": np.array(["a", "b"])}  # fmt: skip
    monkeypatch.setattr(checks, "memory_limit_bytes", lambda: 16 << 20)
    with pytest.raises(ValueError, match="a split's float32 copy and its cut windows together"):
        datasets_from_arrays(arrays, "big.npz", 0, window=(1.0, None))
    train, _ = datasets_from_arrays(arrays, "big.npz", 0, window=None)  # no cut: it fits
    assert train.X.dtype == np.float32
