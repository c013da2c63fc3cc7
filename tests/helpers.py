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
