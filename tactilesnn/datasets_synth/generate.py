"""Sharded dataset generation with a manifest, and a lazy torch Dataset over the shards.

``generate(task, n, seed, out)`` renders samples ``0..n-1`` of any registered task (``task.render``:
for ``hook_loop`` a sample is one scan, cut into its labelled windows; for the trial tasks one
trial) in parallel worker processes, ``shard_size`` samples per
``shard-XXXXX.npz`` (``X [windows, channels, samples]`` float32, ``y``, ``sample``), and writes
``manifest.json`` (task, parameters, seed, generator version, shapes, units, rate, class and
channel names, and per shard its sample range, window count and SHA-256). Sample ``i`` depends
only on (task, seed, i), so any worker count gives identical files.

Safety: an existing dataset is never overwritten unless asked; an interrupted run leaves finished
shards plus ``manifest.partial.json`` and ``generate(..., resume=True)`` only renders the missing
shards (verifying the finished ones' hashes). Shards are written to a temporary name and renamed.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import zipfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ..core.files import replace_atomically, write_text_atomic
from ..core.stages import bar_disabled
from ..core.version import __version__
from .base import get_task

log = logging.getLogger("tactilesnn")
GENERATOR_VERSION = f"tactilesnn {__version__} / tasks v2"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _render_shard(args: tuple) -> dict:
    task_name, task_kwargs, first, last, path = args
    task = get_task(task_name, **task_kwargs)
    xs, ys, ids = [], [], []
    for i in range(first, last):
        X, y = task.render(i)
        xs.append(X)
        ys.append(y)
        ids.append(np.full(y.size, i, np.int64))
    X = (
        np.concatenate(xs)
        if xs
        else np.zeros((0, len(task.channel_names), task.window), np.float32)
    )
    y, sample = np.concatenate(ys), np.concatenate(ids)
    replace_atomically(path, lambda tmp: np.savez(tmp, X=X, y=y, sample=sample), ".npz")
    return {"file": Path(path).name, "first": first, "last": last, "windows": len(X),
            "sha256": _sha256(Path(path))}  # fmt: skip


def generate(
    task_name: str,
    n: int,
    seed: int,
    out: Path,
    shard_size: int = 50,
    workers: int = 2,
    overwrite: bool = False,
    resume: bool = False,
    progress: bool = True,
    task_kwargs: dict | None = None,
    scheduler: str | None = None,
) -> dict:
    """Render ``n`` samples of ``task_name`` into ``out`` (on local processes, or on the Dask
    cluster at ``scheduler``); returns the manifest."""
    from tqdm.auto import tqdm

    out = Path(out)
    kwargs = dict(task_kwargs or {}, seed=seed)
    task = get_task(task_name, **kwargs)
    if n < 1 or shard_size < 1:
        raise ValueError(f"n and shard_size must be >= 1, got {n}, {shard_size}")
    if not task.resizable and n > task.n_samples:
        raise ValueError(f"task {task_name} has {task.n_samples} samples; asked for {n}")
    if n > task.n_samples:  # resizable tasks: sample indices beyond the default size are valid
        kwargs["n_samples"] = n
        task = get_task(task_name, **kwargs)
    if (out.exists() or out.is_symlink()) and (out.is_symlink() or not out.is_dir()):
        raise FileExistsError(f"{out} exists and is not a folder; choose another --out")
    manifest_path, partial_path = out / "manifest.json", out / "manifest.partial.json"
    if manifest_path.exists() and not overwrite:
        raise FileExistsError(f"{out} already holds a dataset; pass --overwrite to replace it")
    if out.exists() and any(out.iterdir()) and not (resume or overwrite):
        raise FileExistsError(
            f"{out} is not empty; pass --resume to finish an interrupted generation or "
            "--overwrite to replace it"
        )
    if overwrite and out.exists() and any(out.iterdir()):
        ours = manifest_path.exists() or partial_path.exists()
        if not ours:
            raise FileExistsError(
                f"{out} holds files that are not a tactilesnn dataset (no manifest): refusing "
                "to replace it; choose another --out"
            )
        # only what the generator itself wrote goes: manifests and shard files
        for f in out.iterdir():
            if f.is_file() and (f.name.startswith("manifest") or f.name.startswith("shard")):
                f.unlink()
        leftover = sorted(p.name for p in out.iterdir())
        if leftover:
            log.warning("--overwrite kept files the generator did not write: %s", leftover[:5])
    out.mkdir(parents=True, exist_ok=True)
    header = {
        "task": task_name,
        "task_kwargs": kwargs,
        "n_samples": n,
        "shard_size": shard_size,
        "generator": GENERATOR_VERSION,
        "fs_hz": task.fs_hz,
        "window_samples": task.window,
        "channel_names": list(task.channel_names),
        "units": task.units,
        "class_names": list(task.class_names),
        "parameters": json.loads(json.dumps(dataclasses.asdict(task), default=str)),
    }
    done: dict[str, dict] = {}
    if resume and partial_path.exists():
        old = json.loads(partial_path.read_text())
        if {k: old[k] for k in header} != json.loads(json.dumps(header)):
            raise ValueError(
                f"--resume needs the same settings as the interrupted run ({partial_path})"
            )
        for sh in old["shards"]:
            f = out / sh["file"]
            if f.exists() and _sha256(f) == sh["sha256"]:
                done[sh["file"]] = sh
    jobs = []
    for k, first in enumerate(range(0, n, shard_size)):
        name = f"shard-{k:05d}.npz"
        if name not in done:
            jobs.append((task_name, kwargs, first, min(n, first + shard_size), out / name))
    shards = dict(done)

    def checkpoint() -> None:
        doc = dict(header, shards=sorted(shards.values(), key=lambda s: s["first"]))
        write_text_atomic(partial_path, json.dumps(doc, indent=2))

    checkpoint()
    bar = tqdm(total=len(jobs), desc=f"generate {task_name}", disable=bar_disabled(progress))
    if scheduler:  # a shard whose worker died is rendered again: it depends only on its inputs
        from ..core.dask_run import on_dask

        for _, rec in on_dask(_render_shard, [(j,) for j in jobs], scheduler):
            shards[rec["file"]] = rec
            checkpoint()
            bar.update()
    elif workers > 1 and len(jobs) > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for rec in pool.map(_render_shard, jobs):
                shards[rec["file"]] = rec
                checkpoint()
                bar.update()
    else:
        for job in jobs:
            rec = _render_shard(job)
            shards[rec["file"]] = rec
            checkpoint()
            bar.update()
    bar.close()
    manifest = dict(header, shards=sorted(shards.values(), key=lambda s: s["first"]))
    manifest["n_windows"] = sum(s["windows"] for s in manifest["shards"])
    write_text_atomic(manifest_path, json.dumps(manifest, indent=2))
    partial_path.unlink(missing_ok=True)
    return manifest


def read_dataset_folder(folder: Path) -> dict[str, np.ndarray]:
    """A generated folder as the arrays of the ``--data`` file format (``X``, ``y``, ``fs``,
    ``class_names``, ``channel_names``, and ``recording`` = the sample a window came from, so the
    windows of one scan never straddle the split). Each shard's SHA-256 is checked against the
    manifest and the total size before anything is loaded; an unfinished folder is refused."""
    from ..core.checks import check_allocation

    folder = Path(folder)
    path = folder / "manifest.json"
    if not path.is_file():
        hint = " (generation unfinished: run generate --resume)" if (
            folder / "manifest.partial.json").exists() else ""  # fmt: skip
        raise FileNotFoundError(f"{folder} has no manifest.json: not a generated dataset{hint}")
    m = _manifest(path)
    channels, window = len(m["channel_names"]), m["window_samples"]
    check_allocation(4 * m["n_windows"] * channels * window, f"the dataset {folder}")
    shards = []
    for sh in m["shards"]:
        f = folder / sh["file"]
        if not f.is_file() or _sha256(f) != sh["sha256"]:
            raise ValueError(f"{f} is missing or differs from its manifest SHA-256")
        shards.append(_read_shard(f, channels, window))
    if not shards:
        raise ValueError(f"{folder}: the manifest lists no shards")
    xs, ys, ids = zip(*shards, strict=True)
    return {
        "X": np.concatenate(xs),
        "y": np.concatenate(ys),
        "recording": np.concatenate(ids),
        "fs": np.asarray(float(m["fs_hz"])),
        "class_names": np.asarray(m["class_names"]),
        "channel_names": np.asarray(m["channel_names"]),
    }


def _read_shard(f: Path, channels: int, window: int) -> tuple[np.ndarray, ...]:
    """``(X [n, channels, window], y [n], sample [n])`` of one shard, each member present and
    of the manifest's shape, else a ValueError naming the shard (its hash may have been
    rewritten with its content)."""
    try:
        with np.load(f, allow_pickle=False) as z:
            missing = [k for k in ("X", "y", "sample") if k not in z.files]
            if missing:
                raise ValueError(f"{f}: lacks {missing} (a shard holds X, y and sample)")
            X, y, sample = z["X"], z["y"], z["sample"]
    except (OSError, EOFError, zipfile.BadZipFile) as e:
        raise ValueError(f"{f}: not a readable shard ({e})") from None
    n = len(X)
    if X.shape != (n, channels, window) or y.shape != (n,) or sample.shape != (n,):
        raise ValueError(f"{f}: X {X.shape}, y {y.shape}, sample {sample.shape}; the manifest "
                         f"says X [n, {channels}, {window}], y [n], sample [n]")  # fmt: skip
    return X, y, sample


def _manifest(path: Path) -> dict:
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
        self.manifest = _manifest(path)
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


class TaskDataset:
    """torch-style Dataset that renders a trial task on the fly: item ``i`` -> ``(X [C, W], y)``.

    Item ``i`` is sample ``i`` of (task, seed), identical to what ``generate`` writes, so a
    training loop can stream samples without storing them (each DataLoader worker renders its
    own indices).
    """

    def __init__(self, task_name: str, **task_kwargs: object) -> None:
        self.task = get_task(task_name, **task_kwargs)
        if not hasattr(self.task, "sample"):
            raise ValueError(f"{task_name} is scan-based: generate it and use ShardDataset")
        self.class_names = tuple(self.task.class_names)
        self.fs_hz = float(self.task.fs_hz)

    def __len__(self) -> int:
        return int(self.task.n_samples)

    def __getitem__(self, i: int):
        if not -len(self) <= i < len(self):
            raise IndexError(f"index {i} out of range for {len(self)} samples")
        x, y, _ = self.task.sample(i % len(self))
        return x, y
