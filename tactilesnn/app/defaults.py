"""Defaults that follow the data, and the one place that turns a settings dict into a run.

:func:`run_spec`: settings (command-line flags, a TOML ``--config``, a sweep trial) -> a
:class:`~tactilesnn.app.run.RunSpec`. With ``data`` (a user's file) the defaults follow the file:
every channel, the ``readout`` model, the ``events`` encoder for event files (the ``csnn`` model
when their taxels form a grid or have positions, ``taxel_xy``), long recordings cut into windows,
and the encoder chosen among
:data:`~tactilesnn.data_policy.DATA_ENCODER_CANDIDATES` on held-out training recordings
(:func:`~tactilesnn.app.select.select_encoder`) unless the settings name one.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from ..config import (
    DEFAULT_MODEL,
    DEFAULT_MODEL_MAX_AFFERENTS,
    WIDE_INPUT_MODEL,
    PipelineConfig,
    apply_flat,
    encoder_settings_given,
    flat_settings,
)
from ..core.settings import flag_fields
from ..data_policy import (
    DATA_ENCODER_CANDIDATES,
    DATA_LEVEL_NEURONS,
    DATA_LEVEL_SCALE,
    DATA_LEVEL_SHARE,
    data_file_defaults,
)
from ..datasets_synth import Task, get_task, parse_faults
from ..datasets_synth.tasks.base import task_parameters
from ..encoders import ENCODERS, build_encoder
from ..models import MODELS
from ..recordings import DataFacts, data_facts
from .options import run_options, train_options
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


def pipeline_config(settings: dict[str, Any], base: dict[str, Any] | None = None,
                    facts: DataFacts | None = None,
                    task: Task | None = None) -> tuple[PipelineConfig, bool]:  # fmt: skip
    """The pipeline settings given (``settings``' pipeline keys) over ``base`` (a TOML
    ``--config``'s pipeline settings), with the defaults of the data source for what neither
    gives (see the module docstring), and whether a wide task took the data-file defaults (so
    the encoder is chosen as for a file). ``facts``: the ``--data`` file's; ``task``: the
    synthetic task's instance (each built here when not given)."""
    options = train_options()
    flat = {k: v for k, v in settings.items() if k in options and options[k].pipeline}
    base = base or {}
    given = _given(settings, base)
    data = settings.get("data")
    wide = False
    if not data and "channels" not in given:
        # the default channel ('dynamic', hook_loop's) where the task has it, else all of them
        task = task or get_task(settings["task"], **task_params(settings["task"], settings))
        if not set(PipelineConfig().channels) <= set(task.channel_names):
            flat["channels"] = ("all",)
            if "model" not in given and not _model_settings_given(given):
                wide = _wide_input_model(flat, base, task, given)
    if data:
        facts = facts or data_facts(Path(data))
        owners = flat_settings()
        for key, value in data_file_defaults(facts).items():
            # a default setting of the default model (or encoder) only goes with that component
            part = owners[key].part if key in owners else None
            if key not in given and part not in given:
                flat[key] = value
    config = apply_flat(base, flat)
    epochs = MODELS.get(config.model_type).default_epochs  # a model's own, where it has one
    if epochs is not None and "epochs" not in given:
        flat["epochs"] = epochs
        config = apply_flat(base, flat)
    return config, wide


def _model_settings_given(given: set[str]) -> bool:
    owners = flat_settings()
    return any(k in owners and owners[k].part == "model" for k in given)


def _wide_input_model(
    flat: dict[str, Any], base: dict[str, Any], task: Any, given: set[str]
) -> bool:
    """The default model's cost grows with the square of its input events: past
    :data:`~tactilesnn.config.DEFAULT_MODEL_MAX_AFFERENTS` a task's default run takes what
    ``train --data`` takes (the linear-cost model, the calibrated level code, and, unless an
    encoder is set, the encoder chosen on held-out training windows; ``--model`` names another).
    Localise, 100 channels: GWT + tempotron would take hours; GWT + readout 57.6 %, with the level
    code 68.3 %, LIF + level code + readout 79.8 % (amplitude baseline 84.0 %)."""
    config = apply_flat(base, flat)
    encoder = build_encoder(config.encoder, task.fs_hz, task.window, len(task.channel_names))
    events = encoder.n_afferents * encoder.max_spikes + config.clock_afferents
    if config.model_type == DEFAULT_MODEL and events > DEFAULT_MODEL_MAX_AFFERENTS:
        flat["model"] = WIDE_INPUT_MODEL
        for key, value in (("level_neurons", DATA_LEVEL_NEURONS), ("level_scale", DATA_LEVEL_SCALE),
                           ("level_share", DATA_LEVEL_SHARE)):  # fmt: skip
            if key not in given:
                flat[key] = value
        log.info("%d input events per window: the defaults of a data file (the %s model, level "
                 "code; the default %s's exact maximum costs their square per window, --model %s "
                 "insists)", events, WIDE_INPUT_MODEL, DEFAULT_MODEL, DEFAULT_MODEL)  # fmt: skip
        return True
    return False


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
    ``config_text`` of the RunSpec."""
    settings = {**{o.name: o.default for o in run_options()}, **settings}
    data = settings.get("data")
    # the source's facts, resolved once: a file's headers, or the task's parameters and instance
    facts = data_facts(Path(data)) if data else None
    params = None if data else task_params(settings["task"], settings)
    task = None if params is None else get_task(settings["task"], **params)
    config, wide = pipeline_config(settings, toml, facts, task)
    if (settings.get("data_window_s") or settings.get("data_hop_s")) and not data:
        raise ValueError("--data-window-s / --data-hop-s cut a --data file's recordings")
    if settings.get("fs") is not None and not data:
        raise ValueError("--fs states the rate of --data recordings; a synthetic task has its own")
    select: tuple[str, ...] = ()
    keep: tuple[str, ...] | None = None
    if data:
        source: Any = FileSource(Path(data), *data_window(settings, facts),
                                 fs_hz=settings.get("fs"))  # fmt: skip
        given = _given(settings, toml)
        assert facts is not None
        if not facts.events:
            if not encoder_settings_given(given):
                select = DATA_ENCODER_CANDIDATES
            else:  # the encoder named: its settings the user did not give follow the data
                keep = _encoder_fields_given(config, given, toml)
    else:
        assert params is not None
        source = TaskSource(settings["task"], {**params, "seed": config.seed})
        if wide and not encoder_settings_given(_given(settings, toml)):
            select = DATA_ENCODER_CANDIDATES  # a wide task took the data-file defaults
    return RunSpec(source, config, None if out is None else Path(out), export=bool(settings["export"]),
                   val_fraction=float(settings["val_fraction"]), select_encoders=select,
                   fit_encoder_keep=keep, **run)  # fmt: skip


def _encoder_fields_given(config: PipelineConfig, given: set[str],
                          toml: dict[str, Any] | None) -> tuple[str, ...]:  # fmt: skip
    """The fields of ``config``'s encoder the user set (flags, flat TOML keys, or the keys of a
    TOML ``[encoder]`` section)."""
    flags = flag_fields(ENCODERS.config_class(config.encoder_type))
    fields = {flags[k] for k in given if k in flags}
    section = (toml or {}).get("encoder")
    if isinstance(section, dict):
        fields |= set(section)
    return tuple(sorted(fields))


def _given(settings: dict[str, Any], toml: dict[str, Any] | None) -> set[str]:
    """Names of the pipeline settings the user gave (flags or keys, and TOML keys/sections)."""
    options = train_options()
    return {k for k in settings if k in options and options[k].pipeline} | set(toml or {})
