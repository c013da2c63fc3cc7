"""Train and evaluate a spike pipeline on a task; write the run folder."""

from __future__ import annotations

import json
import logging
import math
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
from tqdm.auto import tqdm

from . import __version__
from .baselines import linear_amplitude_baseline
from .config import PipelineConfig, TrainConfig, is_nested
from .datasets_synth import WindowDataset, get_task
from .models.base import SpikeModel, to_tensor_labels
from .pipeline import SpikePipeline, accuracy_ci95, select_channels
from .plots import plot_confusion, plot_training, plot_windows
from .recordings import load_data_file
from .runs import RunWriter, load_arrays, read_json, write_json_atomic

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


class Trainer:
    """Training loop for any :class:`~tactilesnn.models.base.SpikeModel`.

    Models that learn by a rule get :meth:`~SpikeModel.rule_update` per mini-batch; the others
    Adam on :meth:`~SpikeModel.loss`. After each epoch: training error, validation accuracy
    (if given), best-weight bookkeeping, early stopping (``patience``) and a resumable state
    (weights, optimizer, RNG; momentum is a model buffer) for ``on_epoch``.
    """

    def __init__(self, model: SpikeModel, config: TrainConfig, progress: bool = False) -> None:
        self.model, self.config, self.progress = model, config, progress
        self.history: dict = {}

    def fit(
        self,
        spikes: torch.Tensor,
        y: np.ndarray,
        val: tuple[torch.Tensor, np.ndarray] | None = None,
        on_epoch: Callable[[int, dict], None] | None = None,
        resume: dict | None = None,
    ) -> list[float]:
        """Train on spike times ``[N, A, k]`` and labels ``[N]``; returns the error per epoch."""
        cfg, model = self.config, self.model
        yt = to_tensor_labels(np.asarray(y), model.n_classes, spikes.shape[0])
        gen = torch.Generator().manual_seed(cfg.seed)
        by_rule = model.learns_by_rule
        opt = None if by_rule else torch.optim.Adam(model.parameters(), lr=model.learning_rate())
        st = {"epoch": 0, "history": [], "val_history": [], "best_score": -math.inf, "stale": 0}
        if resume is None:
            model.prepare(spikes)  # resumed runs restore what it fitted with their weights
        best_w = {k: v.detach().clone() for k, v in model.state_dict().items()}
        if resume is not None:
            _load_state(model, resume["model"])
            gen.set_state(torch.from_numpy(np.asarray(resume["rng"], dtype=np.uint8)))
            if opt is not None and "optimizer" in resume:
                _restore_optimizer(opt, resume["optimizer"])
            st = {k: resume[k] for k in st}
            st["history"], st["val_history"] = list(st["history"]), list(st["val_history"])
            best_w = {k: torch.from_numpy(np.asarray(v)) for k, v in resume["best"].items()}
        desc = f"train {type(model).registry_name}"
        bar = tqdm(range(st["epoch"], cfg.epochs), desc=desc, disable=not self.progress)
        for epoch in bar:
            perm = torch.randperm(spikes.shape[0], generator=gen)
            model.train()
            for i in range(0, perm.numel(), cfg.batch_size):
                idx = perm[i : i + cfg.batch_size]
                if by_rule:
                    with torch.no_grad():
                        model.rule_update(spikes[idx], yt[idx], epoch)
                else:
                    loss = model.loss(spikes[idx], yt[idx])
                    opt.zero_grad()
                    loss.backward()
                    opt.step()
            model.eval()
            err = float((model.batched_scores(spikes).argmax(1) != yt).float().mean())
            st["history"].append(err)
            score = 1.0 - err
            if val is not None:
                vy = torch.as_tensor(np.asarray(val[1]), dtype=torch.long)
                score = float((model.batched_scores(val[0]).argmax(1) == vy).float().mean())
                st["val_history"].append(score)
            if score > st["best_score"]:
                st["best_score"], st["stale"] = score, 0
                best_w = {k: v.detach().clone() for k, v in model.state_dict().items()}
            else:
                st["stale"] += 1
            st["epoch"] = epoch + 1
            bar.set_postfix(
                train_error=f"{err:.4f}", **({"val_acc": f"{score:.4f}"} if val else {})
            )
            if on_epoch is not None:
                on_epoch(epoch, self.state(st, gen, opt, best_w))
            if cfg.patience and val is not None and st["stale"] >= cfg.patience:
                break
        if cfg.keep_best:
            model.load_state_dict(best_w)
        model.eval()
        model.calibrate_decision(spikes)  # on the weights kept
        self.history = st
        return st["history"]

    def state(self, st: dict, gen: torch.Generator, opt, best_w: dict) -> dict:
        """Everything needed to resume: weights, optimizer state, RNG, bookkeeping."""
        state = dict(st)
        state["model"] = {k: v.detach().numpy().copy() for k, v in self.model.state_dict().items()}
        state["best"] = {k: v.numpy().copy() for k, v in best_w.items()}
        state["rng"] = gen.get_state().numpy().copy()
        if opt is not None:
            state["optimizer"] = _flatten_optimizer(opt)
        return state


def _load_state(module: torch.nn.Module, arrays: dict) -> None:
    module.load_state_dict({k: torch.from_numpy(np.asarray(v)) for k, v in arrays.items()})


def _flatten_optimizer(opt: torch.optim.Optimizer) -> dict[str, np.ndarray]:
    out = {}
    for i, st in opt.state_dict()["state"].items():
        for k, v in st.items():
            out[f"{i}.{k}"] = v.numpy().copy() if torch.is_tensor(v) else np.asarray(v)
    return out


def _restore_optimizer(opt: torch.optim.Optimizer, flat: dict[str, np.ndarray]) -> None:
    sd = opt.state_dict()
    state: dict[int, dict] = {}
    for key, v in flat.items():
        i, name = key.split(".", 1)
        state.setdefault(int(i), {})[name] = torch.from_numpy(np.array(v))
    sd["state"] = state
    opt.load_state_dict(sd)


def fit_and_evaluate(
    config: PipelineConfig,
    train: WindowDataset,
    test: WindowDataset,
    progress: bool = False,
    val_fraction: float = 0.0,
    checkpoint: Callable[[int, dict], None] | None = None,
    resume: dict | None = None,
    require_export: bool = False,
) -> TrainResult:
    """Fit ``config`` on ``train`` (optionally holding out validation scans) and test it.

    Building the pipeline checks the configuration against the data (channels, rates, window)
    and, with ``require_export``, that the model can be exported, before any training.
    """
    torch.manual_seed(config.seed)
    fit_set, val_set = split_validation(train, val_fraction, config.seed)
    pipe = SpikePipeline(
        config, train.fs_hz, train.X.shape[-1], train.channel_names, train.class_names
    )
    problem = pipe.model.export_problem() if require_export else None
    if problem:
        raise ValueError(f"this pipeline cannot be exported ({problem}); pass --no-export")
    t0 = time.perf_counter()
    pipe.calibrate(fit_set.X)
    s_train = pipe.encode(fit_set.X, progress=progress)
    s_val = pipe.encode(val_set.X, progress=progress) if val_set is not None else None
    s_test = pipe.encode(test.X, progress=progress)
    t_enc = time.perf_counter() - t0
    trainer = Trainer(pipe.model, config.train, progress=progress)
    history = trainer.fit(
        s_train,
        fit_set.y,
        val=(s_val, val_set.y) if val_set is not None else None,
        on_epoch=checkpoint,
        resume=resume,
    )
    t_fit = time.perf_counter() - t0 - t_enc
    test_scores = pipe.scores(s_test).numpy()
    pred = test_scores.argmax(1)
    early = early_decision_metrics(pipe, s_test, test.y, pred)
    acc = float((pred == test.y).mean())
    cm = confusion_matrix(test.y, pred, labels=np.arange(len(test.class_names)))
    metrics = {
        "test_accuracy": acc,
        "test_accuracy_ci95": accuracy_ci95(acc, test.y.size),
        "train_error_final": history[-1],
        "epochs_run": len(history),
        "val_accuracy_history": trainer.history["val_history"],
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
    skipped = pipe.encoder.skip_stats()  # {mechanism: what it skipped}
    if skipped is not None:  # what the skipping changed: the test split encoded without it
        with pipe.encoder.skipping(False):
            full = pipe.scores(pipe.encode(test.X)).numpy().argmax(1)
        change = {"test_accuracy_without_skipping": float((full == test.y).mean()),
                  "predictions_changed": float((full != pred).mean())}  # fmt: skip
        for mechanism, stats in skipped.items():  # the change is that of all of them together
            metrics[mechanism] = {**stats, **change}
    per_rec = recording_accuracy(test_scores, test.y, test.scan)
    if per_rec is not None:
        metrics.update(per_rec)
    return TrainResult(pipe, history, metrics, cm)


def median_power_frequency(X: np.ndarray, fs_hz: float, n_max: int = 256) -> float:
    """Frequency (Hz) below which half the power of (up to ``n_max``) windows lies, each
    channel's mean removed, summed over channels and windows."""
    idx = np.linspace(0, len(X) - 1, min(len(X), n_max)).round().astype(int)
    x = np.asarray(X[idx], dtype=np.float64)
    x = x - x.mean(-1, keepdims=True)
    power = (np.abs(np.fft.rfft(x, axis=-1)) ** 2).sum(axis=(0, 1))
    cum = np.cumsum(power)
    if not cum[-1] > 0:
        return float(fs_hz) / 4
    k = int(np.searchsorted(cum, 0.5 * cum[-1]))
    return float(np.fft.rfftfreq(x.shape[-1], 1.0 / fs_hz)[k])


def select_encoder(
    config: PipelineConfig,
    train: WindowDataset,
    candidates: tuple[str, ...],
    fraction: float = 0.25,
    progress: bool = False,
) -> tuple[PipelineConfig, dict[str, float]]:
    """The candidate encoder (each with its default settings for the data's rate and window:
    see ``data_defaults`` of its config; the rest of ``config`` unchanged) that scores best on
    ``fraction`` of the training recordings held out (whole recordings; per-recording accuracy
    first where recordings hold several windows, then per window; ties go to the earlier
    candidate). Returns the chosen config and each candidate's score."""
    from .encoders import ENCODERS

    fit_set, val_set = split_validation(train, fraction, config.seed + 1)
    assert val_set is not None
    median = median_power_frequency(fit_set.X, train.fs_hz)
    scores: dict[str, float] = {}
    best, best_key = config, (-1.0, -1.0)
    for name in candidates:
        cls = ENCODERS.config_class(name)
        defaults = getattr(cls, "data_defaults", None)
        fitted = defaults(train.fs_hz, train.X.shape[-1], median) if defaults else {}
        cfg = config.replace(encoder=cls(**fitted))
        m = fit_and_evaluate(cfg, fit_set, val_set, progress=False).metrics
        key = (m.get("test_accuracy_per_recording", m["test_accuracy"]), m["test_accuracy"])
        scores[name] = float(key[1])
        log.info("encoder selection: %s scores %.2f %% on %d held-out windows", name,
                 100 * key[1], val_set.y.size)  # fmt: skip
        if key > best_key:
            best, best_key = cfg, key
    log.info("encoder selection: %s", best.encoder_type)
    return best, scores


def recording_accuracy(scores: np.ndarray, y: np.ndarray, groups: np.ndarray) -> dict | None:
    """Evidence accumulated over the windows of each recording (mean score, then argmax).

    Only when every recording has one label and some have several windows (a scan that visits
    several textures, like hook_loop's, has no single answer); None otherwise.
    """
    ids, inv = np.unique(groups, return_inverse=True)
    if ids.size == 0 or ids.size == y.size:
        return None
    lab_min = np.full(ids.size, np.iinfo(np.int64).max)
    lab_max = np.full(ids.size, -1)
    np.minimum.at(lab_min, inv, y)
    np.maximum.at(lab_max, inv, y)
    if (lab_min != lab_max).any():
        return None
    total = np.zeros((ids.size, scores.shape[1]))
    np.add.at(total, inv, scores)
    acc = float((total.argmax(1) == lab_min).mean())
    return {
        "test_accuracy_per_recording": acc,
        "test_accuracy_per_recording_ci95": accuracy_ci95(acc, ids.size),
        "n_test_recordings": int(ids.size),
    }


@torch.no_grad()
def early_decision_metrics(pipe: SpikePipeline, spikes: torch.Tensor, y, full_pred) -> dict | None:
    """A model deciding before the window ends (if it can): accuracy, window and spikes skipped."""
    classes, t_dec = [], []
    batch = pipe.model.batch_size(spikes)
    for i in range(0, spikes.shape[0], batch):
        decided = pipe.model.early_decision(spikes[i : i + batch])
        if decided is None:  # this model cannot decide early
            return None
        classes.append(decided[0])
        t_dec.append(decided[1])
    if not classes:
        return None
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


SCALARS = ("epoch", "history", "val_history", "best_score", "stale")


def save_checkpoint(folder: Path, state: dict) -> None:
    """Write a resumable training state atomically (npz arrays, then the JSON that marks it)."""
    arrays: dict[str, np.ndarray] = {}
    for group in ("model", "best", "optimizer"):
        for k, v in state.get(group, {}).items():
            arrays[f"{group}/{k}"] = np.asarray(v)
    arrays["rng"] = np.asarray(state["rng"])
    tmp = folder / "checkpoint.tmp.npz"
    np.savez(tmp, **arrays)
    os.replace(tmp, folder / "checkpoint.npz")
    meta = {k: state[k] for k in SCALARS}
    tmp_j = folder / "checkpoint.tmp.json"
    tmp_j.write_text(json.dumps(meta))
    os.replace(tmp_j, folder / "checkpoint.json")


def load_checkpoint(folder: Path) -> dict:
    """Read a checkpoint written by :func:`save_checkpoint` (ValueError if it is damaged)."""
    try:
        meta = json.loads((folder / "checkpoint.json").read_text())
        state: dict = dict(meta)
        arrays = load_arrays(folder / "checkpoint.npz")
    except (OSError, ValueError) as e:
        raise ValueError(
            f"the checkpoint in {folder} is damaged ({e}); pass --overwrite to start afresh"
        ) from e
    for key, value in arrays.items():
        if "/" in key:
            group, name = key.split("/", 1)
            state.setdefault(group, {})[name] = value
        else:
            state[key] = value
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
    data_window_s: float | None = None,
    data_hop_s: float | None = None,
    select_encoders: tuple[str, ...] | None = None,
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
        **({"data_window_s": data_window_s, "data_hop_s": data_hop_s} if data_window_s else {}),
        **({"select_encoders": list(select_encoders)} if select_encoders else {}),
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
        elif partial.exists() and not (partial / "checkpoint.json").is_file():
            # a run that failed before its first epoch left only its settings: nothing to resume
            shutil.rmtree(partial)
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
            train, test = run_data(run_cfg, config.seed)
        else:
            task = get_task(task_name, **task_kwargs)
            select_channels(config.channels, task.channel_names)  # before any data is made
            train, test = task.build(progress=progress)
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
        selection = None
        if select_encoders:
            config, selection = select_encoder(config, train, select_encoders, progress=progress)
        res = fit_and_evaluate(
            config,
            train,
            test,
            progress=progress,
            val_fraction=val_fraction,
            checkpoint=lambda epoch, st: save_checkpoint(partial, st),
            resume=state,
            require_export=export,
        )
        res.metrics["trivial_amplitude_baseline_accuracy"] = linear_amplitude_baseline(
            train.X, train.y, test.X, test.y
        )
        res.metrics["train_error_history"] = res.history
        if selection is not None:
            res.metrics["encoder_selection_val_accuracy"] = selection
        writer.write_json(
            "config.json",
            {
                **run_cfg,
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
        if config_text is not None:
            (writer.file("config.toml")).write_text(config_text)
        writer.write_arrays("weights.npz", res.pipeline.weights())
        writer.write_json(
            "confusion_matrix.json",
            {"labels": list(test.class_names), "matrix": res.confusion.tolist()},
        )
        plot_confusion(res.confusion, test.class_names, writer.file("confusion_matrix.png"))
        plot_training(res.history, res.metrics["val_accuracy_history"],
                      writer.file("training_error.png"))  # fmt: skip
        plot_windows(res.pipeline, test.X, test.y, writer.file("test_windows.png"))
        writer.write_json("metrics.json", res.metrics)
        path = writer.commit()
        shutil.rmtree(partial, ignore_errors=True)  # the run is complete: its checkpoint is spent
    except BaseException:
        writer.abort()
        raise
    if export:  # after the run is safely written: an export failure never loses the run
        res.metrics["onnx"] = export_into_run(res.pipeline, path, test.X, run_cfg, progress)
        write_json_atomic(path / "metrics.json", res.metrics)
    return path, res.metrics


def run_data(cfg: dict, seed: int) -> tuple[WindowDataset, WindowDataset]:
    """The ``(train, test)`` windows of a run trained on a data file, cut as it was cut."""
    return load_data_file(
        Path(cfg["data"]), seed, window_s=cfg.get("data_window_s"), hop_s=cfg.get("data_hop_s")
    )


def export_into_run(
    pipe: SpikePipeline, run: Path, X_check: np.ndarray, run_cfg: dict, progress: bool = False
) -> dict:
    """Write ``run/model.onnx`` (verified on ``X_check``); a failure is reported, not raised."""
    from .export import data_hash, export_pipeline

    try:
        rep = export_pipeline(
            pipe,
            run / "model.onnx",
            X_check,
            metadata={"training_data_sha256": data_hash(run_cfg), "run": run.name},
            progress=progress,
        )
    except Exception as e:  # onnxruntime raises its own types too; the run is kept
        log.error("ONNX export failed (the run folder %s is complete without it): %s", run, e)
        return {"error": f"{type(e).__name__}: {e}"}
    keys = ("nodes", "max_score_diff", "windows_beyond_atol", "prediction_agreement",
            "encoder_max_time_diff_ms", "model_max_score_diff")  # fmt: skip
    return {k: rep[k] for k in keys if k in rep}


def load_run(run_dir: Path) -> tuple[SpikePipeline, dict]:
    """Rebuild a trained pipeline from a run folder (JSON config + npz weights, no pickle)."""
    run_dir = Path(run_dir)
    for name in ("config.json", "weights.npz"):
        if not (run_dir / name).is_file():
            raise FileNotFoundError(f"{run_dir} is not a run folder: {name} is missing")
    cfg = read_json(run_dir / "config.json")
    legacy = not is_nested(cfg["pipeline"])  # written before the component layer
    pipe = SpikePipeline(
        PipelineConfig.from_dict(cfg["pipeline"]),
        cfg["fs_hz"],
        cfg["window"],
        cfg["channel_names"],
        cfg["class_names"],
    )
    pipe.load_weights(load_arrays(run_dir / "weights.npz"), legacy=legacy)
    return pipe, cfg
