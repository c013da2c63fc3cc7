"""Contact localisation on the CMOS piezoresistive chip array (seed 002, SPEC 2.3).

A press with a normal force and a tangential (friction-limited) force lands somewhere on the
5 x 5 chip array (:class:`~tactilesnn.datasets_synth.sensors.piezoresistive.ChipArray`, 7.46 mm pitch);
the chips read the in-plane stress below it (:func:`contact_stress`: Boussinesq + Cerruti at
Poisson ratio 0.5, 1 mm deep). ``target="position"``: the class is the cell of a ``cells x cells``
grid over the inner region (1.5 pitches either side of the centre, 22.4 mm square) where the
contact lands; ``"direction"``: the class is the sector (8 x 45 degrees, ``E`` = +x) the
tangential force points to. Each class's samples are drawn uniformly inside its cell / sector, so
the errors in mm and degrees (``info``: ``center_mm``, ``angle_deg``, forces) can be measured
against the continuous truth; :func:`solve_contact` is the seed's least-squares reference.

Time course: the normal force ramps up (raised cosine, 0.1-0.2 s) 0.1-0.3 s into a 1 s window and
holds; the tangential force follows it at a friction ratio of 0.1-0.6. Forces 2-12 N. Readout: gain
100 (6.5 kPa per LSB), seed 002's noise; 60 frames/s with one frame of latency.

Array contract: ``X [N, 100, 60]`` float32 ``drho/rho`` of the 4 resistors (0, 45, 90, 135 degrees)
of each of the 25 chips (channel ``chip<k>_<angle>``), 60 frames/s. ``difficulty`` scales the
noise and the spread of force, friction and timing.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..scenes.inputs import StressSeries
from ..sensors.piezoresistive import (
    ANGLES_DEG,
    ChipArray,
    ChipArrayParams,
    chip_positions,
    contact_stress,
)
from .base import register_task
from .trial import TrialTask

SECTORS = ("E", "NE", "N", "NW", "W", "SW", "S", "SE")
PITCH_MM = 1.46 + 6.0
SIM_HZ = 600.0


@register_task
@dataclass(frozen=True)
class ContactLocalisationTask(TrialTask):
    """Where a press lands (cells) or where its tangential force points (8 sectors) on the
    5 x 5 piezoresistive chip array; ``X [N, 100, 60]`` drho/rho at 60 frames/s."""

    n_samples: int = 1200
    target: str = "position"
    cells: int = 3
    duration_s: float = 1.0
    extent_mm: float = 1.5 * PITCH_MM
    depth_mm: float = 1.0
    force_lo_N: float = 2.0
    force_hi_N: float = 12.0
    friction_lo: float = 0.1
    friction_hi: float = 0.6

    name: ClassVar[str] = "localise"
    task_id: ClassVar[int] = 7
    units: ClassVar[str] = "drho/rho (relative resistance change of each chip resistor)"

    def __post_init__(self) -> None:
        if self.target not in ("position", "direction"):
            raise ValueError(f"target must be 'position' or 'direction', got {self.target!r}")
        if not isinstance(self.cells, int) or not 2 <= self.cells <= 8:
            raise ValueError(f"cells must be an integer 2..8, got {self.cells!r}")
        if not 0 < self.extent_mm <= 2 * PITCH_MM:
            raise ValueError(f"extent_mm must be in (0, {2 * PITCH_MM}] (the chips' span)")
        if not 0 < self.force_lo_N <= self.force_hi_N:
            raise ValueError("forces must satisfy 0 < force_lo_N <= force_hi_N")
        if not 0 <= self.friction_lo <= self.friction_hi:
            raise ValueError("friction ratios must satisfy 0 <= friction_lo <= friction_hi")
        if self.target == "direction" and self.friction_lo <= 0:
            raise ValueError("the direction target needs a tangential force: friction_lo > 0")
        super().__post_init__()

    @property
    def class_names(self) -> tuple[str, ...]:  # type: ignore[override]
        if self.target == "direction":
            return SECTORS
        return tuple(f"x{i}y{j}" for j in range(self.cells) for i in range(self.cells))

    @property
    def sensor(self) -> ChipArray:
        base = ChipArrayParams(gain=100.0)
        noise = base.noise_nV_rtHz * max(self.difficulty, 1e-3)
        return ChipArray(dataclasses.replace(base, noise_nV_rtHz=noise))

    @property
    def fs_hz(self) -> float:
        return ChipArrayParams().frame_hz

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(f"chip{k}_{a:g}" for k in range(25) for a in ANGLES_DEG)

    def cell_center_mm(self, label: int) -> np.ndarray:
        """Centre (mm) of position class ``label``'s cell."""
        size = 2 * self.extent_mm / self.cells
        i, j = label % self.cells, label // self.cells
        return np.array([-self.extent_mm + (i + 0.5) * size, -self.extent_mm + (j + 0.5) * size])

    def _render(self, label: int, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
        d = self.difficulty
        if self.target == "position":
            size = 2 * self.extent_mm / self.cells
            center = self.cell_center_mm(label) + size * rng.uniform(-0.5, 0.5, 2)
            angle = rng.uniform(-180.0, 180.0)
        else:
            center = rng.uniform(-self.extent_mm, self.extent_mm, 2)
            angle = 45.0 * label + rng.uniform(-22.5, 22.5)
        mid_f = np.sqrt(self.force_lo_N * self.force_hi_N)
        force = mid_f * (self.force_hi_N / self.force_lo_N) ** (
            0.5 * min(d, 1.0) * rng.uniform(-1, 1)
        )
        mid_mu = 0.5 * (self.friction_lo + self.friction_hi)
        mu = mid_mu + 0.5 * (self.friction_hi - self.friction_lo) * min(d, 1.0) * rng.uniform(-1, 1)
        shear = mu * force * np.array([np.cos(np.deg2rad(angle)), np.sin(np.deg2rad(angle))])
        sigma, lam = contact_stress(force, center, chip_positions(), self.depth_mm, shear)
        n = round(self.duration_s * SIM_HZ)
        t = np.arange(n) / SIM_HZ
        onset = 0.2 + 0.1 * min(d, 1.0) * rng.uniform(-1, 1)
        ramp = 0.15 + 0.05 * min(d, 1.0) * rng.uniform(-1, 1)
        phase = np.clip((t - onset) / ramp, 0.0, 1.0)
        env = 0.5 * (1 - np.cos(np.pi * phase))
        stress = StressSeries(env[:, None] * sigma[None], np.broadcast_to(lam, (n, 25)), SIM_HZ)
        x = self.sensor.read_scene(stress, rng).astype(np.float64)  # [100 chip-resistors, frames]
        info = {"center_mm": center.tolist(), "angle_deg": float(angle), "force_N": float(force),
                "shear_N": shear.tolist()}  # fmt: skip
        return x, info
