"""Settings resolved once: the data's facts, then the data policy, then the user's choices.

Every entry point that trains (``tactilesnn train``, ``evaluate --data``'s run, ``SpikeClassifier``,
the benchmarks) calls :func:`resolve` with what it knows, in one pass and in this order:

1. **the facts of the data** (:class:`~tactilesnn.core.data.DataFacts`: read once from a file's
   headers, or kept by the windows loaded from it), or the synthetic task's instance;
2. **the data policy** (:mod:`tactilesnn.data_policy`): the defaults a file starts from, and
   those that go with one component only (:func:`~tactilesnn.data_policy.model_defaults`);
3. **the user's choices**: flat settings (flags, keyword arguments; each known by the component
   it belongs to, :func:`~tactilesnn.config.flat_settings`) over a ``--config`` file's.

The result (:class:`Resolution`) is the pipeline configuration, the encoder candidates to choose
among on held-out training recordings, and which encoder fields to leave when the encoder is
fitted to the data. A file's or task's facts are read by the caller, once; nothing here opens a
file.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from .config import (
    DEFAULT_ENCODER,
    DEFAULT_MODEL,
    DEFAULT_MODEL_MAX_AFFERENTS,
    WIDE_INPUT_MODEL,
    PipelineConfig,
    apply_flat,
    encoder_settings_given,
    flat_settings,
    is_nested,
)
from .core.data import DataFacts
from .core.settings import flag_fields
from .data_policy import (
    DATA_ENCODER_CANDIDATES,
    DATA_LEVEL_NEURONS,
    DATA_LEVEL_SCALE,
    DATA_LEVEL_SHARE,
    data_file_defaults,
    model_defaults,
)
from .encoders import ENCODERS, build_encoder
from .models import MODELS

log = logging.getLogger("tactilesnn")


@dataclass(frozen=True)
class Resolution:
    """What a run trains: ``config``; ``select``: the encoders to choose among on held-out
    training recordings (empty: ``config``'s own); ``keep``: the fields of ``config``'s encoder
    the user set, left as they are when the encoder is fitted to the data's rate and spectrum
    (None: the encoder is not fitted to the data: a synthetic task's defaults or an event code);
    ``wide``: a synthetic task whose inputs are too many for the default model took a data
    file's defaults."""

    config: PipelineConfig
    select: tuple[str, ...] = ()
    keep: tuple[str, ...] | None = None
    wide: bool = False


def resolve(
    given: Mapping[str, Any],
    base: Mapping[str, Any] | None = None,
    *,
    facts: DataFacts | None = None,
    task: Any = None,
    fields: Mapping[str, Mapping[str, Any]] | None = None,
) -> Resolution:
    """The run's settings from ``given`` (flat pipeline settings the user set), ``base`` (a
    ``--config`` file's pipeline settings, nested or flat) and the data: ``facts`` of a data
    file, or ``task`` (a synthetic task's instance: its channel names, rate and window).
    ``fields``: ``{"encoder" | "model": {field: value}}``, settings of whichever encoder and
    model the rest resolves to, by field name (``SpikeClassifier``'s ``encoder_params``). See
    the module docstring for the order."""
    base = dict(base or {})
    user = _user_keys(given, base)
    flat = dict(given)
    wide = False
    if facts is not None:
        flat.update(_policy(facts, flat, base, user))
    if fields:
        by_field = _flat_names(fields, flat, base)
        flat.update(by_field)
        user |= set(by_field)
    elif task is not None and "channels" not in user:
        # the default channel ('dynamic', hook_loop's) where the task has it, else all of them
        if not set(PipelineConfig().channels) <= set(task.channel_names):
            flat["channels"] = ("all",)
            if "model" not in user and not _part_given(user, "model"):
                wide = _wide_input_model(flat, base, task, user)
    config = apply_flat(base, flat)
    epochs = MODELS.get(config.model_type).default_epochs  # a model's own, where it has one
    if epochs is not None and "epochs" not in user:
        config = apply_flat(base, {**flat, "epochs": epochs})
    select: tuple[str, ...] = ()
    keep: tuple[str, ...] | None = None
    if (facts is not None and not facts.events) or wide:
        if not encoder_settings_given(user):
            select = DATA_ENCODER_CANDIDATES
        elif facts is not None:  # the encoder named: its settings not given follow the data
            keep = _encoder_fields_given(config, user, base)
    return Resolution(config, select, keep, wide)


def _policy(facts: DataFacts, flat: dict[str, Any], base: dict[str, Any],
            user: set[str]) -> dict[str, Any]:  # fmt: skip
    """The data policy's settings the user did not give: the file's defaults (a default setting
    of the default model or encoder only with that component), then those of the model in use."""
    owners = flat_settings()
    out: dict[str, Any] = {}
    for key, value in data_file_defaults(facts).items():
        part = owners[key].part if key in owners else None
        if key not in user and part not in user:
            out[key] = value
    model = flat.get("model", out.get("model", _component_of(base, "model")))
    sections = {k for k, v in base.items() if isinstance(v, dict)}  # a file's [model], [train]
    for key, value in model_defaults(facts, model).items():
        if key not in user and owners[key].part not in sections:
            out[key] = value
    return out


def _component_of(base: dict[str, Any], kind: str) -> str:
    """The encoder or model (``kind``) a ``--config`` file names, else the default one."""
    default = DEFAULT_ENCODER if kind == "encoder" else DEFAULT_MODEL
    if is_nested(base):
        section = base.get(kind)
        return section.get("type", default) if isinstance(section, dict) else default
    return str(base.get(kind, default))


def _flat_names(fields: Mapping[str, Mapping[str, Any]], flat: dict[str, Any],
                base: dict[str, Any]) -> dict[str, Any]:  # fmt: skip
    """``{"encoder" | "model": {field: value}}`` as flat settings of the encoder and model in
    use (ValueError naming a field the component does not have)."""
    out: dict[str, Any] = {}
    for kind, values in fields.items():
        if not values:
            continue
        registry = ENCODERS if kind == "encoder" else MODELS
        name = str(flat.get(kind) or _component_of(base, kind))
        names: dict[str, str] = {}
        for flag, field in flag_fields(registry.config_class(name)).items():
            names.setdefault(field, flag)  # a field's own flat name first, then its aliases
        unknown = sorted(set(values) - set(names))
        if unknown:
            raise ValueError(f"{kind} {name!r} has no setting(s) {unknown}; its settings: "
                             f"{sorted(names)}")  # fmt: skip
        out.update({names[f]: v for f, v in values.items()})
    return out


def _user_keys(given: Mapping[str, Any], base: Mapping[str, Any]) -> set[str]:
    """Names of the settings the user gave: flat names, and a ``--config`` file's keys and
    sections."""
    return set(given) | set(base)


def _part_given(user: set[str], part: str) -> bool:
    owners = flat_settings()
    return any(k in owners and owners[k].part == part for k in user)


def _wide_input_model(flat: dict[str, Any], base: dict[str, Any], task: Any,
                      user: set[str]) -> bool:  # fmt: skip
    """The default model's cost grows with the square of its input events: past
    :data:`~tactilesnn.config.DEFAULT_MODEL_MAX_AFFERENTS` a task's default run takes what
    ``train --data`` takes (the linear-cost model, the calibrated level code, and, unless an
    encoder is set, the encoder chosen on held-out training windows; ``--model`` names another).
    Localise, 100 channels: GWT + tempotron would take hours; GWT + readout 57.6 %, with the level
    code 68.3 %, LIF + level code + readout 79.8 % (amplitude baseline 84.0 %)."""
    config = apply_flat(base, flat)
    encoder = build_encoder(config.encoder, task.fs_hz, task.window, len(task.channel_names))
    events = encoder.n_afferents * encoder.max_spikes + config.clock_afferents
    if config.model_type != DEFAULT_MODEL or events <= DEFAULT_MODEL_MAX_AFFERENTS:
        return False
    flat["model"] = WIDE_INPUT_MODEL
    for key, value in (("level_neurons", DATA_LEVEL_NEURONS), ("level_scale", DATA_LEVEL_SCALE),
                       ("level_share", DATA_LEVEL_SHARE)):  # fmt: skip
        if key not in user:
            flat[key] = value
    log.info("%d input events per window: the defaults of a data file (the %s model, level "
             "code; the default %s's exact maximum costs their square per window, --model %s "
             "insists)", events, WIDE_INPUT_MODEL, DEFAULT_MODEL, DEFAULT_MODEL)  # fmt: skip
    return True


def _encoder_fields_given(config: PipelineConfig, user: set[str],
                          base: dict[str, Any]) -> tuple[str, ...]:  # fmt: skip
    """The fields of ``config``'s encoder the user set (flat names, or the keys of a
    ``--config`` file's ``[encoder]`` section)."""
    flags = flag_fields(ENCODERS.config_class(config.encoder_type))
    fields = {flags[k] for k in user if k in flags}
    section = base.get("encoder")
    if isinstance(section, dict):
        fields |= set(section) - {"type"}
    return tuple(sorted(fields))
