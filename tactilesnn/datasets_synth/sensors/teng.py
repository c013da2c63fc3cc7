"""TENG tribotronic sensor + LIF analog-to-spike converter (seed 000, SPEC 2.2).

Array contract of :meth:`TENGArray.read`: per-electrode gap ``gap_mm [channels, samples]`` between
the object's surface and the skin (> 0 = proximity, < 0 = overlap) at ``fs_hz``, the contacting
``material`` and its contact count -> triboelectric gate potential ``V_T [channels, samples]``
float64 in volts at the same rate (default 500 S/s; V_T is slow, the converter's spikes are
events and are produced by :class:`~tactilesnn.encoders.teng_converter.TENGConverter`).

Transduction ``Tr: P(t) -> V(t)``, built from the seed's single-sensor characterisation:
- proximity phase: the induced potential starts ~2 mm before contact and rises 0.8 mV/um
  (0.8 V/mm; "equivalent to an additional 2 mm-thick air layer"), smoothed over ``knee_mm``;
- contact phase: 0.4 mV/um of skin indentation, i.e. 1.5 mV/kPa through the skin's stress-strain
  relation (267 kPa per mm of indentation); linear up to 50 N on the 15 mm indenter (47 N/mm);
- the induced charge relaxes through the contacting surface with time constant ``relax_s`` of the
  material (first-order high-pass), so the peak grows with approach speed and coincides with
  contact onset (the contact phase rises at half the proximity slope), and materials that differ
  at low speed converge at high speed (the seed's Fig. 24);
- the amplitude scales with the surface charge difference of object and skin (sigma_T,
  sigma'_T): ``charge_rel`` of the material, growing with repeated contacts (contact
  electrification, saturating after ``~electrification_contacts``);
- residual charges from earlier contacts add a long-range term of random sign and amplitude per
  contact: far from the skin V_T has a coefficient of variation ~3.5 over repeated contacts.

Converter ``G: V(t) -> ST(t)`` (the encoding stage after this model:
:class:`~tactilesnn.encoders.teng_converter.TENGConverter`): the transistor conducts once V_T
exceeds its turn-on voltage; the drain current charges a leaky membrane
``tau_mem dV/dt = -(V - V_rest) + R I(t)`` that fires at ``theta`` and resets. Far-proximity
potentials stay below turn-on, so the rate starts ~1 mm before contact.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import signal

from ...core.checks import as_float_array, check_choice, check_finite, check_positive
from ..scenes.inputs import GapSeries
from .base import SensorParams, check_scene, register_sensor


@dataclass(frozen=True)
class TriboMaterial:
    """Contact material: surface-charge difference vs the PDMS skin (relative to the seed's
    indenter), charge relaxation time (s) and contact-electrification growth (fraction)."""

    name: str
    charge_rel: float
    relax_s: float
    electrification: float


# Triboelectric series vs PDMS: glass and aluminium sit far on the positive side, Kapton close to
# PDMS; conductive or hygroscopic surfaces (aluminium, paper, cloth) bleed charge faster.
MATERIALS: dict[str, TriboMaterial] = {
    m.name: m
    for m in (
        TriboMaterial("aluminium", 1.00, 0.030, 0.05),
        TriboMaterial("kapton", 0.80, 0.150, 0.60),
        TriboMaterial("paper", 0.90, 0.060, 0.30),
        TriboMaterial("glass", 1.10, 0.120, 0.40),
        TriboMaterial("cloth", 0.85, 0.090, 0.50),
    )
}


@dataclass(frozen=True)
class TENGParams(SensorParams):
    """Seed 000's single-sensor figures; every field can be overridden."""

    #: electronic-noise fields, scaled together by :func:`~.base.noise_scaled`
    NOISE_FIELDS: ClassVar[tuple[str, ...]] = ("noise_V",)

    fs_hz: float = 500.0
    proximity_mm: float = 2.0  # V_T starts rising this far from the skin
    proximity_V_per_mm: float = 0.8  # 0.8 mV/um
    contact_V_per_kPa: float = 1.5e-3  # 1.5 mV/kPa
    skin_kPa_per_mm: float = 0.4 / 1.5e-3  # 0.4 mV/um / 1.5 mV/kPa = 267 kPa per mm
    knee_mm: float = 0.3  # smooth onset of the proximity phase
    noise_V: float = 0.004  # rms at the gate
    residual_mean_V: float = 0.05  # residual-charge term amplitude (mean, sd) at the skin
    residual_sd_V: float = 0.175  # sd / mean = 3.5: the seed's far-field CV
    residual_range_mm: float = 3.0  # decay length of the residual-charge term
    electrification_contacts: float = 20.0
    # per-sensor calibration spread (seed: C 3-22 pF, R 0.24-1 MOhm before trimming) is a device
    # property: use Faults(gain_sd=...), which draws it once per device
    electrode_mm: float = 4.0  # square pad side: induced charge is the mean over the pad
    pad_quad: int = 3  # quadrature points per pad side

    def __post_init__(self) -> None:
        for name in ("fs_hz", "proximity_mm", "proximity_V_per_mm", "contact_V_per_kPa",
                     "skin_kPa_per_mm", "knee_mm", "residual_range_mm"):  # fmt: skip
            check_positive(getattr(self, name), name)


@register_sensor("teng")
class TENGArray:
    """TENG electrodes under a PDMS skin: gap time courses -> gate potentials V_T (V)."""

    units: ClassVar[str] = "V"
    scene_type: ClassVar[type] = GapSeries

    def output_rate_hz(self, scene: GapSeries) -> float:
        return self.fs_hz

    def read_scene(self, scene: GapSeries, rng: np.random.Generator | None = None) -> np.ndarray:
        """The :class:`~..sensors.base.SensorModel` form of :meth:`read`."""
        check_scene(self, scene)
        return self.read(
            scene.gap_mm, scene.material, scene.contacts, rng, skin_share=scene.skin_share
        )

    def __init__(self, positions_mm: np.ndarray, params: TENGParams | None = None) -> None:
        self.positions_mm = np.asarray(positions_mm, dtype=np.float64).reshape(-1, 2)
        self.params = params or TENGParams()

    @property
    def fs_hz(self) -> float:
        return self.params.fs_hz

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(f"e{i}" for i in range(len(self.positions_mm)))

    def pad_points(self) -> np.ndarray:
        """Quadrature points over each square pad, ``[channels, Q, 2]`` (mm)."""
        p = self.params
        g = ((np.arange(p.pad_quad) + 0.5) / p.pad_quad - 0.5) * p.electrode_mm
        qx, qy = np.meshgrid(g, g)
        offs = np.stack([qx.ravel(), qy.ravel()], 1)
        return self.positions_mm[:, None, :] + offs[None, :, :]

    def induced_V(self, gap_mm: np.ndarray) -> np.ndarray:
        """Quasi-static induced potential (V, reference material) for a gap (mm; < 0 = overlap).

        0 beyond ``proximity_mm``; 0.8 V/mm inside it (softplus knee); plus 1.5 mV/kPa of the
        skin's stress once in contact.
        """
        p = self.params
        d = np.asarray(gap_mm, dtype=np.float64)
        k, reach = p.knee_mm, p.proximity_mm
        # k (softplus((reach - d)/k) - softplus(-reach/k)) equals reach exactly at d = 0
        approach = k * (np.logaddexp(0.0, (reach - np.maximum(d, 0.0)) / k)
                        - np.logaddexp(0.0, -reach / k))  # fmt: skip
        prox = p.proximity_V_per_mm * np.maximum(approach, 0.0)
        skin_kpa = p.skin_kPa_per_mm * np.maximum(-d, 0.0)
        return prox + p.contact_V_per_kPa * skin_kpa

    def induced_pad_V(self, gap_mm: np.ndarray, skip: bool = True) -> np.ndarray:
        """:meth:`induced_V` averaged over each pad's points: ``[channels, Q, samples]`` ->
        ``[channels, samples]``. ``skip``: samples where every point of every pad is at least
        twice ``proximity_mm`` away are not evaluated (the potential is exactly 0 there: the two
        softplus terms cancel), which is most of a recording outside the presses; the result
        agrees to float64 rounding (<= 1e-12 V; tested), far below the 1 mV noise."""
        if not skip:
            return self.induced_V(gap_mm).mean(1)
        near = (gap_mm < 2 * self.params.proximity_mm).any(axis=(0, 1))  # [samples]
        out = np.zeros((gap_mm.shape[0], gap_mm.shape[2]))
        if near.any():
            out[:, near] = self.induced_V(gap_mm[:, :, near]).mean(1)
        return out

    def read(
        self,
        gap_mm: np.ndarray,
        material: str,
        contacts: int = 0,
        rng: np.random.Generator | None = None,
        skin_share: np.ndarray | float = 1.0,
    ) -> np.ndarray:
        """Gap ``[channels, samples]`` or ``[channels, Q, samples]`` (mm) -> ``V_T`` (V).

        With ``Q`` points per pad (:meth:`pad_points`) the induced potential is averaged over the
        pad (the electrode integrates the induced charge). Output ``[channels, samples]`` at
        ``fs_hz``.

        ``skin_share``: fraction of an overlap taken up by the skin (the rest by a softer object),
        scalar or per channel. ``contacts``: earlier contacts with this material (electrification).
        """
        p = self.params
        check_choice(material, "material", tuple(MATERIALS))
        gap = as_float_array(gap_mm, "gap_mm", ndim=(2, 3)).astype(np.float64)
        if gap.ndim == 2:
            gap = gap[:, None, :]
        check_finite(gap, "gap_mm")
        if gap.shape[0] != len(self.positions_mm):
            raise ValueError(f"gap_mm has {gap.shape[0]} channels; the array has "
                             f"{len(self.positions_mm)} electrodes")  # fmt: skip
        if contacts < 0:
            raise ValueError(f"contacts must be >= 0, got {contacts}")
        mat = MATERIALS[material]
        share = np.broadcast_to(np.asarray(skin_share, dtype=np.float64), (gap.shape[0],))
        eff = np.where(gap < 0, gap * share[:, None, None], gap)  # skin indentation in contact
        charge = mat.charge_rel * (
            1 + mat.electrification * (1 - np.exp(-contacts / p.electrification_contacts))
        )
        u = charge * self.induced_pad_V(eff)
        if rng is not None:
            residual = p.residual_mean_V + p.residual_sd_V * rng.standard_normal()
            u = u + residual * np.exp(-np.maximum(gap, 0.0) / p.residual_range_mm).mean(1)
        v = relax(u, self.fs_hz, mat.relax_s)
        if rng is not None:
            v = v + p.noise_V * rng.standard_normal(v.shape)
        return v


def relax(u: np.ndarray, fs_hz: float, tau_s: float) -> np.ndarray:
    """First-order charge relaxation (high-pass, time constant ``tau_s``) along the last axis.

    Exact discretisation of ``dv/dt = du/dt - v / tau`` for input changing linearly between
    samples, started from rest at the first sample's value.
    """
    a = np.exp(-1.0 / (fs_hz * tau_s))
    du = np.diff(u, axis=-1, prepend=u[..., :1])
    # linear input over a step: the step's increment enters with the mean decay over the step
    b = tau_s * fs_hz * (1 - a)
    return signal.lfilter([b], [1.0, -a], du, axis=-1)


# ------------------------------------------------------------------------------ layouts (mm)
def finger8_layout() -> np.ndarray:
    """Seed 000's 8-electrode finger-shaped array: 2 columns x 4 rows.

    The seed gives no coordinates; the grid (x +-3 mm, rows 8 mm apart) is chosen so that the
    15 mm flat indenter covers 4 electrodes at once, as the seed reports.
    """
    return np.array([(x, y) for y in (6.0, 14.0, 22.0, 30.0) for x in (-3.0, 3.0)])


MIA6 = np.array([(-2.5, 44), (2.5, 44), (3, 35.5), (2.5, 29.5), (4.3, 16.5), (-4.3, 16.5)], float)
MIA14 = np.array(
    [(-4, 25.5), (-4, 17), (-4.5, 12), (0, 8.5), (0, 20.5), (4.5, 12), (4, 17), (4, 25.5),
     (2.5, 30.5), (3, 37), (2.5, 44), (-2.5, 44), (-3, 37), (-2.5, 30.5)], float,
)  # fmt: skip
LAYOUTS = {"finger8": finger8_layout(), "mia6": MIA6, "mia14": MIA14}


def layout(name: str) -> np.ndarray:
    """Electrode coordinates (x across, y along the finger; mm) of a named layout."""
    check_choice(name, "layout", tuple(LAYOUTS))
    return LAYOUTS[name].copy()
