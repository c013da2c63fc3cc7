"""Shared machinery of the trial-based tasks: one sample = one labelled contact trial.

A trial task renders sample ``i`` as ``(x [channels, window] float32, label, info)``; the random
stream of a sample is ``default_rng([task_id, seed, i])``, so sample ``i`` of ``(task, seed)`` is the
same on any machine and in any worker. Classes are balanced by construction (sample ``i`` has
class ``i % n_classes``); the train/test split is a seeded permutation of the sample indices.

Every subclass exposes the same array contract as the hook-vs-loop task (see
:class:`~tactilesnn.datasets_synth.tasks.hook_loop.WindowDataset`), which is what ``tactilesnn train``,
``generate`` and the trivial baseline consume, and documents a ``difficulty`` knob (0 = idealised,
1 = default) and an ``amplitude_spread`` knob (scales the amplitude nuisances).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from ...core.stages import bar_disabled
from ..scenes.faults import Faults, parse_faults
from .base import WindowDataset


@dataclass(frozen=True)
class TrialTask(ABC):
    """Base class: subclasses set the class attributes and implement :meth:`_render`."""

    seed: int = 0
    n_samples: int = 900
    test_fraction: float = 0.2
    difficulty: float = 1.0
    amplitude_spread: float = 1.0
    faults: Faults | str = field(default_factory=Faults)  # or a parse_faults() string

    name: ClassVar[str] = "trial"
    task_id: ClassVar[int] = 0
    resizable: ClassVar[bool] = True  # sample i exists for every i: n_samples can grow
    class_names: ClassVar[tuple[str, ...]] = ()
    units: ClassVar[str] = ""

    def __post_init__(self) -> None:
        if isinstance(self.faults, str):
            object.__setattr__(self, "faults", parse_faults(self.faults))
        for knob in ("difficulty", "amplitude_spread"):
            v = getattr(self, knob)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{knob} must be a finite number >= 0, got {v}")
        if self.n_samples < 2 * len(self.class_names):
            raise ValueError(
                f"n_samples must be >= {2 * len(self.class_names)} (two per class), "
                f"got {self.n_samples}"
            )
        if not 0 < self.test_fraction < 1:
            raise ValueError(f"test_fraction must be in (0, 1), got {self.test_fraction}")

    @classmethod
    def calibrate(cls, X: np.ndarray, y: np.ndarray, fs_hz: float, class_names: tuple[str, ...],
                  budget_s: float = 240.0, seed: int = 0, progress: bool = False,
                  max_evals: int | None = None, optimiser: str = "cma",
                  known: dict[str, float] | None = None):  # fmt: skip
        """Fit the task's sensor model to real recordings ``X [N, channels, samples]`` of the
        classes ``class_names[y]``: a :class:`~..calibration.SensorFit`; ``known``: values the
        user measured (name -> value in the fit's units), held fixed. A task that knows its
        scene well enough to fit it overrides this."""
        base = TrialTask.calibrate.__func__
        able = sorted(n for n, c in _tasks().items()
                      if getattr(getattr(c, "calibrate", None), "__func__", base) is not base)  # fmt: skip
        raise ValueError(f"the {cls.name} task cannot be calibrated; tasks that can: "
                         f"{', '.join(able) or 'none'}")  # fmt: skip

    # subclasses provide ``sensor`` (a model with ``fs_hz`` and ``channel_names``) and either a
    # ``duration_s`` field or their own ``window``
    @property
    @abstractmethod
    def sensor(self):
        """The sensor model this task reads (has ``fs_hz`` and ``channel_names``)."""

    @property
    def fs_hz(self) -> float:
        return float(self.sensor.fs_hz)

    @property
    def window(self) -> int:
        return round(self.duration_s * self.fs_hz)  # type: ignore[attr-defined]

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(self.sensor.channel_names)

    @abstractmethod
    def _render(self, label: int, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
        """Return ``(x [channels, window] float64 in :attr:`units`, info)`` for one trial."""

    # shared ----------------------------------------------------------------------------------
    def rng(self, index: int) -> np.random.Generator:
        return np.random.default_rng([self.task_id, self.seed, index])

    def sample(self, index: int, class_signal: bool = False) -> tuple[np.ndarray, int, dict]:
        """Sample ``index`` -> ``(x [channels, window] float32, label, info)``. With
        ``class_signal``, ``info["class_signal"]``: the class's own signal per sample ``[window]``
        float32 (>= 0, in :attr:`units`, summed over channels): how far the rendering moves from
        the same draw without the stimulus (a Braille slide's letter, not its rest or the
        fingertip's noise; device faults left out), or None where the task cannot render a trial
        without it. It feeds :func:`~tactilesnn.recordings.cut_windows`' window confidences."""
        if not 0 <= index < self.n_samples:
            raise IndexError(f"sample index {index} out of range [0, {self.n_samples})")
        label = index % len(self.class_names)
        rng = self.rng(index)
        x, info = self._render(label, rng)
        if class_signal:
            bare = self._render_without_class(label, self.rng(index))
            info["class_signal"] = None if bare is None else (
                np.abs(np.asarray(x, np.float64) - bare).sum(0).astype(np.float32))  # fmt: skip
        if self.faults.active:  # device draws depend on (task, seed) only; drift on the sample
            device = np.random.default_rng([self.task_id, self.seed, 2**31 + 1])
            x = self.faults.apply(x, self.fs_hz, device, self.rng(index).spawn(1)[0])
        if x.shape != (len(self.channel_names), self.window):
            raise AssertionError(f"{self.name}: rendered {x.shape}, contract says "
                                 f"{(len(self.channel_names), self.window)}")  # fmt: skip
        info["class"] = self.class_names[label]
        return x.astype(np.float32), label, info

    def _render_without_class(self, label: int, rng: np.random.Generator) -> np.ndarray | None:
        """The trial :meth:`_render` draws from ``rng``, without its class's stimulus (every
        other random draw the same); None (default): the task cannot render one."""
        return None

    def render(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Sample ``index`` as windows ``(X [1, C, W] float32, y [1] int64)`` (generator contract)."""
        x, y, _ = self.sample(index)
        return x[None], np.array([y], np.int64)

    def render_with_signal(self, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """:meth:`render` and the trial's class signal ``[1, W]`` float32 (``sample(index,
        class_signal=True)``), or None where the task cannot render a trial without its class."""
        x, y, info = self.sample(index, class_signal=True)
        sig = info.get("class_signal")
        return x[None], np.array([y], np.int64), None if sig is None else sig[None]

    def split(self) -> tuple[np.ndarray, np.ndarray]:
        """Train / test sample indices, a permutation fixed by the seed (stratified by class)."""
        k = len(self.class_names)
        perm = np.random.default_rng([self.task_id, self.seed, 2**31]).permutation(self.n_samples)
        labels = perm % k
        test = np.concatenate(
            [
                perm[labels == c][: max(1, round(self.test_fraction * (labels == c).sum()))]
                for c in range(k)
            ]
        )
        train = np.setdiff1d(np.arange(self.n_samples), test)
        return train, np.sort(test)

    def build(self, progress: bool = False) -> tuple[WindowDataset, WindowDataset]:
        """Render every sample and return the ``(train, test)`` datasets."""
        return self._render_splits(self.split(), progress)

    def test_split(self, progress: bool = False) -> WindowDataset:
        """The test dataset of :meth:`build` alone (only its samples rendered)."""
        return self._render_splits(self.split()[1:], progress)[0]

    def _render_splits(self, parts: tuple[np.ndarray, ...], progress: bool) -> list[WindowDataset]:
        from tqdm.auto import tqdm

        shape = (len(self.channel_names), self.window)
        # rendered straight into each split's array: no full-size copy at any time
        Xs = [np.zeros((idx.size, *shape), np.float32) for idx in parts]
        ys = [np.zeros(idx.size, np.int64) for idx in parts]
        where = sorted((int(i), s, j) for s, idx in enumerate(parts) for j, i in enumerate(idx))
        for i, s, j in tqdm(where, desc=f"{self.name} samples", disable=bar_disabled(progress)):
            Xs[s][j], ys[s][j], _ = self.sample(i)
        return [
            WindowDataset(
                X, y, idx.astype(np.int64), self.fs_hz, self.class_names, self.channel_names
            )
            for X, y, idx in zip(Xs, ys, parts, strict=True)
        ]


def _tasks() -> dict:
    from .base import TASKS

    return dict(TASKS.items())
