"""Touch-modality task on the PVDF triangle (seed 004, SPEC 2.5 table).

Classes (force N / contact diameter mm, hard body site): light poke 0.2-1.4 / 4; hard poke
20-130 / 5.45; caress 0.2-1.4 / 70; slap 70-170 / 70. Half the samples are on soft body sites,
where the same gesture delivers 3-4x less force. A poke lands at a random point of the triangle
and lasts 80-300 ms (raised-cosine press); a slap is an impact of 15-50 ms; a caress is a 70 mm
contact stroking across the patch at 40-150 mm/s with a 0.25-0.45 s force envelope. Onsets fall
50-150 ms into the 0.5 s window.

Array contract: ``X [N, 12, 2000]`` float32 equivalent charge in pC at 4 kS/s (the PVDF
readout's output). Amplitudes span 5 decades (a caress gives ~0.01 pC, a hard poke ~1 nC).
``difficulty`` scales placement, timing spread and noise; ``amplitude_spread`` scales the force
ranges' width and the soft-site factor.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..scenes.inputs import ContactSeries
from ..sensors.base import noise_scaled
from ..sensors.pvdf import PVDFParams, PVDFTriangle
from .base import register_task
from .trial import TrialTask

MODALITIES = {  # force range (N), contact diameter (mm)
    "light_poke": ((0.2, 1.4), 4.0),
    "hard_poke": ((20.0, 130.0), 5.45),
    "caress": ((0.2, 1.4), 70.0),
    "slap": ((70.0, 170.0), 70.0),
}


@register_task
@dataclass(frozen=True)
class TouchModalityTask(TrialTask):
    """4 classes: light poke, hard poke, caress, slap (soft and hard body sites)."""

    n_samples: int = 800
    duration_s: float = 0.5
    skip: bool = True  # simulate only taxels / time a contact can reach (see PVDFTriangle.read)

    name: ClassVar[str] = "touch"
    task_id: ClassVar[int] = 5
    class_names: ClassVar[tuple[str, ...]] = tuple(MODALITIES)
    units: ClassVar[str] = "pC (equivalent input charge of the PVDF charge amplifier)"

    @property
    def sensor(self) -> PVDFTriangle:
        # a floor keeps the noise-relative skip threshold of the PVDF read meaningful
        return PVDFTriangle(noise_scaled(PVDFParams(), max(self.difficulty, 1e-3)))

    def _render(self, label: int, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
        d, a = self.difficulty, self.amplitude_spread
        sensor = self.sensor
        name = self.class_names[label]
        (f_lo, f_hi), diam = MODALITIES[name]
        mid = np.sqrt(f_lo * f_hi)
        force = mid * (f_hi / f_lo) ** (0.5 * min(a, 1.0) * rng.uniform(-1, 1))
        soft = bool(rng.integers(2)) and a > 0
        if soft:
            force /= rng.uniform(3.0, 4.0)
        fs = sensor.fs_hz
        n = self.window
        t = np.arange(n) / fs
        onset = 0.1 + 0.05 * d * rng.uniform(-1, 1)
        centroid = sensor.taxels_mm.mean(0)
        if name in ("light_poke", "hard_poke", "slap"):
            dur = rng.uniform(0.08, 0.3) if name != "slap" else rng.uniform(0.015, 0.05)
            phase = np.clip((t - onset) / dur, 0.0, 1.0)
            f = force * 0.5 * (1 - np.cos(2 * np.pi * phase)) * (phase < 1)
            spread = 12.0 * d if name != "slap" else 10.0 * d
            center = centroid + spread * rng.uniform(-1, 1, 2)
        else:  # caress: a broad contact stroking across the patch
            dur = rng.uniform(0.25, 0.45)
            phase = np.clip((t - onset) / dur, 0.0, 1.0)
            f = force * np.sin(np.pi * phase) ** 2
            speed = rng.uniform(40.0, 150.0)
            ang = rng.uniform(0, 2 * np.pi)
            path = speed * (t - onset - dur / 2)
            center = centroid + np.stack([np.cos(ang) * path, np.sin(ang) * path], 1)
            center = np.round(center / 0.5) * 0.5  # 0.5 mm steps: far below the 6 mm pitch
        q = sensor.read_scene(ContactSeries(f, center, diam, fs), rng, skip=self.skip)
        return q.astype(np.float64), {"force_N": force, "soft_site": soft, "duration_s": dur}
