"""Sharded dataset generation with a manifest (reading a generated folder:
:mod:`tactilesnn.core.dataset_folder`), and a Dataset rendering a task on the fly.

``generate(task, n, seed, out)`` renders samples ``0..n-1`` of any registered task (``task.render``:
for ``hook_loop`` a sample is one scan, cut into its labelled windows; for the trial tasks one
trial) in parallel worker processes, ``shard_size`` samples per
``shard-XXXXX.npz`` (``X [windows, channels, samples]`` float32, ``y``, ``sample``, and for a
trial task that can render a trial without its class ``class_signal [windows, samples]``: the
class's own signal per sample, which ``train --data`` turns into window confidences), and writes
``manifest.json`` (task, parameters, seed, generator version, shapes, units, rate, class and
channel names, and per shard its sample range, window count and SHA-256). Sample ``i`` depends
only on (task, seed, i), so any worker count gives identical files.

Safety: an existing dataset is never overwritten unless asked; an interrupted run leaves finished
shards plus ``manifest.partial.json`` and ``generate(..., resume=True)`` only renders the missing
shards (verifying the finished ones' hashes). Shards are written to a temporary name and renamed.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ..core.dataset_folder import sha256 as _sha256
from ..core.files import replace_atomically, write_text_atomic
from ..core.stages import bar_disabled
from ..core.version import __version__
from .tasks.base import get_task

log = logging.getLogger("tactilesnn")
GENERATOR_VERSION = f"tactilesnn {__version__} / tasks v2"


def _render_shard(args: tuple) -> dict:
    task_name, task_kwargs, first, last, path = args
    task = get_task(task_name, **task_kwargs)
    xs, ys, ids, sigs = [], [], [], []
    with_signal = getattr(task, "render_with_signal", None)  # trial tasks: the class's own signal
    for i in range(first, last):
        if with_signal is not None:
            X, y, sig = with_signal(i)
            sigs.append(sig)
        else:
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
    extra = {}
    if sigs and all(s is not None for s in sigs):
        extra["class_signal"] = np.concatenate(sigs).astype(np.float32)
    replace_atomically(path, lambda tmp: np.savez(tmp, X=X, y=y, sample=sample, **extra), ".npz")
    return {"file": Path(path).name, "first": first, "last": last, "windows": len(X),
            "sha256": _sha256(Path(path)), "class_signal": bool(extra)}  # fmt: skip


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
    manifest_path, partial_path = _prepare_out(out, overwrite, resume)
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
    done = _finished_shards(out, header, partial_path) if resume else {}
    jobs = [(task_name, kwargs, first, min(n, first + shard_size), out / f"shard-{k:05d}.npz")
            for k, first in enumerate(range(0, n, shard_size))
            if f"shard-{k:05d}.npz" not in done]  # fmt: skip
    shards = dict(done)

    def checkpoint() -> None:
        doc = dict(header, shards=sorted(shards.values(), key=lambda s: s["first"]))
        write_text_atomic(partial_path, json.dumps(doc, indent=2))

    checkpoint()
    bar = tqdm(total=len(jobs), desc=f"generate {task_name}", disable=bar_disabled(progress))
    for rec in _rendered(jobs, workers, scheduler):
        shards[rec["file"]] = rec
        checkpoint()
        bar.update()
    bar.close()
    manifest = dict(header, shards=sorted(shards.values(), key=lambda s: s["first"]))
    manifest["n_windows"] = sum(s["windows"] for s in manifest["shards"])
    write_text_atomic(manifest_path, json.dumps(manifest, indent=2))
    partial_path.unlink(missing_ok=True)
    return manifest


def _prepare_out(out: Path, overwrite: bool, resume: bool) -> tuple[Path, Path]:
    """Check ``out`` may take a dataset (refusing a file, another dataset without
    ``overwrite``, foreign files), remove what an earlier generation wrote there when
    ``overwrite``; returns the manifest's and the partial manifest's paths."""
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
    return manifest_path, partial_path


def _finished_shards(out: Path, header: dict, partial_path: Path) -> dict[str, dict]:
    """The shards an interrupted generation with the same ``header`` finished (their files
    present with the recorded hash), by file name."""
    done: dict[str, dict] = {}
    if not partial_path.exists():
        return done
    old = json.loads(partial_path.read_text())
    if {k: old[k] for k in header} != json.loads(json.dumps(header)):
        raise ValueError(
            f"--resume needs the same settings as the interrupted run ({partial_path})"
        )
    for sh in old["shards"]:
        f = out / sh["file"]
        if f.exists() and _sha256(f) == sh["sha256"]:
            done[sh["file"]] = sh
    return done


def _rendered(jobs: list[tuple], workers: int, scheduler: str | None):
    """Each job's shard record as it is rendered: on the Dask cluster at ``scheduler`` (a shard
    whose worker died is rendered again: it depends only on its inputs), on ``workers``
    processes, or here."""
    if scheduler:
        from ..core.dask_run import on_dask

        for _, rec in on_dask(_render_shard, [(j,) for j in jobs], scheduler):
            yield rec
    elif workers > 1 and len(jobs) > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            yield from pool.map(_render_shard, jobs)
    else:
        for job in jobs:
            yield _render_shard(job)


class TaskDataset:
    """torch-style Dataset that renders a trial task on the fly: item ``i`` -> ``(X [C, W], y)``.

    Item ``i`` is sample ``i`` of (task, seed), identical to what ``generate`` writes, so a
    training loop can stream samples without storing them (each DataLoader worker renders its
    own indices).
    """

    def __init__(self, task_name: str, **task_kwargs: object) -> None:
        self.task = get_task(task_name, **task_kwargs)
        if not self.task.resizable:
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
