"""Indentation scene: an object pressed into a curved fingertip carrying an electrode array.

Array contract of :meth:`IndentationScene.render`: electrode positions ``[channels, 2]`` (mm; x
across, y along the finger) -> ``gap_mm [channels, samples]`` at ``fs_hz`` (object surface minus
skin surface at each electrode; > 0 = proximity, < 0 = overlap), plus the time of first contact.

Geometry: the finger is a cylinder of radius ``finger_radius_mm`` about its long (y) axis, so an
electrode at x sits ``x^2 / (2 R_f)`` below the crest. The object is a spherical cap of radius
``radius_mm`` (paraboloid near its apex) or, for ``radius_mm = inf``, a flat disc of
``diameter_mm`` with a 1 mm edge round; it moves along -z at ``speed_mm_s`` from ``start_gap_mm``
above first contact to ``depth_mm`` of overlap, holds, and retracts at the same speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.checks import check_positive


@dataclass(frozen=True)
class IndentationScene:
    """One approach-hold-retract cycle; lengths in mm, times in s, speeds in mm/s."""

    radius_mm: float = np.inf  # curvature radius of the object (inf = flat indenter)
    diameter_mm: float = 15.0  # flat indenter diameter (seed 000: 15 mm)
    center_mm: tuple[float, float] = (0.0, 18.0)
    speed_mm_s: float = 9.3
    start_gap_mm: float = 3.0
    depth_mm: float = 1.2
    pre_s: float = 0.05
    hold_s: float = 0.25
    finger_radius_mm: float = 9.0
    edge_round_mm: float = 1.0

    def __post_init__(self) -> None:
        for name in ("radius_mm", "diameter_mm", "speed_mm_s", "start_gap_mm", "finger_radius_mm",
                     "edge_round_mm"):  # fmt: skip
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.depth_mm < 0 or self.pre_s < 0 or self.hold_s < 0:
            raise ValueError("depth_mm, pre_s and hold_s must be >= 0")

    def surface_mm(self, xy_mm: np.ndarray) -> np.ndarray:
        """Height of the object's surface above its apex plane at points ``[P, 2]`` (mm)."""
        rho = np.hypot(xy_mm[..., 0] - self.center_mm[0], xy_mm[..., 1] - self.center_mm[1])
        if np.isinf(self.radius_mm):
            out = np.maximum(rho - self.diameter_mm / 2, 0.0)
            return out**2 / (2 * self.edge_round_mm)
        r = self.radius_mm
        return np.where(rho < r, r - np.sqrt(np.maximum(r * r - rho * rho, 0.0)), r + (rho - r))

    def finger_mm(self, xy_mm: np.ndarray) -> np.ndarray:
        """Height of the skin surface (crest = 0) at points ``[P, 2]`` (mm)."""
        return -(xy_mm[..., 0] ** 2) / (2 * self.finger_radius_mm)

    def height_mm(self, fs_hz: float, n: int) -> tuple[np.ndarray, float]:
        """Object height above first contact ``[n]`` (mm) and the first-contact time (s)."""
        check_positive(fs_hz, "fs_hz")
        t = np.arange(n) / fs_hz
        t_contact = self.pre_s + self.start_gap_mm / self.speed_mm_s
        t_bottom = t_contact + self.depth_mm / self.speed_mm_s
        t_up = t_bottom + self.hold_s
        h = np.where(
            t < self.pre_s,
            self.start_gap_mm,
            self.start_gap_mm - self.speed_mm_s * (t - self.pre_s),
        )
        h = np.maximum(h, -self.depth_mm)
        h = np.where(t > t_up, -self.depth_mm + self.speed_mm_s * (t - t_up), h)
        return np.minimum(h, self.start_gap_mm), t_contact

    def _offset_and_grid(self) -> tuple[float, np.ndarray, float]:
        gx, gy = np.meshgrid(np.arange(-8, 8.01, 0.25), np.arange(0, 50.01, 0.25))
        grid = np.stack([gx.ravel(), gy.ravel()], 1)
        rest = self.surface_mm(grid) - self.finger_mm(grid)
        return float(rest.min()), rest - rest.min(), 0.25**2

    def depth_for_force(self, force_N: float, skin_N_per_mm3: float, skin_share: float) -> float:
        """Overlap depth (mm) at which the contact carries ``force_N`` (force control).

        Winkler skin: pressure ``skin_N_per_mm3 * skin_share * overlap`` at each point of the
        fingertip (0.25 mm grid), summed over the contact; solved by bisection.
        """
        check_positive(force_N, "force_N")
        _, rest, cell = self._offset_and_grid()
        k = skin_N_per_mm3 * skin_share * cell

        def force(depth: float) -> float:
            return k * float(np.maximum(depth - rest, 0.0).sum())

        lo, hi = 0.0, 1.0
        while force(hi) < force_N:
            hi *= 2
            if hi > 100:
                raise ValueError(f"{force_N} N is out of reach of this contact geometry")
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if force(mid) < force_N else (lo, mid)
        return 0.5 * (lo + hi)

    def render(self, positions_mm: np.ndarray, fs_hz: float, n: int) -> tuple[np.ndarray, float]:
        """Gaps ``[*points, n]`` (mm) and first-contact time (s) for points ``[*points, 2]``."""
        pos = np.asarray(positions_mm, dtype=np.float64)
        # first contact: the lowest object-minus-skin gap over the fingertip (0.25 mm grid)
        offset = self._offset_and_grid()[0]
        static = self.surface_mm(pos) - self.finger_mm(pos) - offset  # >= 0 at rest
        h, t_contact = self.height_mm(fs_hz, n)
        return static[..., None] + h, t_contact
