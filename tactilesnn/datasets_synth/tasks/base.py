"""The task protocol and registry (the data contract, :class:`WindowDataset`, is in
:mod:`tactilesnn.core.data`: what every task's ``build()`` and every recordings reader returns).

A task is a frozen dataclass satisfying :class:`Task`, registered with ``@register_task`` (unique
``name`` and ``task_id``; the id is mixed into every random stream, so two tasks never share one).
Scan tasks (one sample = one long scan cut into windows; fixed size) and trial tasks (one sample =
one window; ``n_samples`` can grow) are siblings behind the same protocol.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

from ...core.data import WindowDataset
from ...schema.tasks import TASKS

__all__ = ["TASKS", "ScanTask", "Task", "WindowDataset", "get_task", "register_task"]


@runtime_checkable
class Task(Protocol):
    """What the CLI, the generator and the benchmarks use of a task."""

    name: ClassVar[str]
    task_id: ClassVar[int]
    #: True if ``n_samples`` can be raised to render more samples (trial tasks)
    resizable: ClassVar[bool]
    #: the windows' units (the sensor's output, as the task scales it)
    units: ClassVar[str]
    seed: int

    @property
    def fs_hz(self) -> float: ...
    @property
    def window(self) -> int: ...
    @property
    def channel_names(self) -> tuple[str, ...]: ...
    @property
    def n_samples(self) -> int: ...
    def render(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Sample ``index`` -> its windows ``(X [n, C, W] float32, y [n] int64)``."""
        ...

    def split(self) -> tuple[np.ndarray, np.ndarray]: ...
    def build(self, progress: bool = False) -> tuple[WindowDataset, WindowDataset]: ...
    def test_split(self, progress: bool = False) -> WindowDataset:
        """``build()[1]`` with only the test split's samples rendered."""
        ...


@runtime_checkable
class ScanTask(Task, Protocol):
    """A task whose samples are long continuous scans (cut into windows by ``render``)."""

    @property
    def n_scans(self) -> int: ...
    def scan(self, index: int) -> tuple[np.ndarray, np.ndarray, dict]:
        """Scan ``index`` -> ``(x [channels, samples], labels per sample, description)``."""
        ...


def register_task(cls: type) -> type:
    """Class decorator: register a task under its ``name`` (names and ids must be unique)."""
    name, tid = cls.name, cls.task_id
    if TASKS.registered(name):
        raise ValueError(f"task {name!r} is already registered")
    if not isinstance(tid, int) or tid < 1:
        raise ValueError(f"task {name!r}: task_id must be an integer >= 1, got {tid!r}")
    clash = [n for n, c in TASKS.registered_items() if c.task_id == tid]
    if clash:
        raise ValueError(f"task {name!r}: task_id {tid} is already used by {clash[0]!r}")
    return TASKS.register(name)(cls)


def task_parameters(name: str) -> set[str]:
    """Constructor parameters of a registered task (ValueError for an unknown name)."""
    if name not in TASKS:
        raise ValueError(f"unknown task {name!r}; available tasks: {', '.join(TASKS)}")
    return {f.name for f in dataclasses.fields(TASKS[name])}


def get_task(name: str, **kwargs: object) -> Task:
    """Instantiate a registered task by name (``kwargs`` go to its constructor)."""
    known = task_parameters(name)
    unknown = sorted(set(kwargs) - known)
    if unknown:
        raise ValueError(
            f"task {name!r} has no parameter(s) {unknown}; its parameters: {sorted(known)}"
        )
    return TASKS[name](**kwargs)
