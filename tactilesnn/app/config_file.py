"""A ``train --config`` TOML file: run options and pipeline settings, checked before any work.

Pipeline settings come in the nested form (``[encoder]``, ``[model]``, ``[train]`` tables) or the
flat form of earlier versions (``encoder = "lif"``, ``lif_neurons = 8``; also under ``[train]``);
run options (``task``, ``data``, ``val_fraction``...) are top-level keys. Values are checked by
type against :mod:`tactilesnn.app.options` (``overwrite = "false"`` is not a boolean) and the
file's size and nesting are bounded.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomllib

from ..config import TOP_FLAGS, PipelineConfig
from .options import check_settings, train_options

MAX_CONFIG_BYTES = 1 << 20
MAX_DEPTH = 8
#: command-line flags a file may also set (typed: ``overwrite = "false"`` is refused)
COMMAND = {"out": str, "overwrite": bool, "resume": bool, "quiet": bool}


@dataclass(frozen=True)
class TrainFile:
    """What a ``--config`` file holds: its text, the run options it sets and its pipeline
    settings (nested or flat, as :func:`tactilesnn.resolve.resolve` takes them)."""

    text: str
    run: dict[str, Any] = field(default_factory=dict)
    pipeline: dict[str, Any] = field(default_factory=dict)
    #: the command-line flags it sets (``out``, ``overwrite``, ``resume``, ``quiet``)
    command: dict[str, Any] = field(default_factory=dict)


def _depth(v: Any, level: int = 0) -> int:
    if level > MAX_DEPTH:
        return level
    if isinstance(v, dict):
        return max([_depth(x, level + 1) for x in v.values()] or [level + 1])
    if isinstance(v, list):
        return max([_depth(x, level + 1) for x in v] or [level + 1])
    return level


def read_train_file(path: Path) -> TrainFile:
    """Read and check ``path`` (ValueError naming the file and the setting that is wrong)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"config file {path} does not exist")
    if path.stat().st_size > MAX_CONFIG_BYTES:
        raise ValueError(f"{path}: larger than {MAX_CONFIG_BYTES} bytes; not a settings file")
    text = path.read_text(errors="replace")
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{path}: not valid TOML: {e}") from e
    except RecursionError as e:
        raise ValueError(f"{path}: nested too deeply") from e
    if _depth(table) > MAX_DEPTH:
        raise ValueError(f"{path}: nested more than {MAX_DEPTH} levels deep")
    nested = isinstance(table.get("encoder"), dict) or isinstance(table.get("model"), dict)
    if not nested and isinstance(table.get("train"), dict):  # the flat form under [train]
        table = {**{k: v for k, v in table.items() if k != "train"}, **table["train"]}
    options = train_options()
    run: dict[str, Any] = {}
    pipeline: dict[str, Any] = {}
    command: dict[str, Any] = {}
    for key, value in table.items():
        name = key.replace("-", "_")
        if nested and key in ("encoder", "model", "train", *TOP_FLAGS):
            pipeline[key] = value
        elif name in COMMAND:
            kind = COMMAND[name]
            if isinstance(value, bool) != (kind is bool) or not isinstance(value, kind):
                raise ValueError(f"{path}: {key!r} must be {'true or false' if kind is bool else 'text'}, "
                                 f"got {str(value)[:60]!r}")  # fmt: skip
            command[name] = value
        elif name in options and options[name].pipeline and not nested:
            pipeline[name] = value
        elif name in options and not options[name].pipeline:
            run[name] = value
        else:
            raise ValueError(f"{path}: unknown setting {key!r}")
    run = check_settings(run, str(path))
    try:
        if nested:
            PipelineConfig.from_dict(pipeline)
        else:
            pipeline = check_settings(pipeline, str(path))
            PipelineConfig.from_flat(pipeline, strict=True)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{path}: {e}") from e
    return TrainFile(text, run, pipeline, command)
