"""A generated dataset folder read back: its manifest, its shards, as one array set.

``tactilesnn generate`` (:mod:`tactilesnn.datasets_synth.generate`) writes ``manifest.json`` and
``shard-XXXXX.npz`` files; reading them needs no task, so real-data readers (``train --data
FOLDER``) and the lazy :class:`ShardDataset` read them from here, below the synthetic package.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from pathlib import Path

import numpy as np

from .checks import check_allocation


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def read_dataset_folder(folder: Path) -> dict[str, np.ndarray]:
    """A generated folder as the arrays of the ``--data`` file format (``X``, ``y``, ``fs``,
    ``class_names``, ``channel_names``, and ``recording`` = the sample a window came from, so the
    windows of one scan never straddle the split). Each shard's SHA-256 is checked against the
    manifest and the total size before anything is loaded; an unfinished folder is refused."""
    folder = Path(folder)
    path = folder / "manifest.json"
    if not path.is_file():
        hint = " (generation unfinished: run generate --resume)" if (
            folder / "manifest.partial.json").exists() else ""  # fmt: skip
        raise FileNotFoundError(f"{folder} has no manifest.json: not a generated dataset{hint}")
    m = manifest(path)
    channels, window = len(m["channel_names"]), m["window_samples"]
    check_allocation(4 * m["n_windows"] * channels * window, f"the dataset {folder}")
    shards = []
    for sh in m["shards"]:
        f = folder / sh["file"]
        if not f.is_file() or sha256(f) != sh["sha256"]:
            raise ValueError(f"{f} is missing or differs from its manifest SHA-256")
        shards.append(_read_shard(f, channels, window))
    if not shards:
        raise ValueError(f"{folder}: the manifest lists no shards")
    xs, ys, ids, sigs = zip(*shards, strict=True)
    out = {
        "X": np.concatenate(xs),
        "y": np.concatenate(ys),
        "recording": np.concatenate(ids),
        "fs": np.asarray(float(m["fs_hz"])),
        "class_names": np.asarray(m["class_names"]),
        "channel_names": np.asarray(m["channel_names"]),
    }
    if all(s is not None for s in sigs):  # every shard knows its class's signal
        out["class_signal"] = np.concatenate(sigs)
    return out


def _read_shard(f: Path, channels: int, window: int) -> tuple[np.ndarray, ...]:
    """``(X [n, channels, window], y [n], sample [n], class_signal [n, window] or None)`` of
    one shard, each member present and
    of the manifest's shape, else a ValueError naming the shard (its hash may have been
    rewritten with its content)."""
    try:
        with np.load(f, allow_pickle=False) as z:
            missing = [k for k in ("X", "y", "sample") if k not in z.files]
            if missing:
                raise ValueError(f"{f}: lacks {missing} (a shard holds X, y and sample)")
            X, y, sample = z["X"], z["y"], z["sample"]
            sig = z["class_signal"] if "class_signal" in z.files else None
    except (OSError, EOFError, zipfile.BadZipFile) as e:
        raise ValueError(f"{f}: not a readable shard ({e})") from None
    n = len(X)
    if X.shape != (n, channels, window) or y.shape != (n,) or sample.shape != (n,):
        raise ValueError(f"{f}: X {X.shape}, y {y.shape}, sample {sample.shape}; the manifest "
                         f"says X [n, {channels}, {window}], y [n], sample [n]")  # fmt: skip
    if sig is not None and sig.shape != (n, window):
        raise ValueError(f"{f}: class_signal {sig.shape}; X says [{n}, {window}]")
    return X, y, sample, sig


def manifest(path: Path) -> dict:
    """A dataset folder's manifest, checked: the keys a reader needs with their types, and shard
    files that are plain names inside the folder (never ``../x.npz`` or ``/etc/hostname``)."""
    try:
        m = json.loads(path.read_text())
    except (ValueError, RecursionError) as e:
        raise ValueError(f"{path}: not a valid manifest ({e})") from e
    need = {"channel_names": list, "class_names": list, "window_samples": int, "n_windows": int,
            "fs_hz": (int, float), "shards": list}  # fmt: skip
    if not isinstance(m, dict):
        raise ValueError(f"{path}: a manifest is a JSON object")
    for key, kind in need.items():
        if key not in m:
            raise ValueError(f"{path}: the manifest lacks {key!r}; not a generated dataset")
        if isinstance(m[key], bool) or not isinstance(m[key], kind):
            raise ValueError(f"{path}: manifest {key!r} has the wrong type")
    if m["window_samples"] < 1 or m["n_windows"] < 0 or not m["fs_hz"] > 0:
        raise ValueError(f"{path}: manifest sizes must be positive")
    for sh in m["shards"]:
        name = sh.get("file") if isinstance(sh, dict) else None
        if (not isinstance(name, str) or not isinstance(sh.get("sha256"), str)
                or Path(name).name != name or name in ("", ".", "..")):  # fmt: skip
            raise ValueError(f"{path}: shard entry {str(sh)[:80]} is not a file of the folder")
    return m


class ShardDataset:
    """torch-style Dataset over a generated folder: item ``i`` -> ``(X [C, W] float32, y int)``.

    Shards are opened lazily (one cached at a time; ``allow_pickle=False``), so a dataset larger
    than memory can be iterated in order.
    """

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        path = self.folder / "manifest.json"
        if not path.is_file():
            raise FileNotFoundError(f"{self.folder} has no manifest.json: not a generated dataset")
        self.manifest = manifest(path)
        self.shards = self.manifest["shards"]
        self.offsets = np.cumsum([0] + [s["windows"] for s in self.shards])
        self.class_names = tuple(self.manifest["class_names"])
        self.fs_hz = float(self.manifest["fs_hz"])
        self._cache: tuple[int, dict] | None = None

    def __len__(self) -> int:
        return int(self.offsets[-1])

    def _shard(self, k: int) -> dict:
        if self._cache is None or self._cache[0] != k:
            with np.load(self.folder / self.shards[k]["file"], allow_pickle=False) as f:
                self._cache = (k, {key: f[key] for key in f.files})
        return self._cache[1]

    def __getitem__(self, i: int):
        if not -len(self) <= i < len(self):
            raise IndexError(f"index {i} out of range for {len(self)} windows")
        i %= len(self)
        k = int(np.searchsorted(self.offsets, i, side="right") - 1)
        sh = self._shard(k)
        j = i - int(self.offsets[k])
        return sh["X"][j], int(sh["y"][j])
