"""Synthetic tactile data: sensor models, scenes and tasks."""

from __future__ import annotations

from .scenes.faults import Faults, parse_faults
from .sensors.capacitive_piezo import CapacitivePiezoParams, CapacitivePiezoStack
from .tasks.base import TASKS, Task, WindowDataset, get_task, register_task

# the registry's list of shipped tasks: importing a task module registers it
from .tasks.braille import BrailleTask
from .tasks.hook_loop import HookLoopTask
from .tasks.localisation import ContactLocalisationTask
from .tasks.teng import MaterialTask, StiffnessCurvatureTask
from .tasks.texture import TextureTask
from .tasks.touch import TouchModalityTask

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
