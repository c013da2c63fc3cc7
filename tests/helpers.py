"""Shared test helpers: a run of a synthetic task or a data file through the public API."""

from __future__ import annotations

from pathlib import Path

from tactilesnn.app.run import FileSource, RunSpec, TaskSource, train_run
from tactilesnn.config import PipelineConfig


def run_task(
    task: str | None,
    params: dict,
    config: PipelineConfig,
    out: Path,
    data: Path | None = None,
    data_window_s: float | None = None,
    data_hop_s: float | None = None,
    **run: object,
) -> tuple[Path, dict]:
    """``train_run`` of a task (or of ``data``) -> ``(run folder, metrics)``; ``run``: the other
    fields of :class:`~tactilesnn.app.run.RunSpec` (``export``, ``resume``, ``progress``...)."""
    source = (
        FileSource(Path(data), data_window_s, data_hop_s)
        if data is not None
        else TaskSource(task, dict(params))
    )
    res = train_run(RunSpec(source, config, Path(out), **run))
    return res.path, res.metrics


def exported_model(tmp: Path, params: dict, epochs: int = 1, n_check: int = 8, **settings):
    """A small hook-loop run exported to ``tmp/m.onnx``: ``(path, pipeline, test split)``."""
    from tactilesnn.app.run import load_run
    from tactilesnn.datasets_synth import HookLoopTask
    from tactilesnn.export import export_pipeline

    run, _ = run_task("hook_loop", params, PipelineConfig.from_flat(epochs=epochs, **settings),
                      Path(tmp) / "r", progress=False)  # fmt: skip
    pipe, _ = load_run(run)
    test = HookLoopTask(**params).build()[1]
    export_pipeline(pipe, Path(tmp) / "m.onnx", test.X[:n_check])
    return Path(tmp) / "m.onnx", pipe, test
