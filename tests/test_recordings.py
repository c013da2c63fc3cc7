"""Recordings with sensors at several sampling rates form one recording (resampled channels)."""

from pathlib import Path

import numpy as np
import pytest

from tactilesnn.recordings import load_data_file


def _two_rate_file(path: Path, span_s: float = 2.0, slow_samples: int | None = None) -> None:
    rng = np.random.default_rng(0)
    n, fs, fs_slow = 20, 1000.0, 100.0
    t = np.arange(int(span_s * fs)) / fs
    ts = np.arange(slow_samples or int(span_s * fs_slow)) / fs_slow
    y = np.arange(n) % 2
    f0 = np.where(y == 0, 3.0, 7.0)[:, None]  # the class is in the slow stream's frequency
    np.savez(
        path,
        X=(0.1 * rng.standard_normal((n, 1, t.size))).astype(np.float32),
        fs=fs,
        y=y,
        class_names=np.array(["slow3", "slow7"]),
        channel_names=np.array(["vib"]),
        recording=np.arange(n),
        **{"X@imp": np.sin(2 * np.pi * f0 * ts)[:, None, :], "fs@imp": fs_slow,
           "channel_names@imp": np.array(["e0"])},
    )  # fmt: skip


def test_slow_stream_is_resampled_and_appended(tmp_path: Path) -> None:
    _two_rate_file(tmp_path / "d.npz")
    train, test = load_data_file(tmp_path / "d.npz", seed=0)
    assert train.channel_names == ("vib", "imp:e0") and train.fs_hz == 1000.0
    assert train.X.shape[1:] == (2, 2000)
    # the 100 Hz sine, resampled to 1 kHz, is the sine at 1 kHz (away from the edges)
    t = np.arange(2000) / 1000.0
    for ds in (train, test):
        f0 = np.where(ds.y == 0, 3.0, 7.0)[:, None]
        want = np.sin(2 * np.pi * f0 * t)
        assert np.abs(ds.X[:, 1, 100:-100] - want[:, 100:-100]).max() < 0.02


def test_streams_must_cover_the_same_time(tmp_path: Path) -> None:
    _two_rate_file(tmp_path / "d.npz", slow_samples=150)  # 1.5 s against 2 s
    with pytest.raises(ValueError, match="same time"):
        load_data_file(tmp_path / "d.npz", seed=0)


def test_stream_without_rate_is_refused(tmp_path: Path) -> None:
    np.savez(tmp_path / "d.npz", X=np.zeros((4, 1, 10)), fs=10.0, y=np.array([0, 1, 0, 1]),
             class_names=np.array(["a", "b"]), **{"X@b": np.zeros((4, 1, 5))})  # fmt: skip
    with pytest.raises(ValueError, match="fs@b"):
        load_data_file(tmp_path / "d.npz", seed=0)
