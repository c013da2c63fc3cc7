"""Texture task: sliding scans over 12 textures read by the capacitive-piezo stack (seed 001).

Textures (:data:`~tactilesnn.datasets_synth.scenes.textures.TEXTURES`): hook, loop; gratings of 1, 2 and
4 mm period and a shallow 2 mm one (narrow ridges, 35 % depth); random-rough surfaces with a
self-affine spectrum (correlation 0.3 and 2 mm); fabrics (denim twill, corduroy wales, knit with
stick-slip, felt). One sample = one 1 s window (200 samples at 200 S/s, channels ``static``,
``dynamic``) taken at a random point of a two-stride closed-loop scan at a random speed.

Knobs: ``difficulty`` scales the speed spread (60 mm/s x exp(+-0.15 d), which shifts every
temporal frequency f = v / period), stride jitter, load ripple, texture irregularity and the
electronic noise; ``amplitude_spread`` scales the pressure set point range and the coupling-gain
spread (so amplitude alone cannot name the texture).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..scenes.inputs import PressureSeries
from ..scenes.sliding_scan import ScanProtocol, ScanVariability, SlidingScanScene
from ..scenes.textures import TEXTURES
from ..sensors.capacitive_piezo import CapacitivePiezoStack
from .base import register_task
from .trial import TrialTask


@register_task
@dataclass(frozen=True)
class TextureTask(TrialTask):
    """12 classes (:data:`TEXTURES` order); ``X [N, 2, 200]`` relative units at 200 S/s."""

    n_samples: int = 2400
    speed_mm_s: float = 60.0
    window_samples: int = 200  # 1 s: a few cycles of the coarsest (4 mm) grating
    #: the centre of the scans' normal-load set points (kPa; each scan's varies about it)
    pressure_kpa: float = 1.0

    name: ClassVar[str] = "texture"
    task_id: ClassVar[int] = 2
    class_names: ClassVar[tuple[str, ...]] = tuple(TEXTURES)
    units: ClassVar[str] = "relative change (static: dC/C; dynamic: rectified dV/V_bias)"

    @property
    def sensor(self) -> CapacitivePiezoStack:
        return CapacitivePiezoStack.with_noise_scale(self.difficulty)

    @property
    def window(self) -> int:
        return self.window_samples

    def _render(self, label: int, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
        speed = self.speed_mm_s * np.exp(0.15 * self.difficulty * rng.uniform(-1, 1))
        protocol = ScanProtocol(
            baseline_s=1.6, speed_mm_s=speed, n_strides=2, stride_mm=speed * 1.0, tail_s=0.1
        )
        scene = SlidingScanScene(
            textures=(self.class_names[label],),
            surface="planar",
            protocol=protocol,
            variability=ScanVariability().scaled(self.difficulty, self.amplitude_spread),
            set_point_Pa=1000.0 * self.pressure_kpa,
        )
        pressure, labels_sim, info = scene.render(rng, (0,))
        sensor = self.sensor
        stream = sensor.read_scene(PressureSeries(pressure, protocol.fs_sim_hz), rng)
        labels = labels_sim[:: round(protocol.fs_sim_hz / self.fs_hz)][: stream.shape[1]]
        inside = np.flatnonzero(labels == 0)
        first, last = inside[0], inside[-1] - self.window + 1
        if last < first:
            raise ValueError(f"scan too short for a {self.window}-sample window")
        start = int(rng.integers(first, last + 1))
        info.update(speed_mm_s=speed, start_sample=start)
        return stream[:, start : start + self.window].astype(np.float64), info
