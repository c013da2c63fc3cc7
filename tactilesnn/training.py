"""Train and evaluate a spike pipeline on a task; write the run folder."""

from __future__ import annotations

import logging
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from sklearn.metrics import confusion_matrix

from . import __version__
from .baselines import linear_amplitude_baseline
from .datasets_synth import WindowDataset, get_task
from .pipeline import PipelineConfig, SpikePipeline, accuracy_ci95
from .runs import RunWriter, load_arrays, read_json

log = logging.getLogger("tactilesnn")


@dataclass
class TrainResult:
    pipeline: SpikePipeline
    history: list[float]
    metrics: dict
    confusion: np.ndarray


def fit_and_evaluate(
    config: PipelineConfig,
    train: WindowDataset,
    test: WindowDataset,
    progress: bool = False,
) -> TrainResult:
    """Fit ``config`` on ``train`` and report accuracy on ``test``."""
    torch.manual_seed(config.seed)
    pipe = SpikePipeline(
        config, train.fs_hz, train.X.shape[-1], train.channel_names, train.class_names
    )
    t0 = time.perf_counter()
    s_train = pipe.encode(train.X)
    s_test = pipe.encode(test.X)
    t_enc = time.perf_counter() - t0
    history = pipe.fit_spikes(s_train, train.y, progress=progress)
    t_fit = time.perf_counter() - t0 - t_enc
    pred = pipe.scores(s_test).argmax(1).numpy()
    acc = float((pred == test.y).mean())
    cm = confusion_matrix(test.y, pred, labels=np.arange(len(test.class_names)))
    metrics = {
        "test_accuracy": acc,
        "test_accuracy_ci95": accuracy_ci95(acc, test.y.size),
        "train_error_final": history[-1],
        "n_train_windows": int(train.y.size),
        "n_test_windows": int(test.y.size),
        "n_train_scans": int(np.unique(train.scan).size),
        "n_test_scans": int(np.unique(test.scan).size),
        "per_class_recall": {
            name: float(cm[i, i] / max(cm[i].sum(), 1)) for i, name in enumerate(test.class_names)
        },
        "encode_seconds": t_enc,
        "fit_seconds": t_fit,
    }
    return TrainResult(pipe, history, metrics, cm)


def train_run(
    task_name: str,
    task_kwargs: dict,
    config: PipelineConfig,
    out: Path,
    overwrite: bool = False,
    progress: bool = True,
) -> tuple[Path, dict]:
    """Generate the task, train, evaluate, and write ``out`` atomically; returns its metrics."""
    writer = RunWriter(out, overwrite=overwrite)  # refuses an existing folder before any work
    try:
        task = get_task(task_name, **task_kwargs)
        t0 = time.perf_counter()
        train, test = task.build(progress=progress)
        log.info(
            "task %s: %d train / %d test windows (%d x %d samples @ %g Hz) in %.1f s",
            task_name,
            train.y.size,
            test.y.size,
            train.X.shape[1],
            train.X.shape[2],
            train.fs_hz,
            time.perf_counter() - t0,
        )
        res = fit_and_evaluate(config, train, test, progress=progress)
        res.metrics["trivial_amplitude_baseline_accuracy"] = linear_amplitude_baseline(
            train.X, train.y, test.X, test.y
        )
        res.metrics["train_error_history"] = res.history
        writer.write_json(
            "config.json",
            {
                "task": task_name,
                "task_kwargs": task_kwargs,
                "pipeline": config.to_dict(),
                "fs_hz": train.fs_hz,
                "window": int(train.X.shape[-1]),
                "channel_names": list(train.channel_names),
                "class_names": list(train.class_names),
                "tactilesnn_version": __version__,
                "torch_version": torch.__version__,
                "python": platform.python_version(),
            },
        )
        writer.write_arrays("weights.npz", res.pipeline.weights())
        writer.write_json("metrics.json", res.metrics)
        writer.write_json(
            "confusion_matrix.json",
            {"labels": list(test.class_names), "matrix": res.confusion.tolist()},
        )
        plot_confusion(res.confusion, test.class_names, writer.file("confusion_matrix.png"))
        path = writer.commit()
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
        PipelineConfig(**cfg["pipeline"]),
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
