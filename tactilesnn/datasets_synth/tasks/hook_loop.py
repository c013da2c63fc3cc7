"""Hook-vs-loop texture task (seed 001): 200 closed-loop scans -> 100-sample windows.

Each scan is rendered by :class:`SlidingScanScene` over both textures (visiting order drawn per
scan) and read by :class:`CapacitivePiezoStack`. Scans are split 160 / 40 at random (from the seed)
into train / test; every window of ``window`` samples (hop ``hop``) lying entirely inside one
texture's labelled interval becomes a classification sample.

Array contract of :class:`WindowDataset`: ``X`` ``[N, 2, window]`` float32 (channels ``static``,
``dynamic`` in relative units, 200 samples/s), ``y`` ``[N]`` int64 (0 = hook, 1 = loop),
``scan`` ``[N]`` int64 scan index.

Difficulty knobs: ``difficulty`` multiplies the spectral nuisances (speed spread and jitter,
normal-load ripple, texture irregularity) and the electronic noise; ``amplitude_spread`` multiplies
the amplitude nuisances (pressure set-point range and coupling-gain spread) that keep overall
amplitude from identifying the texture. Both default to 1.0; 0 gives idealised scans.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from ...core.stages import bar_disabled
from ..scenes.inputs import PressureSeries
from ..scenes.sliding_scan import ScanProtocol, ScanVariability, SlidingScanScene
from ..sensors.capacitive_piezo import CapacitivePiezoStack
from .base import WindowDataset, register_task

TASK_ID = 1  # mixed into every seed so different tasks never share random streams


@register_task
@dataclass(frozen=True)
class HookLoopTask:
    """Seed 001's hook-vs-loop task; deterministic given ``seed`` and the scan index."""

    task_id: ClassVar[int] = TASK_ID
    resizable: ClassVar[bool] = False  # a scan task: its 200 scans are the seed's protocol

    seed: int = 0
    n_planar: int = 100
    n_concave: int = 50
    n_convex: int = 50
    n_test: int = 40
    window: int = 100
    hop: int = 50
    difficulty: float = 1.0
    amplitude_spread: float = 1.0
    protocol: ScanProtocol = field(default_factory=ScanProtocol)
    name: str = "hook_loop"
    class_names: tuple[str, ...] = ("hook", "loop")

    def __post_init__(self) -> None:
        for knob in ("difficulty", "amplitude_spread"):
            v = getattr(self, knob)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{knob} must be a finite number >= 0, got {v}")
        if self.window < 8 or self.hop < 1:
            raise ValueError(f"window must be >= 8 and hop >= 1, got {self.window}, {self.hop}")
        if not 0 < self.n_test < self.n_scans:
            raise ValueError(f"n_test must be in (0, {self.n_scans}), got {self.n_test}")

    units = "relative change (static: dC/C; dynamic: rectified dV/V_bias)"

    @property
    def n_scans(self) -> int:
        return self.n_planar + self.n_concave + self.n_convex

    @property
    def n_samples(self) -> int:
        """A sample of this task is one scan (cut into its labelled windows)."""
        return self.n_scans

    @property
    def channel_names(self) -> tuple[str, ...]:
        return self.sensor.channel_names

    def render(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Scan ``index`` as its windows ``(X [n, 2, W] float32, y [n] int64)``."""
        return self.windows(*self.scan(index)[:2])

    @property
    def fs_hz(self) -> float:
        return self.sensor.fs_hz

    @property
    def sensor(self) -> CapacitivePiezoStack:
        return CapacitivePiezoStack.with_noise_scale(self.difficulty)

    def surface(self, index: int) -> str:
        """Surface of scan ``index``: the first 100 planar, then 50 concave, then 50 convex."""
        if not 0 <= index < self.n_scans:
            raise IndexError(f"scan index {index} out of range [0, {self.n_scans})")
        if index < self.n_planar:
            return "planar"
        return "concave" if index < self.n_planar + self.n_concave else "convex"

    def scene(self, index: int) -> SlidingScanScene:
        var = ScanVariability().scaled(self.difficulty, self.amplitude_spread)
        return SlidingScanScene(
            textures=self.class_names,
            surface=self.surface(index),
            protocol=self.protocol,
            variability=var,
        )

    def scan(self, index: int) -> tuple[np.ndarray, np.ndarray, dict]:
        """Scan ``index`` -> ``(stream [2, samples] float32 @ 200 Hz, labels [samples] int8, info)``.

        Labels are the scene's per-sample labels taken at each readout sample (-1 = null).
        """
        rng = np.random.default_rng([TASK_ID, self.seed, index])
        scene = self.scene(index)
        order = tuple(rng.permutation(len(self.class_names)).tolist())
        pressure, labels_sim, info = scene.render(rng, order)
        stream = self.sensor.read_scene(PressureSeries(pressure, self.protocol.fs_sim_hz), rng)
        decim = round(self.protocol.fs_sim_hz / self.fs_hz)
        labels = labels_sim[::decim][: stream.shape[1]]
        info["order"] = [self.class_names[i] for i in order]
        return stream, labels, info

    def windows(self, stream: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cut windows lying wholly inside one label -> ``(X [n, C, W], y [n])``."""
        w, h = self.window, self.hop
        starts = np.arange(0, stream.shape[1] - w + 1, h)
        lab = np.lib.stride_tricks.sliding_window_view(labels, w)[starts]
        keep = (lab == lab[:, :1]).all(axis=1) & (lab[:, 0] >= 0)
        starts = starts[keep]
        X = np.stack([stream[:, s : s + w] for s in starts]) if starts.size else None
        if X is None:
            return np.zeros((0, stream.shape[0], w), np.float32), np.zeros(0, np.int64)
        return X.astype(np.float32), lab[keep, 0].astype(np.int64)

    def split(self) -> tuple[np.ndarray, np.ndarray]:
        """Random train / test scan indices (160 / 40 by default), deterministic from the seed."""
        perm = np.random.default_rng([TASK_ID, self.seed, 2**31]).permutation(self.n_scans)
        return np.sort(perm[self.n_test :]), np.sort(perm[: self.n_test])

    def build(self, progress: bool = False) -> tuple[WindowDataset, WindowDataset]:
        """Generate every scan and return the ``(train, test)`` window datasets."""
        train_idx, test_idx = self.split()
        per_scan = self._scans(range(self.n_scans), progress)
        return self._gather(per_scan, train_idx), self._gather(per_scan, test_idx)

    def test_split(self, progress: bool = False) -> WindowDataset:
        """The test dataset of :meth:`build` alone (only its scans generated)."""
        test_idx = self.split()[1]
        return self._gather(self._scans(test_idx, progress), test_idx)

    def _scans(self, idx: Iterable[int], progress: bool) -> dict:
        from tqdm.auto import tqdm

        per_scan = {}
        for i in tqdm(idx, desc=f"{self.name} scans", disable=bar_disabled(progress)):
            stream, labels, _ = self.scan(int(i))
            per_scan[int(i)] = self.windows(stream, labels)
        return per_scan

    def _gather(self, per_scan: dict, idx: np.ndarray) -> WindowDataset:
        X = np.concatenate([per_scan[i][0] for i in idx])
        y = np.concatenate([per_scan[i][1] for i in idx])
        scan = np.concatenate([np.full(per_scan[i][1].size, i, np.int64) for i in idx])
        return WindowDataset(X, y, scan, self.fs_hz, self.class_names, self.sensor.channel_names)
