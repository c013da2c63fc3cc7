"""iCub capacitive fingertip (seed 003 technology, SPEC 2.4) pressed on a surface with relief.

Array contract of :meth:`CapacitiveFingertip.read`: raised features (dots) of a surface under
the fingertip (``bumps_mm [frames, k, 2]`` centres in the fingertip's frame, one height and base
diameter) and the normal force per frame (``force_N [frames]``) -> ``counts [12, frames]``
float64: the iCub skin's 8-bit taxel values (0..255, 0 = the pad's calibrated rest), one frame
per CDC sweep.

Physics, per frame:

* The fingertip is a curved pad (radii ``radius_along_mm`` / ``radius_across_mm``: height
  ``h(u) = u_x^2 / 2 R_x + u_y^2 / 2 R_y`` above its lowest point ``contact_mm``) covered by a soft
  dielectric layer ``foam_mm`` thick under a thin outer cover. Pressed by ``force_N`` onto the
  surface, each point of the foam is compressed by ``c(u) = max(delta - h(u) + relief(u), 0)`` (a
  Winkler foundation: the foam acts as independent columns). The cover drapes over a dot: the
  relief it passes on is a raised-cosine bump of the dot's height over the dot's radius plus
  ``cover_spread_mm`` (0: the bare spherical cap). The strain ``s = c / foam_mm`` (capped below
  ``strain_max``) needs the pressure of the foam's saturating law inverted,
  ``p = p_half s / (s_max - s)`` (the law of :class:`CapacitiveTriangle`: ``s = s_max p / (p +
  p_half)``); the approach ``delta`` balances ``sum p dA = force_N`` (bisection, per frame).
* Each pad (``pad_diameter_mm``) is a parallel plate over the compressed foam: its capacitance is
  the area-weighted sum of ``eps_r(s) eps0 dA / (x0 (1 - s))`` over sub-points of the pad
  (:meth:`CapacitiveTriangle.capacitance_pF` per sub-point), plus the routing's parasitic.
* The 16-bit CDC (AD7147-like, :meth:`CapacitiveTriangle.cdc_code`) converts it; CDC noise
  ``noise_lsb`` rms.
* The iCub readout: ``counts = clip(round(gain (code - rest) / 2^shift_bits + offset), 0, 255)``,
  ``rest`` the pad's unloaded code (the skin's calibration at start-up, fingertip in the air),
  plus readout noise ``noise_counts`` rms.
  Per-taxel ``gain`` and ``offset`` (manufacturing spread, calibration error) are given by the
  caller (a task draws them); a value below the calibrated rest reads 0, as on the robot.

The taxel layout (:func:`icub_fingertip_layout`) is a planar projection of the 12 pads of the
fingertip's flexible PCB (approximate: 3 rows x 4 columns, staggered, 3.5 mm pitch); the real
fingertip is curved about both axes, which the height ``h(u)`` models. ``pads_mm`` (12 centres,
in the output's channel order) replaces it: the layout and channel map a calibration fits
(:mod:`~tactilesnn.datasets_synth.calibration`).

The finger's mount (defaults: rigid, the position control above). A robot finger sits on a
compliant joint: ``mount_N_per_mm`` (normal stiffness, N/mm; inf = rigid) lets a dot lift the
fingertip (the approach solves ``F_foam(delta) + k delta = F_set + k delta_flat``, ``delta_flat``
the approach on the flat surface at the set force), so the taxels beside the dot unload; and
``tilt_Nmm_per_rad`` (rotational stiffness about the axis across the slide, N mm/rad; inf =
none) lets the dot's moment about the contact point roll it: ``theta = M_dot / k_theta``, the
fingertip's height then ``h(u) + theta (u_x - contact_x)`` (first order: the moment is the
rigid solve's). Together they give the dip of the unloaded taxels the real iCub file shows as a
letter passes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ...core.checks import as_float_array, check_finite, check_positive
from ..scenes.inputs import FingertipPress
from .base import check_scene, register_sensor
from .capacitive_triangle import CapacitiveTriangle, CapacitiveTriangleParams
from .pvdf import disc_points


def icub_fingertip_layout(pitch_mm: float = 3.5) -> np.ndarray:
    """12 pad centres ``[12, 2]`` (mm; x along the fingertip's long axis, y across), centroid 0:
    3 rows of 4, the middle row shifted by half a pitch (the fingertip PCB's staggered pads)."""
    pts = []
    for row, shift in zip((-1, 0, 1), (0.0, 0.5, 0.0), strict=True):
        for col in range(4):
            pts.append(((col - 1.5 + shift) * pitch_mm, row * pitch_mm * np.sqrt(3) / 2))
    xy = np.array(pts)
    return xy - xy.mean(0)


@dataclass(frozen=True)
class FingertipParams:
    """Fingertip geometry, foam and readout (lengths mm, pressures Pa, force N)."""

    pad_diameter_mm: float = 3.0
    pitch_mm: float = 3.5
    radius_along_mm: float = 9.0  # fingertip curvature along its long axis
    radius_across_mm: float = 6.5  # ... and across it (the fingertip is ~14.5 mm wide)
    foam_mm: float = 3.0  # soft dielectric layer (SPEC 2.4: silicone foam 3 mm)
    gap_um: float = 100.0  # dielectric thickness at rest (the triangle module's value)
    eps_r: float = 3.0
    eps_r_gain: float = 2.0
    strain_max: float = 0.7
    p_half_Pa: float = 50e3
    parasitic_pF: float = 2.0
    noise_lsb: float = 4.0  # CDC rms noise at the fastest stage
    shift_bits: int = 6  # 16-bit code -> 8-bit taxel value
    # readout noise (counts rms) beyond the CDC's: the real iCub file's first differences at rest
    # have an sd of ~1 count on pressed taxels (1 / sqrt 2 per sample)
    noise_counts: float = 0.7
    grid_mm: float = 0.25  # quadrature step of the force balance
    pad_rings: int = 3  # sub-point rings per pad (disc quadrature)
    cover_spread_mm: float = 1.5  # how far the outer cover's drape over a dot reaches beyond it
    mount_N_per_mm: float = np.inf  # the finger joint's normal stiffness (inf: rigid)
    tilt_Nmm_per_rad: float = np.inf  # ... and its rotational stiffness across the slide
    #: the pad centres ``((x, y), ...)`` (mm) in channel order; None: :func:`icub_fingertip_layout`
    pads_mm: tuple[tuple[float, float], ...] | None = None

    def __post_init__(self) -> None:
        for name in ("pad_diameter_mm", "pitch_mm", "radius_along_mm", "radius_across_mm",
                     "foam_mm", "gap_um", "p_half_Pa", "grid_mm"):  # fmt: skip
            check_positive(getattr(self, name), name)
        if not 0 < self.strain_max < 1:
            raise ValueError(f"strain_max must be in (0, 1), got {self.strain_max}")
        if not (np.isfinite(self.cover_spread_mm) and self.cover_spread_mm >= 0):
            raise ValueError(
                f"cover_spread_mm must be a finite number >= 0, got {self.cover_spread_mm}"
            )
        if not 0 <= self.shift_bits <= 8:
            raise ValueError(f"shift_bits must be 0..8, got {self.shift_bits}")
        # a fit file sets these: bounded, so that a hostile one cannot ask for a grid of
        # billions of points (the force balance holds [frames, grid] arrays)
        if not 0.05 <= self.grid_mm <= 2.0:
            raise ValueError(f"grid_mm must be in [0.05, 2] mm, got {self.grid_mm}")
        if not (isinstance(self.pad_rings, int) and 1 <= self.pad_rings <= 12):
            raise ValueError(f"pad_rings must be an integer in 1..12, got {self.pad_rings}")
        for name in ("mount_N_per_mm", "tilt_Nmm_per_rad"):
            v = getattr(self, name)
            if not (v > 0) or np.isnan(v):  # inf allowed: rigid
                raise ValueError(f"{name} must be > 0 (inf: rigid), got {v}")
        if self.pads_mm is not None:
            pads = np.asarray(self.pads_mm, np.float64)
            if pads.shape != (12, 2) or not np.isfinite(pads).all():
                raise ValueError(f"pads_mm must be 12 finite (x, y) centres, got {pads.shape}")

    def triangle_params(self) -> CapacitiveTriangleParams:
        """The same pad, foam and CDC as a :class:`CapacitiveTriangleParams` (shared physics)."""
        return CapacitiveTriangleParams(
            pad_diameter_mm=self.pad_diameter_mm, gap_um=self.gap_um, eps_r=self.eps_r,
            eps_r_gain=self.eps_r_gain, strain_max=self.strain_max, p_half_Pa=self.p_half_Pa,
            parasitic_pF=self.parasitic_pF, noise_lsb=self.noise_lsb, hysteresis=0.0,
        )  # fmt: skip


@register_sensor("capacitive_fingertip")
class CapacitiveFingertip:
    """Twelve capacitive pads on a curved fingertip under a soft foam, read as iCub counts."""

    units: ClassVar[str] = "iCub counts (0..255)"
    scene_type: ClassVar[type] = FingertipPress

    def output_rate_hz(self, scene: FingertipPress) -> float:
        return float(scene.fs_frames_hz)

    def read_scene(
        self, scene: FingertipPress, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        """The :class:`~..sensors.base.SensorModel` form of :meth:`read`."""
        check_scene(self, scene)
        return self.read(scene.force_N, scene.bumps_mm, scene.bump_height_mm, scene.bump_diameter_mm,
                         scene.contact_mm, scene.gain, scene.offset_counts, rng,
                         scene.position_control)  # fmt: skip

    n_channels = 12

    def __init__(self, params: FingertipParams | None = None) -> None:
        self.params = params or FingertipParams()
        p = self.params
        self.taxels_mm = (
            icub_fingertip_layout(p.pitch_mm) if p.pads_mm is None
            else np.asarray(p.pads_mm, np.float64)
        )  # fmt: skip
        self._cap = CapacitiveTriangle(p.triangle_params())
        self._pad_offsets, self._pad_w = disc_points(p.pad_diameter_mm, p.pad_rings)
        self.pad_points_mm = self.pad_points(self.taxels_mm)  # [12*Q, 2]
        self._n_sub = self._pad_offsets.shape[0]
        self.last_force_N = np.zeros(0)  # the contact force of the last read, per frame (N)

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(f"taxel{i}" for i in range(self.n_channels))

    def contact_grid(self, contact_mm: np.ndarray, relief_max_mm: float) -> np.ndarray:
        """Quadrature points ``[G, 2]`` (mm) covering every point the foam can touch: where the
        fingertip's height is below the deepest possible approach (foam fully compressed plus
        the highest relief)."""
        p = self.params
        reach = p.foam_mm * p.strain_max + relief_max_mm
        ax, ay = np.sqrt(2 * p.radius_along_mm * reach), np.sqrt(2 * p.radius_across_mm * reach)
        gx = np.arange(-ax, ax + p.grid_mm / 2, p.grid_mm)
        gy = np.arange(-ay, ay + p.grid_mm / 2, p.grid_mm)
        u = np.stack(np.meshgrid(gx, gy, indexing="ij"), -1).reshape(-1, 2)
        keep = u[:, 0] ** 2 / ax**2 + u[:, 1] ** 2 / ay**2 <= 1.0
        return u[keep] + np.asarray(contact_mm, np.float64)

    def height_mm(self, points_mm: np.ndarray, contact_mm: np.ndarray) -> np.ndarray:
        """The fingertip surface's height (mm) above its lowest point ``contact_mm``."""
        p = self.params
        d = np.asarray(points_mm, np.float64) - np.asarray(contact_mm, np.float64)
        return d[..., 0] ** 2 / (2 * p.radius_along_mm) + d[..., 1] ** 2 / (2 * p.radius_across_mm)

    def relief_mm(self, points_mm: np.ndarray, bumps_mm: np.ndarray, height_mm: float,
                  diameter_mm: float) -> np.ndarray:  # fmt: skip
        """Relief (mm) the foam feels ``[frames, P]`` at ``points_mm [P, 2]`` from dots centred at
        ``bumps_mm [frames, k, 2]``: each a spherical cap (``cover_spread_mm`` = 0) or the cover's
        raised-cosine drape over it; overlapping drapes take the higher.

        A dot's shape is evaluated only in the frames where it is within reach of some point
        (the points' bounding box closer than the drape's or the cap's sphere's radius); in the
        others every point sits at the shape's far value, the same number the formula gives
        there (a slide's dots pass under the fingertip in a fraction of its frames)."""
        a = diameter_mm / 2
        spread = self.params.cover_spread_mm
        if spread > 0:
            reach = a + spread

            def shape(r: np.ndarray) -> np.ndarray:
                return height_mm * np.cos(0.5 * np.pi * np.minimum(r / reach, 1.0)) ** 2
        else:
            radius = (a * a + height_mm**2) / (2 * height_mm)
            reach = radius  # beyond the sphere's radius the cap is exactly 0

            def shape(r: np.ndarray) -> np.ndarray:
                return np.maximum(
                    np.sqrt(np.maximum(radius**2 - r**2, 0.0)) - (radius - height_mm), 0.0
                )

        lo, hi = points_mm.min(0), points_mm.max(0)
        far = shape(np.full(1, 2.0 * reach))[0] if bumps_mm.shape[1] else 0.0  # out of reach
        out = np.full((bumps_mm.shape[0], points_mm.shape[0]), far)
        for k in range(bumps_mm.shape[1]):
            b = bumps_mm[:, k]
            gap = np.maximum(np.maximum(lo - b, b - hi), 0.0)  # [frames, 2] to the box
            near = np.flatnonzero((gap * gap).sum(1) < reach * reach)
            dx = points_mm[None, :, 0] - b[near, 0, None]
            dy = points_mm[None, :, 1] - b[near, 1, None]
            r = np.sqrt(dx * dx + dy * dy)  # (no [frames, P, 2] temporary, as norm makes)
            out[near] = np.maximum(out[near], shape(r))
        return out

    def pressure_Pa(self, strain: np.ndarray) -> np.ndarray:
        """The foam's pressure at a strain: the saturating law inverted (strain < strain_max)."""
        p = self.params
        return p.p_half_Pa * strain / (p.strain_max - strain)

    def _strain(self, delta: np.ndarray, height: np.ndarray, relief: np.ndarray) -> np.ndarray:
        """Foam strain ``[frames, G]`` at approach ``delta [frames]`` over heights ``[G]`` or
        ``[frames, G]`` (a rolled fingertip) and relief ``[frames, G]`` (mm)."""
        p = self.params
        c = np.maximum(delta[:, None] - height + relief, 0.0)
        return np.minimum(c / p.foam_mm, p.strain_max * (1 - 1e-6))

    def pad_points(self, centres_mm: np.ndarray) -> np.ndarray:
        """The quadrature sub-points ``[P * Q, 2]`` (mm) of pads centred at ``centres_mm [P, 2]``."""
        c = np.asarray(centres_mm, np.float64)
        return (c[:, None, :] + self._pad_offsets[None]).reshape(-1, 2)

    def _foam_force(self, delta: np.ndarray, height: np.ndarray, relief: np.ndarray) -> np.ndarray:
        return (
            self.pressure_Pa(self._strain(delta, height, relief)).sum(1)
            * self.params.grid_mm**2
            * 1e-6
        )

    def approach_mm(
        self, force_N: np.ndarray, grid_mm: np.ndarray, height: np.ndarray, relief: np.ndarray
    ) -> np.ndarray:
        """The approach ``delta [frames]`` (mm) at which the foam carries ``force_N``
        (bisection to 1e-6 mm; the force grows monotonically with ``delta``)."""
        p = self.params
        lo = np.zeros(force_N.size)
        hi = np.full(force_N.size, p.foam_mm * p.strain_max + float(relief.max(initial=0.0)))
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            low = self._foam_force(mid, height, relief) < force_N
            lo, hi = np.where(low, mid, lo), np.where(low, hi, mid)
        return 0.5 * (lo + hi)

    def flat_approach_mm(self, force_N: np.ndarray, height: np.ndarray) -> np.ndarray:
        """:meth:`approach_mm` on the flat surface (no relief: one force law for every frame):
        the law tabulated once, inverted by interpolation, then polished by Newton steps (the
        same root to ~1e-9 mm at a tenth of the bisection's cost)."""
        p = self.params
        grid = np.linspace(0.0, p.foam_mm * p.strain_max, 513)
        law = self._foam_force(grid, height, np.zeros((1, height.size)))
        f = np.asarray(force_N, np.float64)
        d = np.interp(f, law, grid)  # beyond what the foam carries: fully compressed, as bisected
        step = grid[1] * 1e-3
        for _ in range(3):
            here = self._foam_force(d, height, np.zeros((1, height.size)))
            slope = (self._foam_force(d + step, height, np.zeros((1, height.size))) - here) / step
            d = np.clip(d - (here - f) / np.maximum(slope, 1e-12), 0.0, grid[-1])
        return d

    def contact_state(
        self,
        force_N: np.ndarray,
        bumps_mm: np.ndarray,
        bump_height_mm: float,
        bump_diameter_mm: float,
        contact_mm: np.ndarray,
        position_control: bool = True,
    ) -> dict[str, np.ndarray]:
        """The fingertip's pose per frame: ``delta`` (approach, mm), ``theta`` (roll, rad),
        ``load_N`` (the foam's force) and what :meth:`codes_at` needs to read pads."""
        p = self.params
        shape = (bump_height_mm, bump_diameter_mm)
        grid = self.contact_grid(contact_mm, bump_height_mm)
        height = self.height_mm(grid, contact_mm)
        relief = self.relief_mm(grid, bumps_mm, *shape)
        n = force_N.size
        theta = np.zeros(n)
        if position_control:
            delta = self.flat_approach_mm(force_N, height)
            touched = relief.max(1) > 0
            rigid = np.isinf(p.mount_N_per_mm) and np.isinf(p.tilt_Nmm_per_rad)
            if touched.any() and not rigid:
                lever = grid[:, 0] - float(np.asarray(contact_mm)[0])  # mm from the contact point
                r, h = relief[touched], height[None, :]
                if np.isfinite(p.tilt_Nmm_per_rad):
                    da = p.grid_mm**2 * 1e-6
                    press = self.pressure_Pa(self._strain(delta[touched], height, r)) * da
                    flat = self.pressure_Pa(self._strain(delta[touched], height, 0 * r)) * da
                    theta[touched] = ((press - flat) @ lever) / p.tilt_Nmm_per_rad
                    h = height[None, :] + theta[touched, None] * lever[None, :]
                if np.isfinite(p.mount_N_per_mm):
                    k, ref = p.mount_N_per_mm, delta[touched]
                    target = force_N[touched] + k * ref
                    lo, hi = ref - p.foam_mm * p.strain_max - bump_height_mm, ref.copy()
                    for _ in range(24):  # F_foam(d) + k d grows with d: bisection to ~0.2 um
                        mid = 0.5 * (lo + hi)
                        low = self._foam_force(mid, h, r) + k * mid < target
                        lo, hi = np.where(low, mid, lo), np.where(low, hi, mid)
                    delta[touched] = 0.5 * (lo + hi)
        else:
            delta = self.approach_mm(force_N, grid, height, relief)
        rolled = height[None, :] + theta[:, None] * (grid[:, 0] - contact_mm[0])
        load = self._foam_force(delta, rolled, relief)
        return {"delta": delta, "theta": theta, "load_N": load, "bumps": bumps_mm,
                "shape": np.array(shape), "contact": np.asarray(contact_mm, np.float64)}  # fmt: skip

    def capacitance_field_pF(
        self, points_mm: np.ndarray, state: dict[str, np.ndarray]
    ) -> np.ndarray:
        """The capacitance a unit pad would have at each of ``points_mm [P, 2]`` (mm) above its
        parasitic ``[frames, P]`` (pF) in the pose :meth:`contact_state` found: a pad's is the
        area-weighted mean of this over its surface."""
        p = self.params
        contact = state["contact"]
        height = self.height_mm(points_mm, contact)[None, :] + state["theta"][:, None] * (
            points_mm[:, 0] - contact[0]
        )
        relief = self.relief_mm(points_mm, state["bumps"], *state["shape"])
        s = self._strain(state["delta"], height, relief)
        return self._cap.capacitance_pF(s) - p.parasitic_pF

    def code_of(self, pad_pF: np.ndarray) -> np.ndarray:
        """CDC code above rest of pads whose capacitance above the parasitic is ``pad_pF``."""
        cap = self._cap
        rest = cap.cdc_code(cap.capacitance_pF(np.zeros(1)))
        return cap.cdc_code(pad_pF + self.params.parasitic_pF) - rest

    def codes_at(self, centres_mm: np.ndarray, state: dict[str, np.ndarray]) -> np.ndarray:
        """Noise-free CDC code above the pad's rest ``[P, frames]`` of pads centred at
        ``centres_mm [P, 2]`` (mm) in the pose :meth:`contact_state` found: the capacitance
        field averaged over each pad's quadrature points."""
        field = self.capacitance_field_pF(self.pad_points(centres_mm), state)
        n_pads = np.asarray(centres_mm).reshape(-1, 2).shape[0]
        return self.code_of((field.reshape(field.shape[0], n_pads, self._n_sub) @ self._pad_w).T)

    def read(
        self,
        force_N: np.ndarray,
        bumps_mm: np.ndarray,
        bump_height_mm: float,
        bump_diameter_mm: float,
        contact_mm: np.ndarray,
        gain: np.ndarray,
        offset_counts: np.ndarray,
        rng: np.random.Generator | None = None,
        position_control: bool = True,
    ) -> np.ndarray:
        """Frames of a press -> ``counts [12, frames]`` (see module doc).

        ``bumps_mm [frames, k, 2]``: the dots' centres (mm, fingertip frame) at each frame (the
        scene moves the surface), ``bump_height_mm`` / ``bump_diameter_mm`` their shape;
        ``contact_mm [2]``: the
        fingertip's lowest point in layout coordinates; ``gain [12]`` (relative) and
        ``offset_counts [12]`` or ``[12, frames]`` (counts, drift included): the readout's
        per-taxel calibration; ``rng``: CDC noise when given.

        ``position_control`` (default, as a robot arm sliding at a set height): ``force_N`` is
        the force on the flat surface, which sets the approach; a dot then compresses the foam
        further and the force rises (``last_force_N`` holds it per frame; the mount's
        compliance, when finite, gives some of it back). Otherwise the force is held (force
        control) and a dot takes load from the rest of the contact.
        """
        p = self.params
        f = as_float_array(force_N, "force_N", ndim=1).astype(np.float64)
        check_finite(f, "force_N")
        if (f <= 0).any():
            raise ValueError("force_N must be > 0 N in every frame (the fingertip is pressed)")
        gain = as_float_array(gain, "gain", ndim=1).astype(np.float64)
        if gain.shape != (self.n_channels,):
            raise ValueError(f"gain must be [{self.n_channels}], got {gain.shape}")
        bumps = as_float_array(bumps_mm, "bumps_mm", ndim=3).astype(np.float64)
        if bumps.shape[0] != f.size or bumps.shape[2] != 2:
            raise ValueError(f"bumps_mm must be [frames={f.size}, k, 2], got {bumps.shape}")
        check_finite(bumps, "bumps_mm")
        check_positive(bump_height_mm, "bump_height_mm")
        check_positive(bump_diameter_mm, "bump_diameter_mm")
        contact = np.asarray(contact_mm, np.float64)
        state = self.contact_state(f, bumps, bump_height_mm, bump_diameter_mm, contact,
                                   position_control)  # fmt: skip
        self.last_force_N = state["load_N"]
        code = self.codes_at(self.taxels_mm, state) + self._cap.cdc_code(
            self._cap.capacitance_pF(np.zeros(1))
        )
        if rng is not None:
            code = np.clip(np.round(code + p.noise_lsb * rng.standard_normal(code.shape)), 0, 65535)
        rest = self._cap.cdc_code(self._cap.capacitance_pF(np.zeros(1)))
        off = np.asarray(offset_counts, np.float64)
        off = off[:, None] if off.ndim == 1 else off
        counts = gain[:, None] * (code - rest) / 2**p.shift_bits + off
        if rng is not None and p.noise_counts > 0:
            counts = counts + p.noise_counts * rng.standard_normal(counts.shape)
        return np.clip(np.round(counts), 0, 255)
