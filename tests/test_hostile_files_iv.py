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
