"""Synthetic tactile data: sensor models, scenes and tasks."""

from __future__ import annotations

from .base import TASKS, Task, WindowDataset, get_task, register_task

# the registry's list of shipped tasks: importing a task module registers it
from .braille_task import BrailleTask
from .capacitive_piezo import CapacitivePiezoParams, CapacitivePiezoStack
from .faults import Faults, parse_faults
from .hook_loop import HookLoopTask
from .localisation_task import ContactLocalisationTask
from .teng_tasks import MaterialTask, StiffnessCurvatureTask
from .texture_task import TextureTask
from .touch_task import TouchModalityTask

__all__ = [
    "TASKS",
    "BrailleTask",
    "CapacitivePiezoParams",
    "CapacitivePiezoStack",
    "ContactLocalisationTask",
    "Faults",
    "HookLoopTask",
    "MaterialTask",
    "StiffnessCurvatureTask",
    "Task",
    "TextureTask",
    "TouchModalityTask",
    "WindowDataset",
    "get_task",
    "parse_faults",
    "register_task",
]
