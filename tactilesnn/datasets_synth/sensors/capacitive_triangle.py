"""Capacitive triangle module (seed 003, SPEC 2.4): 12 parallel-plate taxels, 16-bit CDC.

Array contract of :meth:`CapacitiveTriangle.read`: a disc contact per simulation sample
(``force_N [samples]``, ``center_mm [samples, 2]`` or ``[2]``, ``diameter_mm``) at ``fs_in_hz``
-> ``(t_s [frames], codes [channels, frames])``: 16-bit CDC codes (float64 integers 0..65535),
one frame per CDC sweep. ``mode`` selects 12 taxels, 3 macro-areas (4 pads wired together) or 1
(all-in-one); the stages of a frame are converted one after another, so each channel is sampled
at its own stage time. :meth:`code_to_pF` inverts the CDC.

Physics: ``C = eps_r eps0 A / x`` per pad (4 mm diameter pad, A = 12.6 mm^2) plus the routing's
parasitic capacitance. The soft layer (silicone foam, 3 mm) is the dielectric: pressure p
compresses it to ``x = x0 (1 - s)`` with the foam's saturating strain ``s = s_max p/(p + p_half)``
and its permittivity rises with compression (air squeezed out: ``eps_r = eps0_r + k s``). Load
spreads through the layer (Boussinesq stress at mid-depth) so a 12 mm probe at the centre loads
the 3 inner taxels most, the 6 edge taxels less and the 3 corners least (seed 003). Foam
hysteresis: a play (backlash) operator of width ``hysteresis`` on the strain. CDC (AD7147-like):
16-bit, linear over 4-30 pF (codes clip outside), stage conversion 0.768 / 1.536 / 3.072 ms
(12 taxels per frame: 9.2 / 18.4 / 36.8 ms; 3 macro-areas 2.3 / 4.6 / 9.2 ms), noise falling
with longer conversions and growing with the number of modules on the bus.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ...core.checks import as_float_array, check_choice, check_finite, check_positive
from ..scenes.inputs import ContactSeries
from .base import SensorParams, check_scene, register_sensor
from .pvdf import EPS0, boussinesq_t3, contact_positions, disc_points

STAGE_MS = (0.768, 1.536, 3.072)
MODES = {"12": 12, "3": 3, "1": 1}


def triangle12_layout(circumradius_mm: float = 12.0) -> np.ndarray:
    """3-fold symmetric 12-pad triangle (mm, centroid at 0): 3 inner, 6 edge, 3 corner pads."""
    ang = np.deg2rad(90 + np.array([0, 120, 240]))
    corners = circumradius_mm * np.stack([np.cos(ang), np.sin(ang)], 1)
    edges = []
    for i in range(3):
        a, b = corners[i], corners[(i + 1) % 3]
        edges += [a + (b - a) / 3, a + 2 * (b - a) / 3]
    inner = -0.25 * corners  # toward the edge midpoints
    return np.concatenate([inner, np.array(edges) * 1.0, corners * 1.0])


def macro_groups(mode: str) -> list[np.ndarray]:
    """Pads wired together per CDC stage: 12 singles, 3 sectors of 4, or all 12."""
    check_choice(mode, "mode", tuple(MODES))
    if mode == "12":
        return [np.array([i]) for i in range(12)]
    if mode == "1":
        return [np.arange(12)]
    # sector k: corner k, the two edge pads next to it, and one inner pad (3-fold symmetric)
    return [np.array([9 + k, 3 + 2 * k, 4 + 2 * ((k - 1) % 3), (k - 1) % 3]) for k in range(3)]


@dataclass(frozen=True)
class CapacitiveTriangleParams(SensorParams):
    """Seed 003's values; every field can be overridden (lengths mm, pressures Pa)."""

    pad_diameter_mm: float = 4.0
    gap_um: float = 100.0  # foam dielectric thickness at rest (SPEC: 10 um - 3 mm)
    eps_r: float = 3.0
    eps_r_gain: float = 2.0  # permittivity rise at full compression (foam 3 -> ~4.4)
    strain_max: float = 0.7
    p_half_Pa: float = 50e3
    spread_depth_mm: float = 1.5  # load spreading depth in the 3 mm silicone foam
    parasitic_pF: float = 2.0
    cdc_lo_pF: float = 4.0
    cdc_hi_pF: float = 30.0
    cdc_bits: int = 16
    stage: int = 0  # index into STAGE_MS
    noise_lsb: float = 4.0  # rms at the fastest stage, one module
    modules: int = 1  # triangles on the bus (16 per MCU board)
    hysteresis: float = 0.03  # play width on the strain
    circumradius_mm: float = 12.0

    def __post_init__(self) -> None:
        for name in ("pad_diameter_mm", "gap_um", "eps_r", "p_half_Pa", "spread_depth_mm",
                     "circumradius_mm"):  # fmt: skip
            check_positive(getattr(self, name), name)
        if not 0 < self.strain_max < 1:
            raise ValueError(f"strain_max must be in (0, 1), got {self.strain_max}")
        if self.stage not in range(len(STAGE_MS)):
            raise ValueError(f"stage must be 0, 1 or 2 ({STAGE_MS} ms), got {self.stage}")
        if not self.cdc_lo_pF < self.cdc_hi_pF:
            raise ValueError("cdc_lo_pF must be below cdc_hi_pF")


@register_sensor("capacitive_triangle")
class CapacitiveTriangle:
    """Twelve parallel-plate taxels under silicone foam, read by a 16-bit CDC."""

    units: ClassVar[str] = "CDC counts"
    scene_type: ClassVar[type] = ContactSeries

    def output_rate_hz(self, scene: ContactSeries) -> float:
        return 1000.0 / self.frame_ms

    def read_scene(
        self, scene: ContactSeries, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        """The :class:`~..sensors.base.SensorModel` form of :meth:`read`."""
        check_scene(self, scene)
        return self.read(scene.force_N, scene.center_mm, scene.diameter_mm, scene.fs_in_hz, rng)[1]

    def __init__(self, params: CapacitiveTriangleParams | None = None, mode: str = "12") -> None:
        self.params = params or CapacitiveTriangleParams()
        self.mode = check_choice(mode, "mode", tuple(MODES))
        self.taxels_mm = triangle12_layout(self.params.circumradius_mm)
        self.groups = macro_groups(mode)
        self.last_skipped_channels = 0  # channels the last read() did not simulate

    @property
    def n_channels(self) -> int:
        return len(self.groups)

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(
            f"{'taxel' if self.mode == '12' else 'area'}{i}" for i in range(self.n_channels)
        )

    @property
    def stage_ms(self) -> float:
        return STAGE_MS[self.params.stage]

    @property
    def frame_ms(self) -> float:
        """One CDC sweep: stages x conversion time (12: 9.2 ms, 3: 2.3 ms at 0.768 ms/stage)."""
        return self.n_channels * self.stage_ms

    @property
    def pad_area_mm2(self) -> float:
        return np.pi * (self.params.pad_diameter_mm / 2) ** 2

    # ------------------------------------------------------------------ mechanics
    def taxel_pressure_Pa(
        self,
        force_N: np.ndarray,
        center_mm: np.ndarray,
        diameter_mm: float,
        taxels: np.ndarray | None = None,
        positions: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """Pressure (Pa) on each pad ``[12, samples]`` from a uniform disc load spread by the
        foam; with ``taxels`` only those pads (``[len(taxels), samples]``); ``positions``: the
        contact's :func:`contact_positions`, if already known."""
        f = np.asarray(force_N, dtype=np.float64)
        pads = self.taxels_mm if taxels is None else self.taxels_mm[np.asarray(taxels)]
        offs, wts = disc_points(diameter_mm)
        uniq, inv = positions or contact_positions(center_mm, f.size)
        per = np.empty((len(pads), len(uniq)))
        for k, u in enumerate(uniq):
            r = np.linalg.norm(pads[:, None, :] - (u + offs)[None], axis=-1)
            per[:, k] = -boussinesq_t3(1.0, r, self.params.spread_depth_mm) @ wts
        return per[:, inv] * f[None, :]

    def reachable_channels(
        self,
        force_N: np.ndarray,
        center_mm: np.ndarray,
        diameter_mm: float,
        tol_lsb: float = 0.0,
        positions: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """Channels whose CDC code the contact can move off its rest value ``[channels]`` bool.

        The foam's spread ``|T3|`` falls with distance, so a pad's pressure never exceeds
        ``max F x |T3|(nearest approach of the disc)``; strain (also through the play operator,
        whose output stays in ``[0, max strain]``), capacitance and the CDC's rounding are
        monotone, so if that bound converts to the rest code, every sample does (exact). With
        ``tol_lsb > 0`` a channel whose bound stays below ``tol_lsb`` LSB of the rest level is
        also left out: its codes then differ from a full simulation by at most
        ``ceil(tol_lsb)`` LSB (the CDC's noise is ``noise_lsb`` = 4 LSB rms).
        """
        p = self.params
        if p.eps_r + p.eps_r_gain * p.strain_max <= 0:  # capacitance not monotone in strain
            return np.ones(self.n_channels, dtype=bool)
        f_max = max(float(np.max(force_N, initial=0.0)), 0.0)
        uniq, _ = positions or contact_positions(center_mm, np.asarray(force_N).size)
        reach = np.linalg.norm(self.taxels_mm[:, None, :] - uniq[None], axis=-1).min(1)
        nearest = np.maximum(reach - diameter_mm / 2, 0.0)
        p_max = -boussinesq_t3(f_max, nearest, p.spread_depth_mm)
        c_rest = self.capacitance_pF(np.zeros(12))
        c_max = self.capacitance_pF(self.strain_static(p_max))
        lsb = (p.cdc_hi_pF - p.cdc_lo_pF) / (2**p.cdc_bits - 1)
        live = []
        for g in self.groups:
            lo = c_rest[g].sum() - (len(g) - 1) * p.parasitic_pF
            hi = c_max[g].sum() - (len(g) - 1) * p.parasitic_pF
            live.append(self.cdc_code(lo) != self.cdc_code(hi) and hi - lo >= tol_lsb * lsb)
        return np.array(live)

    def strain_static(self, pressure_Pa: np.ndarray) -> np.ndarray:
        """Foam compression (fraction) at a pressure, without hysteresis."""
        p = self.params
        q = np.maximum(pressure_Pa, 0.0)
        return p.strain_max * q / (q + p.p_half_Pa)

    def strain(self, pressure_Pa: np.ndarray) -> np.ndarray:
        """Foam compression (fraction) with play-operator hysteresis along the last axis."""
        p = self.params
        s = self.strain_static(pressure_Pa)
        if p.hysteresis <= 0:
            return s
        out = np.empty_like(s)
        y = np.zeros(s.shape[:-1])
        half = p.hysteresis / 2
        # skip what the scene does not need: one step of the play operator is idempotent, so
        # over a run of samples where no pad's strain changes (no contact before and after a
        # press, a steady hold) the output is its first value: only the changes are stepped
        # (exact, the same floats as stepping every sample)
        flat = s.reshape(-1, s.shape[-1])
        changes = np.flatnonzero(np.r_[True, (flat[:, 1:] != flat[:, :-1]).any(axis=0)])
        ends = np.r_[changes[1:], s.shape[-1]]
        for t, end in zip(changes, ends, strict=True):
            y = np.clip(y, s[..., t] - half, s[..., t] + half)
            y = np.maximum(y, 0.0)
            out[..., t:end] = y[..., None]
        return out

    def strain_every_sample(self, pressure_Pa: np.ndarray) -> np.ndarray:
        """:meth:`strain` stepping the play operator at every sample (the reference its run
        skipping is tested and benchmarked against)."""
        p = self.params
        s = (
            p.strain_max
            * np.maximum(pressure_Pa, 0.0)
            / (np.maximum(pressure_Pa, 0.0) + p.p_half_Pa)
        )
        out, y, half = np.empty_like(s), np.zeros(s.shape[:-1]), p.hysteresis / 2
        for t in range(s.shape[-1]):
            y = np.maximum(np.clip(y, s[..., t] - half, s[..., t] + half), 0.0)
            out[..., t] = y
        return out

    def capacitance_pF(self, strain: np.ndarray) -> np.ndarray:
        """Pad capacitance (pF): ``eps_r(s) eps0 A / (x0 (1 - s))`` + parasitic."""
        p = self.params
        eps = p.eps_r + p.eps_r_gain * strain
        x = p.gap_um * 1e-6 * (1 - strain)
        return eps * EPS0 * self.pad_area_mm2 * 1e-6 / x * 1e12 + p.parasitic_pF

    # ------------------------------------------------------------------ CDC
    def cdc_code(self, c_pF: np.ndarray) -> np.ndarray:
        """Linear 16-bit conversion over [cdc_lo, cdc_hi] pF, clipped to 0..2^bits - 1."""
        p = self.params
        full = 2**p.cdc_bits - 1
        code = np.round((c_pF - p.cdc_lo_pF) / (p.cdc_hi_pF - p.cdc_lo_pF) * full)
        return np.clip(code, 0, full)

    def code_to_pF(self, code: np.ndarray) -> np.ndarray:
        p = self.params
        return p.cdc_lo_pF + np.asarray(code) / (2**p.cdc_bits - 1) * (p.cdc_hi_pF - p.cdc_lo_pF)

    def read(
        self,
        force_N: np.ndarray,
        center_mm: np.ndarray,
        diameter_mm: float,
        fs_in_hz: float,
        rng: np.random.Generator | None = None,
        skip: bool = True,
        skip_tol_lsb: float = 0.0,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Contact time course -> ``(t_s [frames], codes [channels, frames])`` (see module doc).

        ``skip``: pads of channels the contact cannot move off their rest code are not simulated
        (identical codes, see :meth:`reachable_channels`); ``skip_tol_lsb``: also those it moves
        by less than this many LSB (codes then within ``ceil(skip_tol_lsb)`` LSB). The number
        of channels left out is kept in ``last_skipped_channels``.
        """
        p = self.params
        f = as_float_array(force_N, "force_N", ndim=1).astype(np.float64)
        check_finite(f, "force_N")
        fs_in = check_positive(fs_in_hz, "fs_in_hz")
        check_positive(diameter_mm, "diameter_mm")
        if fs_in < 2000.0 / self.stage_ms:
            raise ValueError(
                f"fs_in_hz {fs_in_hz} too coarse for {self.stage_ms} ms CDC stages; "
                f"use >= {2000.0 / self.stage_ms:.0f} Hz"
            )
        # skip what the contact cannot reach: the pads of channels whose code cannot change
        # keep their rest capacitance (exact, see reachable_channels)
        if skip_tol_lsb < 0 or not np.isfinite(skip_tol_lsb):
            raise ValueError(f"skip_tol_lsb must be finite and >= 0, got {skip_tol_lsb}")
        where = contact_positions(center_mm, f.size)
        live = None
        if skip:
            live = self.reachable_channels(f, center_mm, diameter_mm, skip_tol_lsb, where)
        simulate = np.ones(12, dtype=bool)
        if live is not None:
            simulate[:] = False
            for g, on in zip(self.groups, live, strict=True):
                simulate[g] |= on
        pads = np.flatnonzero(simulate)
        if pads.size == 12:
            press = self.taxel_pressure_Pa(f, center_mm, diameter_mm, None, where)
            c = self.capacitance_pF(self.strain(press))
        else:
            c = np.repeat(self.capacitance_pF(np.zeros((12, 1))), f.size, axis=1)
            if pads.size:
                press = self.taxel_pressure_Pa(f, center_mm, diameter_mm, pads, where)
                c[pads] = self.capacitance_pF(self.strain(press))
        self.last_skipped_channels = 0 if live is None else int((~live).sum())
        c_ch = np.stack([c[g].sum(0) - (len(g) - 1) * p.parasitic_pF for g in self.groups])
        duration = f.size / fs_in
        frames = int(duration * 1000 / self.frame_ms)
        t_frame = np.arange(frames) * self.frame_ms / 1000
        # stage k of a frame converts channel k at t_frame + (k + 1) stage times
        t_stage = (
            t_frame[None, :] + (np.arange(self.n_channels)[:, None] + 1) * self.stage_ms / 1000
        )
        idx = np.minimum((t_stage * fs_in).astype(int), f.size - 1)
        sampled = np.take_along_axis(c_ch, idx, axis=1)
        code = self.cdc_code(sampled)
        if rng is not None:
            noise = p.noise_lsb * np.sqrt(STAGE_MS[0] / self.stage_ms) * np.sqrt(p.modules)
            code = np.clip(np.round(code + noise * rng.standard_normal(code.shape)), 0,
                           2**p.cdc_bits - 1)  # fmt: skip
        return t_frame, code


def pressure_centroid(values: np.ndarray, positions_mm: np.ndarray) -> np.ndarray:
    """``x_c = sum x_i p_i / sum p_i`` for ``values [channels, ...]`` -> ``[..., 2]`` (mm).

    Frames with no positive pressure give NaN centroids (there is no contact to locate).
    """
    v = np.maximum(np.asarray(values, dtype=np.float64), 0.0)
    pos = np.asarray(positions_mm, dtype=np.float64)
    total = v.sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.moveaxis(np.tensordot(pos.T, v, axes=(1, 0)) / total, 0, -1)


def second_moment(values: np.ndarray, positions_mm: np.ndarray) -> np.ndarray:
    """Second-moment matrix ``E = sum (x_i - x_c)(x_i - x_c)^T p_i / sum p_i`` -> ``[..., 2, 2]``."""
    v = np.maximum(np.asarray(values, dtype=np.float64), 0.0)
    pos = np.asarray(positions_mm, dtype=np.float64)
    xc = pressure_centroid(v, pos)  # [..., 2]
    d = pos.reshape((pos.shape[0],) + (1,) * (v.ndim - 1) + (2,)) - xc[None]  # [C, ..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.einsum("c...i,c...j,c...->...ij", d, d, v) / v.sum(0)[..., None, None]


def ellipse_axes(moment: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axes ``sqrt(eigenvalues)`` (mm, major first) and major-axis angle (rad) of ``E``."""
    w, vec = np.linalg.eigh(moment)
    axes = np.sqrt(np.maximum(w[..., ::-1], 0.0))
    major = vec[..., :, -1]
    return axes, np.arctan2(major[..., 1], major[..., 0])
