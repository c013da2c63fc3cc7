"""Synthetic tactile data: sensor models, scenes and tasks."""

from __future__ import annotations

from .capacitive_piezo import CapacitivePiezoParams, CapacitivePiezoStack
from .hook_loop import HookLoopTask, WindowDataset

TASKS = {"hook_loop": HookLoopTask}


def get_task(name: str, **kwargs: object) -> HookLoopTask:
    """Instantiate a registered task by name (``kwargs`` go to its constructor)."""
    if name not in TASKS:
        raise ValueError(f"unknown task {name!r}; available tasks: {', '.join(sorted(TASKS))}")
    return TASKS[name](**kwargs)


__all__ = [
    "TASKS",
    "CapacitivePiezoParams",
    "CapacitivePiezoStack",
    "HookLoopTask",
    "WindowDataset",
    "get_task",
]
