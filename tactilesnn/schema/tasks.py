"""The synthetic tasks' names, declared without importing their sensor models.

Each name's module (:mod:`tactilesnn.datasets_synth.tasks`) registers the task class when first
asked for (``TASKS.get(name)``), so the command line lists the tasks without scipy or torch.
"""

from __future__ import annotations

from ..core.registry import Registry

TASKS: Registry = Registry("task")

_TASK_MODULE = "tactilesnn.datasets_synth.tasks."
TASKS.declare("braille", None, _TASK_MODULE + "braille")
TASKS.declare("hook_loop", None, _TASK_MODULE + "hook_loop")
TASKS.declare("localise", None, _TASK_MODULE + "localisation")
TASKS.declare("material", None, _TASK_MODULE + "teng")
TASKS.declare("stiffness_curvature", None, _TASK_MODULE + "teng")
TASKS.declare("texture", None, _TASK_MODULE + "texture")
TASKS.declare("touch", None, _TASK_MODULE + "touch")
