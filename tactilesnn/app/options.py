"""The settings of a training run as one schema: run options (data source, task nuisances,
validation, export) and every pipeline setting of the registered components.

The command line builds its ``train`` flags from it, a sweep file and a TOML ``--config`` are
checked against it, and :func:`tactilesnn.app.defaults.run_spec` turns a settings dict into a
:class:`~tactilesnn.app.run.RunSpec`. Values are checked by type here (a TOML ``"false"`` is not
a boolean, ``1e9`` is not an integer), ranges by the component configs.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from typing import Any

from ..config import DEFAULT_ENCODER, DEFAULT_MODEL, flat_settings, registries
from ..schema.tasks import TASKS

#: largest integer a setting may take (counts are further bounded by the components)
MAX_INT = 1 << 31


@dataclass(frozen=True)
class Option:
    """One setting: its name (``snake_case``; the flag is ``--kebab-case``), default, help,
    value type (``bool``, ``int``, ``float``, ``str``; ``tuple`` for several values),
    choices, and whether the flag may be repeated (``task_kw``)."""

    name: str
    default: Any
    help: str
    kind: type = str
    choices: tuple[str, ...] | None = None
    repeated: bool = False
    pipeline: bool = False  # a pipeline setting (else a run option)

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")

    def check(self, value: Any) -> Any:
        """``value`` of the right type (lists become tuples), else ValueError naming the setting."""
        if self.repeated or self.kind is tuple:
            items = value if isinstance(value, list | tuple) else [value]
            return tuple(_scalar(self, v, str if self.repeated else None) for v in items)
        return _scalar(self, value, self.kind)


def _scalar(opt: Option, value: Any, kind: type | None) -> Any:
    bad = ValueError(
        f"setting {opt.name!r} must be {_kind_name(kind)}, got {str(value)[:60]!r} "
        f"({type(value).__name__})"
    )
    if kind is None:  # an element of a multi-valued setting: any plain scalar
        if isinstance(value, bool | int | float | str):
            return value
        raise bad
    if kind is bool:
        if not isinstance(value, bool):
            raise bad
    elif kind is int:
        if isinstance(value, bool) or not isinstance(value, int) or abs(value) > MAX_INT:
            raise bad
    elif kind is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise bad
        if not math.isfinite(value):
            raise bad
        value = float(value)
    elif not isinstance(value, str):
        raise bad
    if opt.choices is not None and value not in opt.choices:
        raise ValueError(f"setting {opt.name!r} must be one of {list(opt.choices)}, got {value!r}")
    return value


def _kind_name(kind: type | None) -> str:
    return {
        bool: "true or false",
        int: "an integer",
        float: "a finite number",
        str: "text",
        None: "numbers or text",
    }[kind]


#: the options of a run that are not pipeline settings
RUN_OPTIONS: tuple[Option, ...] = (
    Option(
        "task",
        "hook_loop",
        "synthetic task to generate and train on (ignored with --data)",
        choices=tuple(sorted(TASKS)),
    ),
    Option(
        "data",
        None,
        "recordings .npz (X [N,C,S], y, fs, class_names; see README) or a "
        "folder written by tactilesnn generate",
    ),
    Option(
        "fs",
        None,
        "with --data: the sampling rate (Hz) of recordings without a time column; where the "
        "data states its rate, a different --fs is refused",
        float,
    ),
    Option(
        "data_window_s",
        None,
        "with --data: cut each recording into windows of this many "
        "seconds (scores are then also summed per recording); 0: one window per "
        "recording; default: rows of >= 2 s and 256 samples without recording ids are cut "
        "into 7 windows (a quarter of the row, every eighth), shorter rows are kept whole",
        float,
    ),
    Option(
        "data_hop_s",
        None,
        "with --data-window-s: seconds between window starts (default: half a window)",
        float,
    ),
    Option(
        "hold_out",
        None,
        "with --data: test on the recordings of these conditions, train on the others, and "
        "compare the encoders by leaving conditions out: NAME=V1,V2 or NAME>=X (>, <=, <), "
        "NAME a group_<name> array of the file or a field of its file names (F150: F)",
    ),
    Option(
        "difficulty",
        1.0,
        "multiplier of noise, speed variation, Z ripple and texture irregularity",
        float,
    ),
    Option(
        "amplitude_spread",
        1.0,
        "multiplier of the force set-point range and coupling-gain spread",
        float,
    ),
    Option(
        "faults",
        None,
        'sensor faults for trial tasks, e.g. "dead=3;short=0-1@1e5;gain_sd=0.1;drift_per_s=0.01"',
    ),
    Option(
        "task_kw",
        None,
        "extra task parameter, repeatable (e.g. layout_name=mia14, n_samples=2000)",
        repeated=True,
    ),
    Option(
        "val_fraction",
        0.0,
        "fraction of training scans held out for early stopping / best weights",
        float,
    ),
    Option("export", True, "write model.onnx (window -> scores) into the run folder", bool),
)


def run_options() -> tuple[Option, ...]:
    """The options of a run that are not pipeline settings."""
    return RUN_OPTIONS


def pipeline_options() -> tuple[Option, ...]:
    """The component choices and every flat pipeline setting
    (:func:`tactilesnn.config.flat_settings`); their defaults are the components' own."""
    out = []
    for kind, reg in registries().items():
        default = DEFAULT_ENCODER if kind == "encoder" else DEFAULT_MODEL
        out.append(
            Option(
                kind,
                default,
                f"{kind} component (default {default}; with --data "
                "chosen from the file, see README)",
                choices=tuple(reg.names()),
                pipeline=True,
            )
        )
    for name, f in flat_settings().items():
        kind = tuple if isinstance(f.default, tuple) else type(f.default)
        text = f"{f.help} [{f.owner}; default {f.default!r}]"
        out.append(Option(name, f.default, text, kind, f.choices, pipeline=True))
    return tuple(out)


def train_options() -> dict[str, Option]:
    """Every setting of a training run by name (run options first)."""
    return {o.name: o for o in (*run_options(), *pipeline_options())}


def check_settings(settings: dict[str, Any], where: str) -> dict[str, Any]:
    """``settings`` with each value checked against its option; unknown names refused."""
    options = train_options()
    out = {}
    for key, value in settings.items():
        name = key.replace("-", "_")
        if name not in options:
            raise ValueError(f"{where}: {key!r} is not a train setting (tactilesnn train --help)")
        try:
            out[name] = options[name].check(value)
        except ValueError as e:
            raise ValueError(f"{where}: {e}") from e
    return out


def task_names() -> list[str]:
    """The synthetic tasks' names, sorted (declared in :mod:`tactilesnn.schema.tasks`)."""
    return sorted(TASKS)


def add_serve_arguments(p: argparse.ArgumentParser) -> None:
    """``serve``'s flags, as ``python -m tactilesnn.service`` has them (onnxruntime is not
    imported)."""
    from ..service import command

    command.add_arguments(p)
