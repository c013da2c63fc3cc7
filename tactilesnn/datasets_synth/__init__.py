"""Synthetic tactile data: sensor models, scenes and tasks."""

from __future__ import annotations

import dataclasses

from .capacitive_piezo import CapacitivePiezoParams, CapacitivePiezoStack
from .faults import Faults, parse_faults
from .hook_loop import HookLoopTask, WindowDataset
from .teng_tasks import MaterialTask, StiffnessCurvatureTask
from .texture_task import TextureTask
from .touch_task import TouchModalityTask

TASKS = {
    "hook_loop": HookLoopTask,
    "stiffness_curvature": StiffnessCurvatureTask,
    "material": MaterialTask,
    "texture": TextureTask,
    "touch": TouchModalityTask,
}


def get_task(name: str, **kwargs: object):
    """Instantiate a registered task by name (``kwargs`` go to its constructor)."""
    if name not in TASKS:
        raise ValueError(f"unknown task {name!r}; available tasks: {', '.join(sorted(TASKS))}")
    known = {f.name for f in dataclasses.fields(TASKS[name])}
    unknown = sorted(set(kwargs) - known)
    if unknown:
        raise ValueError(
            f"task {name!r} has no parameter(s) {unknown}; its parameters: {sorted(known)}"
        )
    return TASKS[name](**kwargs)


__all__ = [
    "TASKS",
    "CapacitivePiezoParams",
    "CapacitivePiezoStack",
    "Faults",
    "HookLoopTask",
    "MaterialTask",
    "StiffnessCurvatureTask",
    "TextureTask",
    "TouchModalityTask",
    "WindowDataset",
    "get_task",
    "parse_faults",
]
