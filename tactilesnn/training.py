"""Fit a pipeline on a training split and evaluate it on a test split: validation hold-out,
metrics (per window, per recording, early decision, skipping), resumable checkpoints.

Run folders, data sources and export around this are the application layer's
(:mod:`tactilesnn.app.run`)."""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from sklearn.metrics import confusion_matrix

from .config import PipelineConfig
from .core.data import WindowDataset, condition_text, confidence_summary
from .core.device import resolve_device
from .core.files import load_arrays
from .models.base import seeded
from .models.softmax_fit import group_folds
from .pipeline import SpikePipeline, accuracy_ci95, recording_accuracy
from .stream_training import fit_streams, stream_evaluation
from .trainer import Trainer

log = logging.getLogger("tactilesnn")


@dataclass
class TrainResult:
    pipeline: SpikePipeline
    history: list[float]
    metrics: dict
    confusion: np.ndarray
    #: the pipeline's spike times of the test windows (on the CPU; None where they were coded
    #: elsewhere), which the export's verification takes instead of coding them again
    test_spikes: torch.Tensor | None = None


def split_validation(
    data: WindowDataset, fraction: float, seed: int, by: np.ndarray | None = None,
    side: str | None = None,
) -> tuple[WindowDataset, WindowDataset | None]:  # fmt: skip
    """Hold out ``fraction`` of the training scans (whole scans, so windows of one scan never
    straddle the split) for early stopping and best-weight selection; ``by`` ``[N]``: hold out
    whole groups of these values instead (a condition: each recording has one value, so its
    windows stay together too), drawn at random, or with ``side`` the highest (``"high"``) or
    lowest (``"low"``) values."""
    if fraction <= 0:
        return data, None
    if not 0 < fraction < 1:
        raise ValueError(f"val_fraction must be in [0, 1), got {fraction}")
    keys = data.scan if by is None else np.asarray(by)
    groups = np.unique(keys)
    rng = np.random.default_rng([seed, 7919])
    n_val = max(1, round(fraction * groups.size))
    if n_val >= groups.size:
        what = "scans" if by is None else "condition values"
        raise ValueError(f"too few {what} ({groups.size}) to hold out a validation fraction")
    if side is None or by is None:
        val_groups = rng.choice(groups, n_val, replace=False)
    else:  # np.unique sorted them
        val_groups = groups[-n_val:] if side == "high" else groups[:n_val]
    is_val = np.isin(keys, val_groups)
    return data.subset(~is_val), data.subset(is_val)


def condition_accuracy(scores: np.ndarray, test: WindowDataset) -> dict[str, dict[str, dict]]:
    """Test accuracy per value of each condition the data states (:attr:`WindowDataset.conditions`):
    ``{name: {value: {"windows", "accuracy", "accuracy_per_recording"}}}``."""
    out: dict[str, dict[str, dict]] = {}
    pred = scores.argmax(1)
    for name in sorted(test.conditions or {}):
        values = test.condition(name)
        rows: dict[str, dict] = {}
        for v in np.unique(values):
            m = values == v
            rec = recording_accuracy(scores[m], test.y[m], test.scan[m]) or {}
            rows[condition_text(v)] = {
                "windows": int(m.sum()), "accuracy": float((pred[m] == test.y[m]).mean()),
                "accuracy_per_recording": rec.get("test_accuracy_per_recording"),
            }  # fmt: skip
        out[name] = rows
    return out


@dataclass
class Fitted:
    """A pipeline fitted by :func:`fit_pipeline`: the trainer (its history), the windows it was
    fitted on and held out for validation, the spikes and labels it learnt (``train_*``: the
    fitted windows, then those coded with their past) and validated on, the windows it also learnt coded
    with their recording's past (``in_recordings``: their indices and spikes, or None), and the
    seconds spent encoding and fitting."""

    pipeline: SpikePipeline
    trainer: Trainer
    history: list[float]
    fit_set: WindowDataset
    val_set: WindowDataset | None
    val_spikes: torch.Tensor | None
    train_spikes: torch.Tensor
    train_y: np.ndarray
    in_recordings: tuple[np.ndarray, torch.Tensor] | None
    encode_seconds: float
    fit_seconds: float


#: folds of whole condition values the unseen-condition estimate re-fits the read-out in (a
#: bounded cost: FabricSlide's 12 speeds and 5 forces, one refit each, added ~70 s to a 65 s
#: run; in 3 folds each, ~15 s)
UNSEEN_FOLDS = 3


def unseen_condition_accuracy(fitted: Fitted) -> dict[str, dict] | None:
    """How the fitted model does on condition values it never saw, where the data states
    conditions and the test holds none out (``train --data`` with no ``--hold-out``): for each
    condition with two or more values among the fitted windows, its values in (at most
    :data:`UNSEEN_FOLDS`) folds of whole values, each fold left out of a copy of the model
    re-solved on the others' spikes (the windows as the run coded them) and scored on it.
    ``{name: {"accuracy", "accuracy_per_recording", "per_value": {value: accuracy}}}`` (over
    every fitted window, each scored by the fit that left its value out), or None where the
    model trains by epochs (a refit of each fold would multiply the run) or nothing can be left
    out."""
    pipe, fit_set = fitted.pipeline, fitted.fit_set
    if not fit_set.conditions or not type(pipe.model).solves_in_one_go(pipe.config.model):
        return None
    n = fit_set.y.size  # the windows coded alone (those coded with their past follow them)
    spikes, y = fitted.train_spikes[:n], fit_set.y
    out: dict[str, dict] = {}
    for name in sorted(fit_set.conditions):
        values = fit_set.condition(name)
        if np.unique(values).size < 2:
            continue
        scores = np.zeros((n, len(pipe.class_names)))
        for held in group_folds(values, UNSEEN_FOLDS):
            got = _left_out_scores(pipe.model, spikes, y, fit_set.scan, held)
            if got is None:
                return None
            scores[held] = got
        rows = condition_accuracy(scores, fit_set)[name]
        rec = recording_accuracy(scores, y, fit_set.scan) or {}
        per_value = {value: r["accuracy"] for value, r in rows.items()}
        out[name] = {"accuracy": float((scores.argmax(1) == y).mean()),
                     "accuracy_per_recording": rec.get("test_accuracy_per_recording"),
                     "per_value": per_value}  # fmt: skip
    return out or None


def _left_out_scores(model: torch.nn.Module, spikes: torch.Tensor, y: np.ndarray,
                     groups: np.ndarray, held: np.ndarray) -> np.ndarray | None:  # fmt: skip
    """Scores of the ``held`` windows by a copy of ``model`` prepared and solved on the others
    in one exact fit at the capacity the model's own solve chose (read-out instants, penalty
    relative to the prior; no cross-validation again: the cost of one final fit per value),
    or None where the solve falls back to epochs."""
    import copy

    m = copy.deepcopy(model)
    if getattr(model, "chosen_capacity", None) is not None:  # no cross-validation again
        m.refit_capacity = model.chosen_capacity
    keep = torch.from_numpy(~held)
    fit = spikes[keep]
    m.prepare(fit)
    yt = torch.as_tensor(y[~held], dtype=torch.int64)
    solved = m.solve(fit, yt, groups[~held])
    if solved is None or solved.get("train_epochs"):
        return None
    m.eval()
    return m.batched_scores(spikes[torch.from_numpy(held)]).numpy()


def fit_pipeline(
    config: PipelineConfig,
    train: WindowDataset,
    progress: bool = False,
    val_fraction: float = 0.0,
    checkpoint: Callable[[int, dict], None] | None = None,
    resume: dict | None = None,
    require_export: bool = False,
    with_past: bool = True,
) -> Fitted:
    """The one way a pipeline is fitted (``tactilesnn train``, :class:`SpikeClassifier`, the
    encoder selection and the benchmarks all come here): hold out ``val_fraction`` of the
    recordings for validation and early stopping, build the pipeline (checked against the data
    and, with ``require_export``, against the exporter, before any work), calibrate and encode,
    add every window that has a past in its recording coded with it (``with_past``: an encoder
    whose stream form carries state; off while encoders are compared), and train (the readout:
    its exact solve). The caller seeds torch's generator (:func:`~.models.base.seeded`)."""
    fit_set, val_set = split_validation(train, val_fraction, config.seed)
    pipe = SpikePipeline(
        config, train.fs_hz, train.X.shape[-1], train.channel_names, train.class_names
    )
    problem = pipe.model.export_problem() if require_export else None
    if problem:
        raise ValueError(f"this pipeline cannot be exported ({problem}); pass --no-export")
    t0 = time.perf_counter()
    pipe.calibrate(fit_set.X)
    dev = resolve_device(config.train.device)  # the encoder runs where the training does
    s_train = pipe.encode(fit_set.X, progress=progress, device=dev)
    s_val = pipe.encode(val_set.X, progress=progress, device=dev) if val_set is not None else None
    # an encoder whose stream form carries state codes a window served in a stream with its
    # past: trained on both codes of every window that has one, so that the window graph (a
    # window alone) and the stream graph (a live stream) both get windows like those it learnt
    fit_y, fit_groups = fit_set.y, fit_set.scan
    # soft targets where the data knows how much of its class each window holds and the model
    # trains on them; a model that does not trains on the labels as they are
    conf = fit_set.confidence if pipe.model.trains_on_confidence else None
    if fit_set.confidence is not None and conf is None:
        log.info("%s trains on hard labels: the windows' confidences are not used",
                 type(pipe.model).registry_name)  # fmt: skip
    elif conf is not None:
        share = confidence_summary(conf)
        log.info("soft targets: each window trained on its share of its class's signal (%.0f %% "
                 "of the windows hold none, %.0f %% all)", 100 * share["none"],
                 100 * share["full"])  # fmt: skip
    in_rec = pipe.encode_in_recordings(fit_set.X, fit_set.scan) if with_past else None
    if in_rec is not None:
        at, s_past = in_rec
        s_train = torch.cat([s_train, s_past])
        fit_y = np.concatenate([fit_set.y, fit_set.y[at]])
        fit_groups = np.concatenate([fit_set.scan, fit_set.scan[at]])
        conf = None if conf is None else np.concatenate([conf, conf[at]])
    t_enc = time.perf_counter() - t0
    trainer = Trainer(pipe.model, config.train, progress=progress)
    history = trainer.fit(
        s_train,
        fit_y,
        val=(s_val, val_set.y) if val_set is not None else None,
        on_epoch=checkpoint,
        resume=resume,
        groups=fit_groups,
        confidence=conf,
    )
    # a stream model: then trained on the recordings as streams, its state carried
    streams = fit_streams(pipe, fit_set.X, fit_set.y, fit_set.scan, progress) if with_past else None
    if streams is not None:
        trainer.history["streams"] = streams
    return Fitted(pipe, trainer, history, fit_set, val_set, s_val, s_train, fit_y, in_rec,
                  t_enc, time.perf_counter() - t0 - t_enc)  # fmt: skip


def adapt_pipeline(pipe: SpikePipeline, data: WindowDataset, progress: bool = False) -> dict:
    """A fitted pipeline's model re-estimates its input statistics on a new domain's windows
    (:meth:`~.models.base.SpikeModel.adapt`; labels unused): after synthetic pretraining, the
    user's few real windows. The encoder keeps its calibration. Returns the model's report."""
    if data.X.shape[0] < 2:
        raise ValueError(f"adapting needs two windows or more, got {data.X.shape[0]}")
    return pipe.model.adapt(pipe.encode(data.X, progress=progress))


def finetune_pipeline(pipe: SpikePipeline, data: WindowDataset, progress: bool = False,
                      choose_prior: bool = False) -> dict:  # fmt: skip
    """Pretrain, then fine-tune: a fitted pipeline adapted to a few windows of a new domain
    (``data``: real recordings after synthetic pretraining). The encoder keeps what it
    calibrated on the pretraining data (its levels, its scaling) and codes ``data``; the model
    re-fits its read-out with a prior centred on the pretrained weights
    (:meth:`~.models.base.SpikeModel.finetune`): the model's own prior strength, or with
    ``choose_prior`` one chosen by leave-one-recording-out cross-validation on ``data`` (iCub
    Braille, k = 2, one draw: it chose the strongest prior, 52.4 % per window against 57.1 %
    with the model's own; not the default). Windows with a ``confidence`` (e.g. from
    :func:`~.recordings.expected_class_signal`) are fitted to soft targets, as in
    :func:`fit_pipeline`. Returns the model's report."""
    if tuple(data.class_names) != tuple(pipe.class_names):
        raise ValueError(f"fine-tuning data has classes {data.class_names}, the pipeline "
                         f"{pipe.class_names}")  # fmt: skip
    if data.confidence is not None and not pipe.model.trains_on_confidence:
        raise ValueError(f"the {type(pipe.model).__name__} model does not train on window "
                         "confidences; fine-tune on windows without them")  # fmt: skip
    spikes = pipe.encode(data.X, progress=progress)
    pipe.model.train()
    try:
        groups = data.scan if choose_prior else None
        conf = None if data.confidence is None else torch.as_tensor(data.confidence)
        return pipe.model.finetune(spikes, torch.as_tensor(data.y, dtype=torch.int64), groups,
                                   confidence=conf)  # fmt: skip
    finally:
        pipe.model.eval()


@torch.no_grad()
def blend_finetuned(pipe: SpikePipeline, *others: SpikePipeline) -> None:
    """``pipe``'s fine-tuned parameters (:meth:`~.models.base.SpikeModel.finetune_parameters`)
    set to their mean over ``pipe`` and ``others``: copies of one pretrained pipeline fine-tuned
    on different targets (the labels; each window's share of its class, which says nothing
    before and after the class's signal). For a linear read-out on shared features the result
    scores every window with the mean of their logits: one read-out, exported like any other.
    iCub Braille (``bench sim2real``, the labels' and the letter's share's fine-tunes, nine
    draws x three seeds, pretrained at the read-out's strongest penalty, docs/sim2real.md):
    per slide 70.1 / 82.1 / 91.5 % at k = 1 / 2 / 5 against 67.2 / 77.5 / 88.9 % for the
    labels' alone; per window 60.2 / 75.2 / 86.8 against 60.5 / 75.8 / 88.2 %."""
    mine = pipe.model.finetune_parameters()
    theirs = [o.model.finetune_parameters() for o in others]
    if not mine or any(len(t) != len(mine) for t in theirs):
        raise ValueError("blending needs copies of one pipeline whose model fine-tunes")
    for i, q in enumerate(mine):
        parts = [q, *(t[i] for t in theirs)]
        if any(x.shape != q.shape for x in parts):
            raise ValueError("blending needs copies of one pipeline (parameter shapes differ)")
        q.copy_(torch.stack(parts).mean(0))


def transfer_pipeline(
    pipe: SpikePipeline,
    train: WindowDataset,
    share: WindowDataset | None = None,
    *,
    seed: int,
    adapt_only: bool = False,
    choose_prior: bool = False,
    progress: bool = False,
    on_arm: Callable[[str, SpikePipeline], None] | None = None,
) -> dict:
    """Pretrained ``pipe`` carried over to a new domain's few labelled windows, in place (what
    ``tactilesnn finetune`` and ``bench sim2real`` both do): the read-out's input scaling
    re-estimated on ``train`` (:func:`adapt_pipeline`, labels unused); unless ``adapt_only``,
    the read-out fine-tuned on ``train``'s labels (:func:`finetune_pipeline`, its window
    confidences ignored) and, given ``share`` (windows weighted by their share of their class's
    signal, ``confidence``), a copy fine-tuned on those, the two blended
    (:func:`blend_finetuned`). Each fine-tune runs under ``seeded(seed)``. ``on_arm(name,
    pipeline)`` sees each stage as it is reached: ``"adapted"``, ``"class_share"`` (the copy),
    ``"labels"``, ``"blend"``. Returns the reports: ``adapt``, ``finetune``,
    ``finetune_class_share``."""
    import copy
    from dataclasses import replace

    report: dict = {"adapt": adapt_pipeline(pipe, train, progress=progress)}
    seen = on_arm or (lambda name, p: None)
    seen("adapted", pipe)
    if adapt_only:
        return report
    if share is not None:
        soft = copy.deepcopy(pipe)
        with seeded(seed):
            report["finetune_class_share"] = finetune_pipeline(soft, share, progress=progress,
                                                               choose_prior=choose_prior)  # fmt: skip
        seen("class_share", soft)
    labels = train if train.confidence is None else replace(train, confidence=None)
    with seeded(seed):
        report["finetune"] = finetune_pipeline(pipe, labels, progress=progress,
                                               choose_prior=choose_prior)  # fmt: skip
    seen("labels", pipe)
    if share is not None:
        blend_finetuned(pipe, soft)
        seen("blend", pipe)
    return report


def fit_and_evaluate(
    config: PipelineConfig,
    train: WindowDataset,
    test: WindowDataset,
    progress: bool = False,
    val_fraction: float = 0.0,
    checkpoint: Callable[[int, dict], None] | None = None,
    resume: dict | None = None,
    require_export: bool = False,
    with_past: bool = True,
    unseen_conditions: bool = False,
) -> TrainResult:
    """Fit ``config`` on ``train`` (:func:`fit_pipeline`) and test it on ``test``: accuracy per
    window (with its interval), per recording, in a stream, early decisions, the confusion
    matrix; with ``unseen_conditions``, each stated condition's values left out in folds
    (:func:`unseen_condition_accuracy`). Random draws from torch's global generator
    (augmentation, dropout) start from ``config.seed``; the caller's generator is left as it
    was."""
    with seeded(config.seed):
        fitted = fit_pipeline(config, train, progress, val_fraction, checkpoint, resume,
                              require_export, with_past)  # fmt: skip
        result = _evaluate(fitted, test, progress, with_past)
    if unseen_conditions:  # the test holds no condition out: how an unseen one would go
        unseen = unseen_condition_accuracy(fitted)
        if unseen is not None:
            result.metrics["unseen_conditions"] = unseen
    return result


def _evaluate(fitted: Fitted, test: WindowDataset, progress: bool, with_past: bool) -> TrainResult:
    pipe, trainer, history = fitted.pipeline, fitted.trainer, fitted.history
    fit_set, val_set, in_rec = fitted.fit_set, fitted.val_set, fitted.in_recordings
    dev = resolve_device(pipe.config.train.device)
    t0 = time.perf_counter()
    s_test = pipe.encode(test.X, progress=progress, device=dev)
    test_rec = pipe.encode_in_recordings(test.X, test.scan) if with_past else None
    t_enc, t_fit = fitted.encode_seconds + time.perf_counter() - t0, fitted.fit_seconds
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
    c = fit_set.confidence
    if c is not None and pipe.model.trains_on_confidence:  # trained on soft targets
        metrics["train_window_confidence"] = confidence_summary(c)
    if test_rec is not None or in_rec is not None:
        metrics["in_stream"] = stream_metrics(pipe, test_scores, test_rec, test.y, in_rec)
    if test.conditions:
        metrics["by_condition"] = condition_accuracy(test_scores, test)
    frames = stream_evaluation(pipe, test.X, test.y, test.scan, test_scores)
    if frames is not None:
        metrics["frame_stream"] = frames
    if trainer.history.get("streams") is not None:
        metrics["stream_training"] = trainer.history["streams"]
    if trainer.history.get("solved") is not None:
        metrics["model_fit"] = trainer.history["solved"]
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
    on_cpu = s_test.device.type == "cpu" and torch.device(dev).type == "cpu"
    return TrainResult(pipe, history, metrics, cm, s_test if on_cpu else None)


def stream_metrics(
    pipe: SpikePipeline,
    test_scores: np.ndarray,
    test_rec: tuple[np.ndarray, torch.Tensor] | None,
    y: np.ndarray,
    train_rec: tuple[np.ndarray, torch.Tensor] | None,
) -> dict:
    """The test accuracy as a stream serves the windows (:meth:`SpikePipeline.
    encode_in_recordings`: each window that has a past in its recording coded with it; the
    others alone, as the window graph codes them) and how many windows had a past."""
    scores = test_scores.copy()
    n_test = 0
    if test_rec is not None:
        at, spikes = test_rec
        scores[at] = pipe.scores(spikes).numpy()
        n_test = len(at)
    acc = float((scores.argmax(1) == y).mean())
    return {"test_accuracy": acc, "test_accuracy_ci95": accuracy_ci95(acc, y.size),
            "test_windows_with_past": n_test,
            "train_windows_added": 0 if train_rec is None else len(train_rec[0])}  # fmt: skip


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
    tmp, tmp_j = folder / "checkpoint.tmp.npz", folder / "checkpoint.tmp.json"
    try:
        np.savez(tmp, **arrays)
        os.replace(tmp, folder / "checkpoint.npz")
        tmp_j.write_text(json.dumps({k: state[k] for k in SCALARS}))
        os.replace(tmp_j, folder / "checkpoint.json")
    finally:  # a failed write (full disk) leaves no temporary file
        tmp.unlink(missing_ok=True)
        tmp_j.unlink(missing_ok=True)


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
