"""Settings -> a run: :func:`run_spec` reads the data source's facts once (a file's headers, or
the synthetic task built once), checks the run options that need no data first, and hands the
pipeline settings to :func:`tactilesnn.resolve.resolve` (the data policy, then the user's
choices) for the :class:`~tactilesnn.app.run.RunSpec` that ``train``, sweeps and ``evaluate``
run.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from ..datasets_synth import get_task, parse_faults
from ..datasets_synth.tasks.base import task_parameters
from ..recordings import DataFacts, data_facts
from ..resolve import resolve
from .options import train_options
from .run import FileSource, RunSpec, TaskSource

log = logging.getLogger("tactilesnn")


def task_params(task: str, settings: dict[str, Any]) -> dict[str, Any]:
    """The task's parameters from run options (difficulty, amplitude spread, faults,
    ``task_kw`` entries ``key=value`` with JSON values)."""
    kw: dict[str, Any] = {"difficulty": settings["difficulty"],
                          "amplitude_spread": settings["amplitude_spread"]}  # fmt: skip
    for item in settings.get("task_kw") or ():
        key, sep, val = str(item).partition("=")
        if not sep or not key:
            raise ValueError(f"task_kw expects key=value, got {item!r}")
        try:
            value = json.loads(val)
        except json.JSONDecodeError:
            value = val
        kw[key.strip()] = tuple(value) if isinstance(value, list) else value
    if settings.get("faults"):
        if "faults" not in task_parameters(task):
            raise ValueError(f"faults apply to tasks with a sensor-fault model, not {task}")
        parse_faults(settings["faults"])  # fail early on a typo
        kw["faults"] = settings["faults"]
    return kw


def data_window(
    settings: dict[str, Any], facts: DataFacts | None = None
) -> tuple[float | None, float | None]:
    """``(window_s, hop_s)`` to cut a data file's recordings with (None: keep them whole)."""
    window_s, hop_s = settings.get("data_window_s"), settings.get("data_hop_s")
    if window_s is None and hop_s is None:
        facts = facts or data_facts(Path(settings["data"]))
        window_s, hop_s = facts.auto_cut or (None, None)
        if window_s is not None:
            log.info("recordings of %s cut into %.3g s windows every %.3g s (--data-window-s 0 "
                     "keeps them whole)", settings["data"], window_s, hop_s)  # fmt: skip
    elif window_s == 0:
        if hop_s is not None:
            raise ValueError("--data-hop-s needs a window length (--data-window-s > 0)")
        window_s = None
    return window_s, hop_s


def run_spec(
    settings: dict[str, Any],
    out: Path | None,
    toml: dict[str, Any] | None = None,
    **run: Any,
) -> RunSpec:
    """Settings -> :class:`~tactilesnn.app.run.RunSpec` for ``out`` (None: a folder under
    ``runs/`` named after what is trained). ``settings``: run options
    (missing ones take their defaults) and the pipeline settings given; ``toml``: a
    ``--config`` file's pipeline settings; ``run``: ``overwrite``, ``resume``, ``progress``,
    ``config_text`` of the RunSpec. The source's facts are read once (a file's headers, or the
    task built), then :func:`~tactilesnn.resolve.resolve` gives the pipeline."""
    options = train_options()
    settings = {**{o.name: o.default for o in options.values() if not o.pipeline}, **settings}
    data = settings.get("data")
    check_run_options(settings)
    given = {k: v for k, v in settings.items() if k in options and options[k].pipeline}
    if data:
        facts = data_facts(Path(data))
        res = resolve(given, toml, facts=facts)
        source: Any = FileSource(Path(data), *data_window(settings, facts),
                                 fs_hz=settings.get("fs"),
                                 hold_out=settings.get("hold_out"))  # fmt: skip
    else:
        params = task_params(settings["task"], settings)
        res = resolve(given, toml, task=get_task(settings["task"], **params))
        source = TaskSource(settings["task"], {**params, "seed": res.config.seed})
    return RunSpec(source, res.config, None if out is None else Path(out),
                   export=bool(settings["export"]), val_fraction=float(settings["val_fraction"]),
                   select_encoders=res.select, fit_encoder_keep=res.keep, **run)  # fmt: skip


def check_run_options(settings: dict[str, Any]) -> None:
    """The run options that need no data, checked before any file is opened: the cut and the
    rate are a ``--data`` file's."""
    if (settings.get("data_window_s") or settings.get("data_hop_s")) and not settings.get("data"):
        raise ValueError("--data-window-s / --data-hop-s cut a --data file's recordings")
    if settings.get("hold_out") and not settings.get("data"):
        raise ValueError("--hold-out names conditions of a --data file's recordings")
    if settings.get("fs") is not None and not settings.get("data"):
        raise ValueError("--fs states the rate of --data recordings; a synthetic task has its own")
    if settings.get("data_window_s") == 0 and settings.get("data_hop_s") is not None:
        raise ValueError("--data-hop-s needs a window length (--data-window-s > 0)")
