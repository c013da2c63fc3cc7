"""TENG finger tasks (seed 000): object stiffness x curvature, and contact material.

``stiffness_curvature``: objects of 3 stiffnesses (soft / medium / hard: the skin takes 30 / 60 /
97 % of an overlap) x 3 curvatures (flat 15 mm indenter, sphere R 25 mm, sphere R 8 mm) indent
the 8-electrode finger (or the Mia 6 / 14 layouts). The order in which electrodes activate and
their timing encode curvature (a flat indenter activates 4 at once, a sharp sphere one or two,
then neighbours), the contact-phase slope relative to the proximity slope encodes stiffness.
Nuisances: contact material and its electrification (an amplitude factor), residual charge,
object placement (+-0.75 mm across, +-2 mm along), approach speed (+-10 %), target force
(15 N +-15 %; force control, so softer and sharper objects travel further).

``material``: the 15 mm flat indenter covered with aluminium, Kapton, paper, glass or cloth
presses the finger at ~4.65 then ~9.3 mm/s to 10-70 N. Materials differ in surface charge and
its relaxation; as in the seed, they differ at low speed and converge at high speed, so the
change of response with speed identifies them. Nuisances: speeds (+-10 %), force, placement,
per-contact charge (CV ~0.7), earlier contacts (0-60).

Array contract: ``X [N, electrodes, window]`` float32 gate potentials V_T in volts at 500 S/s.
``difficulty`` scales placement / speed / depth spread and the noise; ``amplitude_spread`` scales
the amplitude nuisances (material charge factor spread, electrification, force range).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from ..scenes.indentation import IndentationScene
from ..scenes.inputs import GapSeries
from ..sensors.base import noise_scaled
from ..sensors.teng import MATERIALS, TENGArray, TENGParams, layout
from .base import register_task
from .trial import TrialTask


def teng_sensor(layout_name: str, difficulty: float) -> TENGArray:
    """The seed's TENG array on a named layout, gate noise scaled by ``difficulty``."""
    return TENGArray(layout(layout_name), noise_scaled(TENGParams(), difficulty))


STIFFNESS = {"soft": 0.3, "medium": 0.6, "hard": 0.97}  # skin's share of an overlap
CURVATURE_MM = {"flat": np.inf, "round": 25.0, "sharp": 8.0}  # object radius of curvature


@register_task
@dataclass(frozen=True)
class StiffnessCurvatureTask(TrialTask):
    """9 classes: ``<stiffness>-<curvature>``; 1 s trials of V_T on a TENG finger array."""

    layout_name: str = "finger8"
    duration_s: float = 1.0
    material: str = "kapton"  # printed-plastic objects
    force_N: float = 15.0  # force-controlled press (+-15 % x difficulty)

    name = "stiffness_curvature"
    task_id = 3
    class_names = tuple(f"{s}-{c}" for s in STIFFNESS for c in CURVATURE_MM)
    units = "V (TENG gate potential V_T)"

    @property
    def sensor(self) -> TENGArray:
        return teng_sensor(self.layout_name, self.difficulty)

    def _render(self, label: int, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
        d, a = self.difficulty, self.amplitude_spread
        stiff = list(STIFFNESS)[label // len(CURVATURE_MM)]
        curv = list(CURVATURE_MM)[label % len(CURVATURE_MM)]
        sensor = self.sensor
        pos = sensor.positions_mm
        y_mid = 0.5 * (pos[:, 1].min() + pos[:, 1].max())
        scene = IndentationScene(
            radius_mm=CURVATURE_MM[curv],
            center_mm=(0.75 * d * rng.uniform(-1, 1), y_mid + 2.0 * d * rng.uniform(-1, 1)),
            speed_mm_s=9.3 * (1 + 0.1 * d * rng.uniform(-1, 1)),
            pre_s=0.05 + 0.05 * rng.uniform(),
        )
        # force control: stop at the target force, so softer / sharper objects travel further
        force = self.force_N * (1 + 0.15 * d * rng.uniform(-1, 1))
        k_skin = sensor.params.skin_kPa_per_mm * 1e-3  # N/mm^2 per mm of indentation
        scene = replace(scene, depth_mm=scene.depth_for_force(force, k_skin, STIFFNESS[stiff]))
        gap, t_contact = scene.render(sensor.pad_points(), self.fs_hz, self.window)
        contacts = int(rng.integers(0, 1 + round(60 * a)))
        charge = np.exp(0.6 * a * rng.standard_normal())  # humidity, charge history (CV ~0.7)
        v = charge * sensor.read_scene(
            GapSeries(gap, self.material, contacts, STIFFNESS[stiff]), rng
        )
        return v, {"t_contact_s": t_contact, "contacts": contacts, "charge": charge}


@register_task
@dataclass(frozen=True)
class MaterialTask(TrialTask):
    """5 classes (SPEC 2.2 materials): a slow and a fast press of the flat 15 mm indenter.

    Seed 000's material protocol presses each material at speeds from 4.65 to 9.3 mm/s: peak
    voltages differ between materials at low speed and converge at high speed. One sample is
    that comparison: a press at ~4.65 mm/s then one at ~9.3 mm/s (each +-10 % x difficulty, to
    10-70 N), 3 s of V_T. The per-contact charge varies (CV ~0.7: humidity, charge history), so
    single peak amplitudes are unreliable; how the response changes with speed is not.
    """

    duration_s: float = 3.0
    speeds_mm_s: tuple[float, float] = (4.65, 9.3)
    force_range_N: tuple[float, float] = (10.0, 70.0)

    name: ClassVar[str] = "material"
    task_id: ClassVar[int] = 4
    class_names: ClassVar[tuple[str, ...]] = tuple(MATERIALS)
    units: ClassVar[str] = "V (TENG gate potential V_T)"

    @property
    def sensor(self) -> TENGArray:
        return teng_sensor("finger8", self.difficulty)

    def _render(self, label: int, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
        d, a = self.difficulty, self.amplitude_spread
        sensor = self.sensor
        material = self.class_names[label]
        lo, hi = self.force_range_N
        mid = 0.5 * (lo + hi)
        force = mid + (hi - lo) / 2 * min(a, 1.0) * rng.uniform(-1, 1)
        # flat 15 mm indenter on the skin: 267 kPa/mm x 177 mm^2 = 47 N per mm of indentation
        depth = force / (sensor.params.skin_kPa_per_mm * np.pi * 7.5**2 * 1e-3)
        center = (1.0 * d * rng.uniform(-1, 1), 18.0 + 2.0 * d * rng.uniform(-1, 1))
        contacts = int(rng.integers(0, 1 + round(60 * a)))
        pieces, speeds, start = [], [], 0.05 + 0.05 * rng.uniform()
        for k, nominal in enumerate(self.speeds_mm_s):
            speed = nominal * (1 + 0.1 * d * rng.uniform(-1, 1))
            scene = IndentationScene(center_mm=center, speed_mm_s=speed, depth_mm=depth,
                                     start_gap_mm=2.5, pre_s=start, hold_s=0.15)  # fmt: skip
            cycle_s = start + 2 * (2.5 + depth) / speed + 0.15 + 0.05
            n = self.window - sum(p.shape[-1] for p in pieces) if k else round(cycle_s * self.fs_hz)
            gap, _ = scene.render(sensor.pad_points(), self.fs_hz, n)
            pieces.append(gap)
            speeds.append(speed)
            start = 0.0
        gap = np.concatenate(pieces, axis=-1)
        charge = np.exp(0.6 * a * rng.standard_normal())  # humidity, charge history (CV ~0.7)
        v = charge * sensor.read_scene(GapSeries(gap, material, contacts), rng)
        return v, {"speeds_mm_s": speeds, "force_N": force, "contacts": contacts}
