"""``tactilesnn finetune``: pretrain, then fine-tune, from the command line.

A trained run folder (typically ``train --data`` on a calibrated model's generated recordings)
is adapted to a few labelled recordings of the real sensor: the read-out's input scaling
re-estimated on the file's training split (:func:`~tactilesnn.training.adapt_pipeline`,
labels unused), then its weights re-fitted with a prior centred on the pretrained ones
(:func:`~tactilesnn.training.finetune_pipeline`), the same two calls ``bench sim2real``
measures. The file is cut into windows as the run's were (the run's window and hop, at the
run's rate) and split by recording with the run's seed; the test split is scored before and
after, never fitted. The result is a new run folder (``config.json`` naming the file and the
pretrained run, ``weights.npz``, ``metrics.json``, ``model.onnx``) that ``evaluate``,
``export`` and ``serve`` read like any other; the pretrained run is left as it was.
"""

from __future__ import annotations

import logging
import platform
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..core.data import confidence_summary
from ..core.files import file_sha256, write_json_atomic
from ..core.version import __version__
from ..models.base import SpikeModel
from ..pipeline import SpikePipeline, accuracy_ci95, recording_accuracy
from ..recordings import datasets_from_arrays, expected_class_signal, read_data_arrays
from ..training import transfer_pipeline
from .run import RUNS_ROOT, FileSource, export_into_run, load_run, match_channels, match_classes
from .runs import OutLock, RunWriter, default_run_dir

log = logging.getLogger("tactilesnn")

#: the file's rate may differ from the run's by this share: a run generated at a rounded rate
#: (93.97 Hz for the iCub file's 93.9668 Hz: 3.4e-5) cuts the same windows, its time scale off
#: by less than a sample per window of 1,000
RATE_TOLERANCE = 1e-3


def _scores(pipe: SpikePipeline, X: np.ndarray, y: np.ndarray, scan: np.ndarray) -> dict:
    s = pipe.scores(pipe.encode(X)).numpy()
    acc = float((s.argmax(1) == y).mean())
    return {"test_accuracy": acc, "test_accuracy_ci95": accuracy_ci95(acc, y.size),
            **(recording_accuracy(s, y, scan) or {})}  # fmt: skip


def finetune_run(run_dir: Path, data: Path, out: Path | None = None, overwrite: bool = False,
                 export: bool = True, fs_hz: float | None = None, choose_prior: bool = False,
                 class_share: bool = False, progress: bool = True,
                 adapt_only: bool = False) -> dict[str, Any]:  # fmt: skip
    """Fine-tune the run at ``run_dir`` on ``data``'s training split (see the module doc) and
    write the result to ``out`` (default ``runs/<data>-finetuned-<encoder>-<model>-<time>``).
    ``fs_hz``: the file's rate where it states none. ``choose_prior``: the prior's strength by
    leave-one-recording-out cross-validation on the training split. ``class_share``: a second
    fine-tune, each training window fitted to its share of its class's signal as the
    pretraining recordings hold it (:func:`_class_share`), and the result the mean of the two
    read-outs (:func:`~tactilesnn.training.blend_finetuned`, as ``bench sim2real``'s pretrained
    arm). ``adapt_only``: only the input scaling re-estimated on the training split (its labels
    unused), the weights as pretrained: a run trained on synthetic recordings alone, read on the
    user's sensor (``bench sim2real``'s synthetic-only arm). Returns the metrics with
    ``"path"``."""
    run_dir = Path(run_dir)
    pipe, record = load_run(run_dir)
    if adapt_only and (class_share or choose_prior):
        raise ValueError("--adapt-only fits no weights: --class-share and --choose-prior do not "
                         "apply")  # fmt: skip
    if adapt_only and type(pipe.model).adapt is SpikeModel.adapt:
        raise ValueError(f"the run's {pipe.config.model_type!r} model has no input scaling to "
                         "re-estimate; pretrain with --model readout or forest")  # fmt: skip
    if not adapt_only and not pipe.model.finetune_parameters():
        raise ValueError(f"the run's {pipe.config.model_type!r} model does not fine-tune; "
                         "pretrain with --model readout")  # fmt: skip
    window_s = pipe.window / pipe.fs_hz
    hop_s = record.get("data_hop_s") or window_s / 2
    source = FileSource(Path(data), window_s, hop_s, fs_hz=fs_hz)

    arrays = read_data_arrays(Path(data), fs_hz)
    rate = float(np.asarray(arrays.get("fs", np.nan), np.float64).reshape(-1)[0])
    if abs(rate - pipe.fs_hz) > RATE_TOLERANCE * pipe.fs_hz:  # (no rate: the loader says so)
        raise ValueError(f"{data} is sampled at {rate:g} Hz, the run at {pipe.fs_hz:g} Hz: "
                         "record or resample the data at the run's rate")  # fmt: skip
    if class_share:
        arrays = {**arrays, "class_signal": _class_share(record, arrays, data)}
    try:
        train, test = datasets_from_arrays(arrays, Path(data), pipe.config.seed,
                                           window=(window_s, hop_s))  # fmt: skip
    except ValueError as e:
        raise ValueError(f"{e} (the run's windows: {pipe.window} samples, {window_s:g} s)") from e
    train, test = (match_classes(match_channels(d, pipe.channel_names), pipe.class_names)
                   for d in (train, test))  # fmt: skip
    if train.y.size < 2 or test.y.size == 0:
        raise ValueError(f"{data}: {train.y.size} training / {test.y.size} test windows; "
                         "fine-tuning needs two training windows or more and a test split")  # fmt: skip
    out = (default_run_dir(RUNS_ROOT, f"{Path(data).stem}-finetuned", pipe.config.encoder_type,
                           pipe.config.model_type) if out is None else Path(out))  # fmt: skip
    if out.resolve() == run_dir.resolve():
        raise ValueError(f"--out {out} is the pretrained run itself: choose another folder (the "
                         "pretrained run is kept as it is)")  # fmt: skip
    with OutLock(out):
        writer = RunWriter(out, overwrite=overwrite)  # refuses an existing folder before work
        try:
            metrics = _transfer(pipe, train, test, Path(data).name, class_share, adapt_only,
                                choose_prior, progress)  # fmt: skip
            config = {**source.record(), "pipeline": pipe.config.to_dict(),
                      "pretrained_run": {"path": str(run_dir.resolve()),
                                         "weights_sha256": file_sha256(run_dir / "weights.npz"),
                                         "data": record.get("data"), "task": record.get("task")},
                      "fs_hz": pipe.fs_hz, "window": int(pipe.window),
                      "channel_names": list(pipe.channel_names),
                      "class_names": list(pipe.class_names), "tactilesnn_version": __version__,
                      "torch_version": torch.__version__,
                      "python": platform.python_version()}  # fmt: skip
            writer.write_json("config.json", config)
            writer.write_arrays("weights.npz", pipe.weights())
            writer.write_json("metrics.json", metrics)
            path = writer.commit()
        except BaseException:
            writer.abort()
            raise
    if export:  # after the run is written: an export failure never loses it
        metrics["onnx"] = export_into_run(pipe, path, test.X, config, progress)
        write_json_atomic(path / "metrics.json", metrics)
    return {**metrics, "path": str(path)}


def _transfer(pipe: SpikePipeline, train, test, name: str, class_share: bool, adapt_only: bool,
              choose_prior: bool, progress: bool) -> dict[str, Any]:  # fmt: skip
    """``pipe`` carried over to ``train`` in place (:func:`~tactilesnn.training.transfer_pipeline`),
    scored on ``test`` before and after -> the run's metrics."""
    before = _scores(pipe, test.X, test.y, test.scan)
    log.info("pretrained run on %s's test split: %.2f %% per window", name,
             100 * before["test_accuracy"])  # fmt: skip
    extra: dict[str, Any] = {}

    def score(stage: str, p: SpikePipeline) -> None:
        if class_share and stage in ("labels", "class_share"):
            extra[f"finetuned_on_{stage}"] = _scores(p, test.X, test.y, test.scan)

    report = transfer_pipeline(pipe, train, train if class_share else None,
                               seed=pipe.config.seed, adapt_only=adapt_only,
                               choose_prior=choose_prior, progress=progress, on_arm=score)  # fmt: skip
    if class_share:
        extra["finetune_class_share"] = report["finetune_class_share"]
    return {**_scores(pipe, test.X, test.y, test.scan), "pretrained": before, **extra,
            **({"train_window_confidence": confidence_summary(train.confidence)}
               if train.confidence is not None else {}),
            "adapt": report["adapt"],
            **({"finetune": report["finetune"]} if "finetune" in report else {}),
            "adapt_only": adapt_only, "n_train_windows": int(train.y.size),
            "n_test_windows": int(test.y.size),
            "n_train_recordings": int(np.unique(train.scan).size),
            "test_recordings": np.unique(test.scan).tolist()}  # fmt: skip


def _class_share(record: dict, arrays: dict[str, np.ndarray], data: Path) -> np.ndarray:
    """The class signal ``[N, samples]`` the recordings in ``arrays`` would have if they
    followed the pretraining recordings' protocol: each its class's mean rendered signal
    (:func:`~tactilesnn.recordings.expected_class_signal`) from the folder the run was trained
    on (``generate`` stores one for tasks that render a trial without its class), classes
    matched by name (ignoring case)."""
    src = record.get("data")
    if not src:
        raise ValueError("--class-share needs a run trained on a generated folder (train --data "
                         "FOLDER); this run was trained on a task")  # fmt: skip
    syn = read_data_arrays(Path(src))
    if "class_signal" not in syn:
        raise ValueError(f"{src} holds no class signal: generate writes one for tasks that can "
                         "render a trial without its class (braille)")  # fmt: skip
    sig, X = np.asarray(syn["class_signal"]), np.asarray(arrays["X"])
    if X.ndim != 3 or sig.shape[1] != X.shape[-1]:
        raise ValueError(f"{data}: recordings of {X.shape[-1]} samples, the pretraining's "
                         f"{sig.shape[1]}: --class-share needs the same length (the signal is "
                         "taken sample by sample)")  # fmt: skip
    if "class_names" not in arrays:
        raise ValueError(f"{data}: --class-share matches classes by name; the file names none "
                         "(add class_names)")  # fmt: skip
    names = [str(c).casefold() for c in syn["class_names"]]
    mine = [str(c).casefold() for c in np.atleast_1d(arrays["class_names"])]
    missing = sorted({c for c in mine if c not in names})
    if missing:
        raise ValueError(f"{data}: classes {missing} are not among the pretraining's {names}")
    to_syn = np.array([names.index(c) for c in mine])
    return expected_class_signal(sig, np.asarray(syn["y"]), to_syn[np.asarray(arrays["y"])])


def finetune_lines(m: dict[str, Any]) -> list[str]:
    """:func:`finetune_run`'s result as the command prints it."""

    def line(tag: str, r: dict) -> str:
        per = r.get("test_accuracy_per_recording")
        rec = "" if per is None else f", {100 * per:.2f} % per recording"
        return f"{tag}: {100 * r['test_accuracy']:.2f} % per window{rec}"

    only = bool(m.get("adapt_only"))
    how = "input scaling re-estimated on" if only else "fine-tuned on"
    unused = ", labels unused" if only else ""
    lines = [line("pretrained, on the file's test split", m["pretrained"]),
             line(f"{how} {m['n_train_recordings']} recordings "
                  f"({m['n_train_windows']} windows{unused})", m)]  # fmt: skip
    ids = m.get("test_recordings", [])
    more = f" and {len(ids) - 12} more" if len(ids) > 12 else ""
    lines.append(f"test split: recordings {', '.join(map(str, ids[:12]))}{more} (fit nothing "
                 "to them, the calibration included)")  # fmt: skip
    if "onnx" in m and "error" not in m["onnx"]:
        lines.append(f"exported: {m['path']}/model.onnx")
    lines.append(f"run folder: {m['path']}")
    return lines
