"""A training run as one typed object, executed by one function.

:class:`RunSpec` says what ``tactilesnn train`` needs (data source, pipeline config, output
folder, resume / overwrite, export); :func:`train_run` builds the data, trains, evaluates and
writes the run folder atomically. The CLI, sweeps and benchmarks build a ``RunSpec`` and call it.

Run folder: ``config.json`` (settings, data source, rate, channel and class names),
``weights.npz`` (no pickle), ``metrics.json``, ``confusion_matrix.json|png``,
``training_error.png``, ``test_windows.png``, ``config.toml`` (the ``--config`` given) and
``model.onnx`` (with export). While training, each epoch is checkpointed in ``<out>.partial/``.
"""

from __future__ import annotations

import functools
import json
import logging
import platform
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..baselines import linear_amplitude_baseline
from ..config import PipelineConfig, is_nested
from ..core.data import WindowDataset
from ..core.files import file_sha256, load_arrays, read_json, write_json_atomic
from ..core.perf import compute_threads
from ..core.settings import saved_before
from ..core.stages import StagePlan
from ..core.version import __version__
from ..datasets_synth import get_task
from ..pipeline import SpikePipeline, select_channels
from ..recordings import HOLD_OUT, load_data_file
from ..selection import (
    SelectionBudget,
    candidate_configs,
    condition_groups,
    fit_encoder_to_data,
    probe,
    select_encoder,
    selection_seconds,
)
from ..training import TrainResult, fit_and_evaluate, load_checkpoint, save_checkpoint
from .plots import plot_confusion, plot_training, plot_windows
from .runs import (
    PARTIAL_FILES,
    ForeignFilesError,
    OutLock,
    RunWriter,
    default_run_dir,
    read_marker,
    remove_owned,
    write_marker,
)

log = logging.getLogger("tactilesnn")

#: where runs go when no folder is named
RUNS_ROOT = Path("runs")


@dataclass(frozen=True)
class TaskSource:
    """A registered synthetic task and its parameters (rendered deterministically)."""

    name: str = "hook_loop"
    params: dict[str, Any] = field(default_factory=dict)
    #: a task states no conditions: its encoder selection holds out recordings
    condition_left_out = None
    hold_out = None

    @property
    def label(self) -> str:
        return self.name

    def record(self) -> dict[str, Any]:
        return {"task": self.name, "task_kwargs": dict(self.params), "data": None}

    def check_config(self, config: PipelineConfig) -> None:
        """Refuse channels the task does not provide, before any data is rendered."""
        select_channels(config.channels, get_task(self.name, **self.params).channel_names)

    def load(self, seed: int, progress: bool = False) -> tuple[WindowDataset, WindowDataset]:
        return get_task(self.name, **self.params).build(progress=progress)

    def load_test(self, seed: int, progress: bool = False) -> WindowDataset:
        """``load(seed)[1]``, the training split not rendered."""
        return get_task(self.name, **self.params).test_split(progress=progress)


@dataclass(frozen=True)
class FileSource:
    """Recordings in a file (``.npz``) or a generated folder, optionally cut into windows of
    ``window_s`` seconds every ``hop_s``. ``sha256``: the data's hash when it was trained on
    (a run's record); loading refuses data that changed since."""

    path: Path
    window_s: float | None = None
    hop_s: float | None = None
    sha256: str | None = None
    fs_hz: float | None = None  # the rate the user stated (--fs), for files without timestamps
    #: the conditions tested on (``--hold-out``: ``"F>=180"``), the others trained on
    hold_out: str | None = None

    @property
    def label(self) -> str:
        return Path(self.path).stem

    @functools.cached_property
    def current_sha256(self) -> str:
        """SHA-256 of the file's bytes (a generated folder: of its manifest, which holds every
        shard's hash)."""
        return file_sha256(Path(self.path))

    def record(self) -> dict[str, Any]:
        """Absolute path and hash: a run folder's data, wherever it is evaluated from."""
        cut = {"data_window_s": self.window_s, "data_hop_s": self.hop_s} if self.window_s else {}
        if self.fs_hz is not None:
            cut["data_fs_hz"] = self.fs_hz
        if self.hold_out is not None:
            cut["data_hold_out"] = self.hold_out
        return {"task": None, "task_kwargs": {}, "data": str(Path(self.path).resolve()),
                "data_sha256": self.current_sha256, **cut}  # fmt: skip

    @property
    def condition_left_out(self) -> str | None:
        """The condition ``hold_out`` names (the encoder selection leaves its values out)."""
        if self.hold_out is None:
            return None
        m = HOLD_OUT.match(self.hold_out)
        return m.group("name") if m else None

    def check_config(self, config: PipelineConfig) -> None:
        """Channels are checked against the file when it is read."""

    def load(self, seed: int, progress: bool = False) -> tuple[WindowDataset, WindowDataset]:
        if self.sha256 is not None and self.sha256 != self.current_sha256:
            raise ValueError(
                f"the data at {self.path} changed since the run was trained (SHA-256 "
                f"{self.current_sha256[:12]}... vs {self.sha256[:12]}...); pass the training "
                "data, or evaluate on new data with --data"
            )
        return load_data_file(Path(self.path), seed, window_s=self.window_s, hop_s=self.hop_s,
                              fs_hz=self.fs_hz, hold_out=self.hold_out)  # fmt: skip

    def load_test(self, seed: int, progress: bool = False) -> WindowDataset:
        """``load(seed)[1]`` (the split is drawn over the whole file, so the file is read)."""
        return self.load(seed, progress)[1]


DataSource = TaskSource | FileSource


def source_of(record: dict[str, Any]) -> DataSource:
    """The data source a run folder's ``config.json`` (or ``run.json``) describes."""
    if record.get("data"):
        return FileSource(Path(record["data"]), record.get("data_window_s"),
                          record.get("data_hop_s"), record.get("data_sha256"),
                          record.get("data_fs_hz"), record.get("data_hold_out"))  # fmt: skip
    return TaskSource(record["task"], dict(record.get("task_kwargs") or {}))


@dataclass(frozen=True)
class RunSpec:
    """Everything one training run needs (see the module docstring)."""

    source: DataSource
    config: PipelineConfig
    #: the run folder; None: ``runs/<source>-<encoder>-<model>-<UTC time>`` named after the
    #: encoder trained (the chosen one where one is selected)
    out: Path | None
    overwrite: bool = False
    resume: bool = False
    export: bool = False
    val_fraction: float = 0.0
    #: encoders to choose among on held-out training recordings (empty: ``config``'s own)
    select_encoders: tuple[str, ...] = ()
    #: a data file's encoder fitted to its facts (rate, window, spectrum) before training,
    #: except these fields the user set (None: ``config``'s encoder as it is)
    fit_encoder_keep: tuple[str, ...] | None = None
    #: the TOML text the settings came from (kept in the run folder as ``config.toml``)
    config_text: str | None = None
    progress: bool = True

    def record(self) -> dict[str, Any]:
        """The settings that identify the run (``run.json``; a resume must match them)."""
        return {
            **self.source.record(),
            **({"select_encoders": list(self.select_encoders)} if self.select_encoders else {}),
            "pipeline": self.config.to_dict(),
            "val_fraction": self.val_fraction,
        }


@dataclass
class RunResult:
    """The written run folder, its metrics, and the pipeline config trained (the chosen encoder
    where one was selected)."""

    path: Path
    metrics: dict
    config: PipelineConfig


def train_run(spec: RunSpec) -> RunResult:
    """Build the data, train, evaluate and write ``spec.out`` atomically.

    Each epoch's state is checkpointed in ``<out>.partial/``; ``spec.resume`` continues from
    there after an interruption (same settings required). Nothing existing is replaced unless
    ``spec.overwrite``.
    """
    out = _default_out(spec, spec.config) if spec.out is None else Path(spec.out)
    with OutLock(out):  # one training per --out, refused up front
        return _train_run(spec, out)


def _train_run(spec: RunSpec, out: Path) -> RunResult:
    writer = RunWriter(out, overwrite=spec.overwrite)  # refuses an existing folder before work
    partial = out.with_name(out.name + ".partial")
    try:
        record = spec.record()  # (hashes the data: inside, so a failure removes the temporary)
        state = _open_partial(partial, record, spec)
        train, test = _load(spec)
        if spec.fit_encoder_keep is not None:
            spec = replace(
                spec, config=fit_encoder_to_data(spec.config, train, spec.fit_encoder_keep)
            )
        plan, budget, configs, probes = _plan(spec, train, test)
        log.info("%s", plan.plan_line())
        config, selection = spec.config, None
        if spec.select_encoders:
            with plan.stage("encoder selection"):
                config, selection = select_encoder(config, train, spec.select_encoders,
                                                   budget=budget, configs=configs,
                                                   leave_out=spec.source.hold_out)  # fmt: skip
            assert budget is not None
            plan.estimate(
                "fit",
                probes[selection["chosen"]].fit_seconds(
                    train.y.size, test.y.size, budget.measured_overhead(selection)
                ),
            )
            if spec.out is None:  # the folder is named after what was trained
                writer.path = _default_out(spec, config)
        with plan.stage("fit"):
            res = fit_and_evaluate(
                config, train, test, progress=spec.progress, val_fraction=spec.val_fraction,
                checkpoint=lambda epoch, st: save_checkpoint(partial, st), resume=state,
                require_export=spec.export,
                unseen_conditions=spec.source.hold_out is None,
            )  # fmt: skip
            res.metrics["trivial_amplitude_baseline_accuracy"] = linear_amplitude_baseline(
                train.X, train.y, test.X, test.y
            )
        res.metrics["train_error_history"] = res.history
        res.metrics["stage_seconds"] = plan.taken
        res.metrics["compute_threads"] = compute_threads()
        if selection is not None:
            res.metrics["encoder_selection"] = selection
        _write_run(writer, spec, {**record, "pipeline": config.to_dict()}, res, train, test)
        path = writer.commit()
        remove_owned(partial, PARTIAL_FILES, "the checkpoint folder")  # the run is complete
    except BaseException:
        writer.abort()
        if read_marker(partial) is not None and not (partial / "checkpoint.json").is_file():
            remove_owned(partial, PARTIAL_FILES, "the checkpoint folder")  # nothing to resume
        raise
    del train  # the export needs the test windows only
    if spec.export:  # after the run is safely written: an export failure never loses the run
        with plan.stage("export"):
            res.metrics["onnx"] = export_into_run(
                res.pipeline, path, test.X, record, spec.progress, spikes=res.test_spikes
            )
        res.metrics["stage_seconds"] = plan.taken
        write_json_atomic(path / "metrics.json", res.metrics)
    return RunResult(path, res.metrics, config)


#: seconds the ONNX export takes besides encoding the verification windows (torch's exporter,
#: onnxruntime's session; measured 5-15 s on 2 cores)
EXPORT_FIXED_S = 10.0


def _plan(spec: RunSpec, train: WindowDataset, test: WindowDataset):
    """The run's stages with estimates from the candidates' measured encoding speed
    (:func:`~tactilesnn.selection.probe`), the selection's budget (None without selection), the
    candidates' configs and probes."""
    n_tr, n_te = train.y.size, test.y.size
    if spec.select_encoders:
        # unseen test conditions: each encoder's variant for them too (selection.shift_variant)
        left_out = condition_groups(train, spec.source.hold_out)[0]
        configs = candidate_configs(spec.config, train, spec.select_encoders,
                                    shift=left_out is not None)  # fmt: skip
    else:
        configs = {spec.config.encoder_type: spec.config}
    probes = {name: probe(cfg, train) for name, cfg in configs.items()}
    fits = [p.fit_seconds(n_tr, n_te) for p in probes.values()]
    fit = None if any(f is None for f in fits) else float(np.mean(fits))  # type: ignore[arg-type]
    rate = float(np.mean([p.seconds_per_window for p in probes.values()]))
    export = EXPORT_FIXED_S + 3 * rate * n_te if spec.export else None
    stages: dict[str, float | None] = {}
    budget = None
    if spec.select_encoders:
        budget = SelectionBudget({n: p.seconds_per_window for n, p in probes.items()},
                                 (fit or 0.0) + (export or 0.0))  # fmt: skip
        stages["encoder selection"] = (selection_seconds(n_tr, len(configs), budget)
                                       if fit is not None else None)  # fmt: skip
    stages["fit"] = fit
    if spec.export:
        stages["export"] = export
    return StagePlan(stages), budget, (configs if spec.select_encoders else None), probes


def _default_out(spec: RunSpec, config: PipelineConfig) -> Path:
    return default_run_dir(RUNS_ROOT, spec.source.label, config.encoder_type, config.model_type)


def _open_partial(partial: Path, record: dict, spec: RunSpec) -> dict | None:
    """Prepare ``<out>.partial/`` (the run's settings and checkpoints); the checkpoint to
    resume from with ``spec.resume``, else None. Only a checkpoint folder tactilesnn wrote is
    ever removed (:func:`~tactilesnn.app.runs.remove_owned`)."""
    state = None
    exists = partial.exists() or partial.is_symlink()
    if exists and (partial.is_symlink() or not partial.is_dir()):
        raise ForeignFilesError(f"{partial} exists and is not a checkpoint folder tactilesnn "
                                "wrote (a link or a file); move it away or choose another --out")  # fmt: skip
    if spec.resume:
        if not (partial / "checkpoint.json").is_file():
            raise FileNotFoundError(f"nothing to resume: no checkpoint in {partial}")
        if read_json(partial / "run.json") != json.loads(json.dumps(record)):
            raise ValueError(
                f"--resume needs the same settings and the same data as the interrupted run "
                f"({partial / 'run.json'})"
            )
        state = load_checkpoint(partial)
        log.info("resuming %s from epoch %d", spec.out, state["epoch"])
    elif exists and not (partial / "checkpoint.json").is_file():
        # a run that failed before its first epoch left only its settings: nothing to resume
        remove_owned(partial, PARTIAL_FILES, "the checkpoint folder")
    elif exists:
        if not spec.overwrite:
            raise FileExistsError(
                f"an interrupted run is in {partial}: pass --resume to continue it or "
                "--overwrite to discard it"
            )
        remove_owned(partial, PARTIAL_FILES, "the checkpoint folder")
    if state is None:
        partial.mkdir(parents=True)
        write_json_atomic(partial / "run.json", record)
        write_marker(partial, "partial")
    return state


def _load(spec: RunSpec) -> tuple[WindowDataset, WindowDataset]:
    t0 = time.perf_counter()
    spec.source.check_config(spec.config)
    train, test = spec.source.load(spec.config.seed, progress=spec.progress)
    log.info("%s: %d train / %d test windows (%d x %d samples @ %g Hz) in %.1f s",
             spec.source.label, train.y.size, test.y.size, train.X.shape[1], train.X.shape[2],
             train.fs_hz, time.perf_counter() - t0)  # fmt: skip
    return train, test


def _write_run(writer: RunWriter, spec: RunSpec, record: dict, res: TrainResult,
               train: WindowDataset, test: WindowDataset) -> None:  # fmt: skip
    """The run folder's files, into the writer's temporary folder."""
    writer.write_json("config.json", {
        **record, "fs_hz": train.fs_hz, "window": int(train.X.shape[-1]),
        "channel_names": list(train.channel_names), "class_names": list(train.class_names),
        "tactilesnn_version": __version__, "torch_version": torch.__version__,
        "python": platform.python_version(),
    })  # fmt: skip
    if spec.config_text is not None:
        writer.file("config.toml").write_text(spec.config_text)
    writer.write_arrays("weights.npz", res.pipeline.weights())
    writer.write_json("confusion_matrix.json",
                      {"labels": list(test.class_names), "matrix": res.confusion.tolist()})  # fmt: skip
    plot_confusion(res.confusion, test.class_names, writer.file("confusion_matrix.png"))
    plot_training(res.history, res.metrics["val_accuracy_history"],
                  writer.file("training_error.png"), res.metrics.get("model_fit"))  # fmt: skip
    plot_windows(res.pipeline, test.X, test.y, writer.file("test_windows.png"))
    writer.write_json("metrics.json", res.metrics)


def evaluation_data(pipe: SpikePipeline, record: dict, data: Path | None = None,
                    every: bool = False, progress: bool = False,
                    fs_hz: float | None = None) -> WindowDataset:  # fmt: skip
    """What to evaluate a trained pipeline on: the test split of its own data (``record``: its
    ``config.json``), or of ``data`` (cut as its data was; ``every``: all its recordings),
    with channels and classes matched to the run's by name (refused where they differ)."""
    if data is None:
        return source_of(record).load_test(pipe.config.seed, progress=progress)
    tr, test = load_data_file(Path(data), pipe.config.seed, window_s=record.get("data_window_s"),
                              hop_s=record.get("data_hop_s"),
                              fs_hz=fs_hz if fs_hz is not None else record.get("data_fs_hz"))  # fmt: skip
    if every:
        test = tr.concat(test)
    if abs(test.fs_hz - pipe.fs_hz) > 1e-6 * pipe.fs_hz:
        raise ValueError(f"data sampled at {test.fs_hz} Hz, the run expects {pipe.fs_hz} Hz")
    return match_classes(match_channels(test, pipe.channel_names), pipe.class_names)


def match_channels(data: WindowDataset, want: tuple[str, ...]) -> WindowDataset:
    """``data`` with its channels in the run's order (by name); ValueError if they differ."""
    have = tuple(data.channel_names)
    if have == tuple(want):
        return data
    if have == tuple(f"ch{i}" for i in range(len(want))):  # the file names none: by position
        log.warning("the data names no channels: taken in the run's order (%s ...)", want[0])
        return replace(data, channel_names=tuple(want))
    if sorted(have) != sorted(want):
        raise ValueError(f"the data's channels {list(have)} are not the run's {list(want)}")
    log.warning("data channels are in another order than the run's: reordered by name")
    idx = [have.index(c) for c in want]
    return replace(data, X=data.X[:, idx], channel_names=tuple(want))


def match_classes(data: WindowDataset, want: tuple[str, ...]) -> WindowDataset:
    """``data``'s labels as indices into the run's class names (matched by name: a file that
    lists its classes in another order scores correctly); ValueError for classes the run does
    not know."""
    have = tuple(data.class_names)
    if have == tuple(want):
        return data
    folded = [str(c).casefold() for c in want]
    if (
        set(have) - set(want)
        and len(set(folded)) == len(want)
        and all(str(c).casefold() in folded for c in have)
    ):  # "A" in the file, "a" in the run: the same class where case tells none apart
        log.warning("the data's classes %s matched to the run's %s ignoring case", list(have),
                    list(want))  # fmt: skip
        have = tuple(want[folded.index(str(c).casefold())] for c in have)
        data = replace(data, class_names=have)
        if have == tuple(want):
            return data
    unknown = sorted(set(have) - set(want))
    if unknown:
        raise ValueError(f"the data's classes {unknown} are not among the run's {list(want)}")
    log.warning("data classes are listed in another order than the run's: matched by name")
    to_run = np.asarray([list(want).index(c) for c in have], dtype=np.int64)
    return replace(data, y=to_run[data.y], class_names=tuple(want))


def export_into_run(
    pipe: SpikePipeline, run: Path, X_check: np.ndarray, record: dict, progress: bool = False,
    spikes: torch.Tensor | None = None,
) -> dict:  # fmt: skip
    """Write ``run/model.onnx`` (verified on ``X_check``, whose spike times the pipeline gave
    as ``spikes`` where the caller has them); a failure is reported, not raised."""
    from ..export import data_hash, export_pipeline

    try:
        rep = export_pipeline(
            pipe,
            run / "model.onnx",
            X_check,
            metadata={"training_data_sha256": data_hash(record), "run": run.name},
            progress=progress,
            spikes=spikes,
        )
    except Exception as e:  # onnxruntime raises its own types too; the run is kept
        log.error("ONNX export failed (the run folder %s is complete without it): %s", run, e)
        return {"error": f"{type(e).__name__}: {e}"}
    keys = ("nodes", "max_score_diff", "windows_beyond_atol", "prediction_agreement",
            "encoder_max_time_diff_ms", "model_max_score_diff")  # fmt: skip
    return {k: rep[k] for k in keys if k in rep}


def saved_pipeline_config(d: dict) -> PipelineConfig:
    """A saved run's settings: a component field added after the run was written takes the
    value it had then (its ``saved_before`` in the settings schema), not today's default."""
    cfg = PipelineConfig.from_dict(d)
    for part in ("model", "encoder"):
        settings = getattr(cfg, part)
        before = saved_before(type(settings))
        saved = d.get(part, {}) if is_nested(d) else d
        missing = {k: v for k, v in before.items() if k not in saved}
        if missing:
            cfg = cfg.replace(**{part: replace(settings, **missing)})
    return cfg


def load_run(run_dir: Path) -> tuple[SpikePipeline, dict]:
    """Rebuild a trained pipeline from a run folder (JSON config + npz weights, no pickle)."""
    run_dir = Path(run_dir)
    for name in ("config.json", "weights.npz"):
        if not (run_dir / name).is_file():
            raise FileNotFoundError(f"{run_dir} is not a run folder: {name} is missing")
    cfg = read_json(run_dir / "config.json")
    needed = {"pipeline": dict, "fs_hz": (int, float), "window": int, "channel_names": list,
              "class_names": list}  # fmt: skip
    bad = [
        k for k, t in needed.items() if not isinstance(cfg, dict) or not isinstance(cfg.get(k), t)
    ]
    if bad:
        raise ValueError(f"{run_dir / 'config.json'} is damaged ({', '.join(bad)} missing or of "
                         "the wrong type): not a run folder tactilesnn can load")  # fmt: skip
    legacy = not is_nested(cfg["pipeline"])  # written before the component layer
    pipe = SpikePipeline(
        saved_pipeline_config(cfg["pipeline"]),
        cfg["fs_hz"],
        cfg["window"],
        cfg["channel_names"],
        cfg["class_names"],
    )
    pipe.load_weights(load_arrays(run_dir / "weights.npz"), legacy=legacy)
    return pipe, cfg
