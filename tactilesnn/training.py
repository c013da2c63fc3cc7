"""Train and evaluate a spike pipeline on a task; write the run folder."""

from __future__ import annotations

import json
import logging
import os
import platform
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from sklearn.metrics import confusion_matrix

from . import __version__
from ._checks import check_finite
from .baselines import linear_amplitude_baseline
from .datasets_synth import WindowDataset, get_task
from .pipeline import PipelineConfig, SpikePipeline, accuracy_ci95, tempotron_batch
from .runs import RunWriter, load_arrays, read_json

log = logging.getLogger("tactilesnn")


@dataclass
class TrainResult:
    pipeline: SpikePipeline
    history: list[float]
    metrics: dict
    confusion: np.ndarray


def split_validation(
    data: WindowDataset, fraction: float, seed: int
) -> tuple[WindowDataset, WindowDataset | None]:
    """Hold out ``fraction`` of the training scans (whole scans, so windows of one scan never
    straddle the split) for early stopping and best-weight selection."""
    if fraction <= 0:
        return data, None
    if not 0 < fraction < 1:
        raise ValueError(f"val_fraction must be in [0, 1), got {fraction}")
    groups = np.unique(data.scan)
    rng = np.random.default_rng([seed, 7919])
    n_val = max(1, round(fraction * groups.size))
    if n_val >= groups.size:
        raise ValueError(f"too few scans ({groups.size}) to hold out a validation fraction")
    val_groups = rng.choice(groups, n_val, replace=False)
    is_val = np.isin(data.scan, val_groups)

    def take(m: np.ndarray) -> WindowDataset:
        return WindowDataset(
            data.X[m], data.y[m], data.scan[m], data.fs_hz, data.class_names, data.channel_names
        )

    return take(~is_val), take(is_val)


def fit_and_evaluate(
    config: PipelineConfig,
    train: WindowDataset,
    test: WindowDataset,
    progress: bool = False,
    val_fraction: float = 0.0,
    checkpoint: Callable[[int, dict], None] | None = None,
    resume: dict | None = None,
) -> TrainResult:
    """Fit ``config`` on ``train`` (optionally holding out validation scans) and test it."""
    torch.manual_seed(config.seed)
    fit_set, val_set = split_validation(train, val_fraction, config.seed)
    pipe = SpikePipeline(
        config, train.fs_hz, train.X.shape[-1], train.channel_names, train.class_names
    )
    t0 = time.perf_counter()
    pipe.calibrate(fit_set.X)
    s_train = pipe.encode(fit_set.X)
    s_val = pipe.encode(val_set.X) if val_set is not None else None
    s_test = pipe.encode(test.X)
    t_enc = time.perf_counter() - t0
    history = pipe.fit_spikes(
        s_train,
        fit_set.y,
        progress=progress,
        val=(s_val, val_set.y) if val_set is not None else None,
        on_epoch=checkpoint,
        resume=resume,
    )
    t_fit = time.perf_counter() - t0 - t_enc
    pred = pipe.scores(s_test).argmax(1).numpy()
    early = (
        early_decision_metrics(pipe, s_test, test.y, pred) if config.model == "tempotron" else None
    )
    acc = float((pred == test.y).mean())
    cm = confusion_matrix(test.y, pred, labels=np.arange(len(test.class_names)))
    metrics = {
        "test_accuracy": acc,
        "test_accuracy_ci95": accuracy_ci95(acc, test.y.size),
        "train_error_final": history[-1],
        "epochs_run": len(history),
        "val_accuracy_history": pipe.history["val_history"],
        "n_train_windows": int(fit_set.y.size),
        "n_val_windows": int(val_set.y.size) if val_set is not None else 0,
        "n_test_windows": int(test.y.size),
        "n_train_scans": int(np.unique(fit_set.scan).size),
        "n_test_scans": int(np.unique(test.scan).size),
        "per_class_recall": {
            name: float(cm[i, i] / max(cm[i].sum(), 1)) for i, name in enumerate(test.class_names)
        },
        "encode_seconds": t_enc,
        "fit_seconds": t_fit,
    }
    if early is not None:
        metrics["early_decision"] = early
    return TrainResult(pipe, history, metrics, cm)


@torch.no_grad()
def early_decision_metrics(pipe: SpikePipeline, spikes: torch.Tensor, y, full_pred) -> dict:
    """Tempotron deciding at the first class to fire: accuracy, window and spikes skipped."""
    classes, t_dec = [], []
    batch = tempotron_batch(spikes)
    for i in range(0, spikes.shape[0], batch):
        c, t = pipe.model.predict_early(spikes[i : i + batch])
        classes.append(c)
        t_dec.append(t)
    cls, t = torch.cat(classes).numpy(), torch.cat(t_dec).numpy()
    times = spikes.numpy()
    finite = np.isfinite(times)
    after = finite & (times > t[:, None, None])
    return {
        "accuracy": float((cls == np.asarray(y)).mean()),
        "agrees_with_full_window": float((cls == full_pred).mean()),
        "mean_decision_ms": float(t.mean()),
        "window_skipped_fraction": float(1 - t.mean() / pipe.duration_ms),
        "input_spikes_skipped_fraction": float(after.sum() / max(finite.sum(), 1)),
    }


def load_data_file(path: Path, seed: int, test_fraction: float = 0.2):
    """Real recordings in the documented format -> ``(train, test)`` window datasets.

    ``.npz`` with ``X`` ``[N, channels, samples]`` float, ``y`` ``[N]`` int, ``fs`` (Hz),
    ``class_names`` ``[C]`` str, optionally ``channel_names`` and ``split`` (``[N]``, 0 = train,
    1 = test). Without ``split``, a stratified random ``test_fraction`` is held out (from ``seed``).
    Loaded with ``allow_pickle=False``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"data file {path} does not exist")
    with np.load(path, allow_pickle=False) as f:
        missing = [k for k in ("X", "y", "fs", "class_names") if k not in f.files]
        if missing:
            raise ValueError(
                f"{path}: missing {missing}; expected X [N, channels, samples], y [N], fs, "
                "class_names"
            )
        X = np.asarray(f["X"])
        y = np.asarray(f["y"]).astype(np.int64)
        fs = float(f["fs"])
        names = tuple(str(c) for c in f["class_names"])
        ch = (
            tuple(str(c) for c in f["channel_names"])
            if "channel_names" in f.files
            else tuple(f"ch{i}" for i in range(X.shape[1] if X.ndim == 3 else 0))
        )
        split = np.asarray(f["split"]) if "split" in f.files else None
    if X.ndim != 3:
        raise ValueError(f"{path}: X must be [N, channels, samples], got shape {X.shape}")
    if y.shape != (X.shape[0],):
        raise ValueError(f"{path}: y must be [N={X.shape[0]}], got shape {y.shape}")
    if not np.isfinite(fs) or fs <= 0:
        raise ValueError(f"{path}: fs must be a positive sampling rate in Hz, got {fs}")
    if y.min() < 0 or y.max() >= len(names):
        raise ValueError(f"{path}: labels must index class_names (0..{len(names) - 1})")
    check_finite(X.astype(np.float64, copy=False), f"{path}: X")
    if split is None:
        from sklearn.model_selection import train_test_split

        idx = np.arange(y.size)
        _, te = train_test_split(idx, test_size=test_fraction, random_state=seed, stratify=y)
        split = np.zeros(y.size, np.int64)
        split[te] = 1
    ids = np.arange(y.size)  # each recording is its own group

    def take(m):
        return WindowDataset(X[m].astype(np.float32), y[m], ids[m], fs, names, ch)

    return take(split == 0), take(split == 1)


SCALARS = ("epoch", "history", "val_history", "best_score", "stale")


def save_checkpoint(folder: Path, state: dict) -> None:
    """Write a resumable training state atomically (npz arrays, then the JSON that marks it)."""
    arrays: dict[str, np.ndarray] = {}
    for group in ("model", "best", "optimizer"):
        for k, v in state.get(group, {}).items():
            arrays[f"{group}/{k}"] = np.asarray(v)
    for k in ("rng", "velocity"):
        if k in state:
            arrays[k] = np.asarray(state[k])
    tmp = folder / "checkpoint.tmp.npz"
    np.savez(tmp, **arrays)
    os.replace(tmp, folder / "checkpoint.npz")
    meta = {k: state[k] for k in SCALARS}
    tmp_j = folder / "checkpoint.tmp.json"
    tmp_j.write_text(json.dumps(meta))
    os.replace(tmp_j, folder / "checkpoint.json")


def load_checkpoint(folder: Path) -> dict:
    meta = json.loads((folder / "checkpoint.json").read_text())
    state: dict = dict(meta)
    with np.load(folder / "checkpoint.npz", allow_pickle=False) as f:
        for key in f.files:
            if "/" in key:
                group, name = key.split("/", 1)
                state.setdefault(group, {})[name] = f[key]
            else:
                state[key] = f[key]
    state.setdefault("best", {})
    return state


def train_run(
    task_name: str | None,
    task_kwargs: dict,
    config: PipelineConfig,
    out: Path,
    overwrite: bool = False,
    progress: bool = True,
    data: Path | None = None,
    resume: bool = False,
    val_fraction: float = 0.0,
    config_text: str | None = None,
    export: bool = False,
) -> tuple[Path, dict]:
    """Build the data, train, evaluate and write ``out`` atomically; returns its metrics.

    Each epoch's state is checkpointed in ``<out>.partial/``; ``resume`` continues from there
    after an interruption (same configuration required). Nothing existing is replaced unless
    ``overwrite``.
    """
    out = Path(out)
    writer = RunWriter(out, overwrite=overwrite)  # refuses an existing folder before any work
    partial = out.with_name(out.name + ".partial")
    run_cfg = {
        "task": task_name if data is None else None,
        "task_kwargs": task_kwargs if data is None else {},
        "data": str(data) if data is not None else None,
        "pipeline": config.to_dict(),
        "val_fraction": val_fraction,
    }
    state = None
    try:
        if resume:
            if not (partial / "checkpoint.json").is_file():
                raise FileNotFoundError(f"nothing to resume: no checkpoint in {partial}")
            saved = read_json(partial / "run.json")
            if saved != json.loads(json.dumps(run_cfg)):
                raise ValueError(
                    f"--resume needs the same settings as the interrupted run ({partial / 'run.json'})"
                )
            state = load_checkpoint(partial)
            log.info("resuming %s from epoch %d", out, state["epoch"])
        elif partial.exists():
            if not overwrite:
                raise FileExistsError(
                    f"an interrupted run is in {partial}: pass --resume to continue it or "
                    "--overwrite to discard it"
                )
            shutil.rmtree(partial)
        partial.mkdir(parents=True, exist_ok=True)
        (partial / "run.json").write_text(json.dumps(run_cfg, indent=2))
        t0 = time.perf_counter()
        if data is not None:
            train, test = load_data_file(data, config.seed)
        else:
            train, test = get_task(task_name, **task_kwargs).build(progress=progress)
        log.info(
            "%s: %d train / %d test windows (%d x %d samples @ %g Hz) in %.1f s",
            data or task_name,
            train.y.size,
            test.y.size,
            train.X.shape[1],
            train.X.shape[2],
            train.fs_hz,
            time.perf_counter() - t0,
        )
        res = fit_and_evaluate(
            config,
            train,
            test,
            progress=progress,
            val_fraction=val_fraction,
            checkpoint=lambda epoch, st: save_checkpoint(partial, st),
            resume=state,
        )
        res.metrics["trivial_amplitude_baseline_accuracy"] = linear_amplitude_baseline(
            train.X, train.y, test.X, test.y
        )
        res.metrics["train_error_history"] = res.history
        writer.write_json(
            "config.json",
            {
                **run_cfg,
                "fs_hz": train.fs_hz,
                "window": int(train.X.shape[-1]),
                "channel_names": list(train.channel_names),
                "class_names": list(train.class_names),
                "tactilesnn_version": __version__,
                "torch_version": torch.__version__,
                "python": platform.python_version(),
            },
        )
        if config_text is not None:
            (writer.file("config.toml")).write_text(config_text)
        writer.write_arrays("weights.npz", res.pipeline.weights())
        writer.write_json(
            "confusion_matrix.json",
            {"labels": list(test.class_names), "matrix": res.confusion.tolist()},
        )
        plot_confusion(res.confusion, test.class_names, writer.file("confusion_matrix.png"))
        if export:
            from .export import data_hash, export_pipeline

            rep = export_pipeline(
                res.pipeline,
                writer.file("model.onnx"),
                test.X,
                metadata={"training_data_sha256": data_hash(run_cfg), "run": out.name},
            )
            res.metrics["onnx"] = {
                k: rep[k] for k in ("nodes", "max_score_diff", "prediction_agreement")
            }
        writer.write_json("metrics.json", res.metrics)
        path = writer.commit()
        shutil.rmtree(partial, ignore_errors=True)  # the run is complete: its checkpoint is spent
    except BaseException:
        writer.abort()
        raise
    return path, res.metrics


def load_run(run_dir: Path) -> tuple[SpikePipeline, dict]:
    """Rebuild a trained pipeline from a run folder (JSON config + npz weights, no pickle)."""
    run_dir = Path(run_dir)
    for name in ("config.json", "weights.npz"):
        if not (run_dir / name).is_file():
            raise FileNotFoundError(f"{run_dir} is not a run folder: {name} is missing")
    cfg = read_json(run_dir / "config.json")
    pipe = SpikePipeline(
        PipelineConfig.from_dict(cfg["pipeline"]),
        cfg["fs_hz"],
        cfg["window"],
        cfg["channel_names"],
        cfg["class_names"],
    )
    pipe.load_weights(load_arrays(run_dir / "weights.npz"))
    return pipe, cfg


def plot_confusion(cm: np.ndarray, names: tuple[str, ...] | list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(3.2 + 0.4 * len(names), 3.0 + 0.4 * len(names)))
    ax.imshow(cm, cmap="Blues")
    ax.set_xticks(range(len(names)), names)
    ax.set_yticks(range(len(names)), names)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    for i in range(cm.shape[0]):
        for j in range(cm.shape[1]):
            ax.text(j, i, str(cm[i, j]), ha="center", va="center")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
