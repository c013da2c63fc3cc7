"""CMOS piezoresistive stress-sensor chip array in a flexible skin (seed 002, SPEC 2.3).

Each chip holds four N-well resistors at 0, 45, 90 and 135 degrees to [100]. Under an in-plane
uniaxial stress sigma at angle lambda a resistor at angle phi changes by

    drho/rho = [pi11 (1/2 + 1/2 cos2phi cos2lam) + pi12 (1/2 - 1/2 cos2phi cos2lam)
                + pi44 (1/2 sin2phi sin2lam)] sigma

with the measured coefficients pi11 = -98.9456, pi12 = 49.4729, pi44 = -12.4675 (1e-11 / Pa).
Readings A (0), B (45), C (90) give ``M = (A + C) / 2 = (pi11 + pi12) / 2 sigma`` (magnitude),
``A - M = (pi11 - pi12) / 2 cos2lam sigma`` and ``B - M = pi44 / 2 sin2lam sigma`` (direction):
:func:`solve_stress` inverts them with atan2 (< 1 degree on noise-free input, tested).

Readout chain per resistor: bridge voltage ``0.9 V * drho/rho`` (V_sense ~ 900 mV), programmable gain
2 / 10 / 20 / 100, input noise 80 nV/sqrt(Hz) over the conversion bandwidth, 12-bit
sign-magnitude ADC over +-1.18 V. Array: 5 x 5 chips (1.46 mm, 6 mm edge spacing: 7.46 mm pitch,
37.3 mm patch). Timing: 60 Hz frames, "send-first, sense-later": a frame reports what was sensed
one frame earlier.

Array contract of :meth:`ChipArray.read`: in-plane stress per chip ``sigma_Pa [samples, 25]`` and
``lambda_rad [samples, 25]`` at ``fs_in_hz`` -> ``[25, 4, frames]`` float32 readings, in
``drho/rho`` units (the ADC code divided by gain and bridge voltage), at 60 frames/s.
Contact stress field (:func:`contact_stress`): the radial in-plane stress below a normal and a
tangential force through the foil (Boussinesq + Cerruti, Poisson ratio 0.5), along the line from
the contact; :func:`solve_contact` inverts it (position, normal and tangential force).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ...core.checks import as_float_array, check_finite, check_positive
from ..scenes.inputs import StressSeries
from .base import SensorParams, check_scene, register_sensor

PI11, PI12, PI44 = -98.9456e-11, 49.4729e-11, -12.4675e-11  # 1/Pa, seed 002
ANGLES_DEG = (0.0, 45.0, 90.0, 135.0)
GAINS = (2.0, 10.0, 20.0, 100.0)


def relative_resistance(sigma_Pa, lambda_rad, phi_rad) -> np.ndarray:
    """drho/rho of a resistor at ``phi`` under uniaxial stress ``sigma`` at ``lambda`` (SPEC 2.3)."""
    c = np.cos(2 * np.asarray(phi_rad)) * np.cos(2 * np.asarray(lambda_rad))
    s = np.sin(2 * np.asarray(phi_rad)) * np.sin(2 * np.asarray(lambda_rad))
    return (PI11 * (0.5 + 0.5 * c) + PI12 * (0.5 - 0.5 * c) + PI44 * 0.5 * s) * np.asarray(sigma_Pa)


def solve_stress(readings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[..., 4]`` drho/rho of the 0/45/90/135 degree resistors -> (sigma Pa, lambda rad).

    lambda is returned in (-pi/2, pi/2]; a uniaxial stress is the same at lambda and lambda + pi.
    """
    r = np.asarray(readings, dtype=np.float64)
    a, b, c = r[..., 0], r[..., 1], r[..., 2]
    m = (a + c) / 2
    sigma = 2 * m / (PI11 + PI12)
    safe = np.where(np.abs(sigma) > 0, sigma, 1.0)
    cos2 = (a - m) / ((PI11 - PI12) / 2 * safe)
    sin2 = (b - m) / (PI44 / 2 * safe)
    lam = 0.5 * np.arctan2(sin2, cos2)
    return sigma, np.where(np.abs(sigma) > 0, lam, 0.0)


def chip_positions(n: int = 5, chip_mm: float = 1.46, gap_mm: float = 6.0) -> np.ndarray:
    """Chip centres (mm) of an ``n x n`` array, row-major, origin at the patch centre."""
    pitch = chip_mm + gap_mm
    g = (np.arange(n) - (n - 1) / 2) * pitch
    xx, yy = np.meshgrid(g, g)
    return np.stack([xx.ravel(), yy.ravel()], 1)


def contact_stress(
    force_N: float,
    center_mm: np.ndarray,
    chips_mm: np.ndarray,
    depth_mm: float = 1.0,
    shear_N: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """In-plane stress (Pa) and its direction at each chip below a contact with normal force
    ``force_N`` and tangential force ``shear_N [2]`` (N, in the array's plane).

    For Poisson ratio 0.5 both Boussinesq's normal-load and Cerruti's tangential-load solutions
    leave a uniaxial in-plane stress along the line from the contact to the chip (Johnson,
    Contact Mechanics 3.2-3.3: the ``(1 - 2 nu)`` terms vanish):
    ``sigma = 3 (F z + Q . d) r^2 / (2 pi (r^2 + z^2)^(5/2))`` (compression counted positive),
    with ``d`` the in-plane vector
    from the contact to the chip (``r = |d|``) and ``z`` the depth; a tangential force loads the
    chips it points at more and those behind it less.
    """
    d = (np.asarray(chips_mm, dtype=np.float64) - np.asarray(center_mm, dtype=np.float64)) * 1e-3
    r2 = (d**2).sum(-1)
    z = depth_mm * 1e-3
    load = force_N * z
    if shear_N is not None:
        load = load + d @ np.asarray(shear_N, dtype=np.float64)
    sigma = 3 * load * r2 / (2 * np.pi * (r2 + z * z) ** 2.5)
    return sigma, np.arctan2(d[:, 1], d[:, 0])


def solve_contact(
    chips_mm: np.ndarray, sigma: np.ndarray, lam: np.ndarray, depth_mm: float = 1.0, top: int = 8
) -> tuple[np.ndarray, np.ndarray]:
    """Seed 002's least-squares inverse: the contact centre from the stress directions
    (:func:`locate_contact`), then the normal and tangential force from the magnitudes (linear
    least squares on ``sigma_k = c_k (F z + Q . d_k)``, :func:`contact_stress`'s model).
    Returns ``(center_mm [2], force [3] = (F_N, Qx_N, Qy_N))``."""
    center = locate_contact(chips_mm, sigma, lam, top)
    d = (np.asarray(chips_mm, np.float64) - center) * 1e-3
    r2 = (d**2).sum(-1)
    z = depth_mm * 1e-3
    c = 3 * r2 / (2 * np.pi * (r2 + z * z) ** 2.5)
    a = c[:, None] * np.concatenate([np.full((len(d), 1), z), d], 1)
    return center, np.linalg.lstsq(a, np.asarray(sigma, np.float64), rcond=None)[0]


def locate_contact(
    chips_mm: np.ndarray, sigma: np.ndarray, lam: np.ndarray, top: int = 8
) -> np.ndarray:
    """Contact centre (mm) where the chips' stress directions meet (weighted least squares).

    Each chip's radial stress line passes through the contact: minimise the stress-weighted sum
    of squared distances to the ``top`` most stressed chips' lines.
    """
    idx = np.argsort(-np.abs(sigma))[:top]
    n = np.stack([-np.sin(lam[idx]), np.cos(lam[idx])], 1)  # line normals
    w = np.abs(sigma[idx])
    a = (n[:, :, None] * n[:, None, :] * w[:, None, None]).sum(0)
    b = (n * (n * chips_mm[idx]).sum(1, keepdims=True) * w[:, None]).sum(0)
    return np.linalg.lstsq(a, b, rcond=None)[0]


@dataclass(frozen=True)
class ChipArrayParams(SensorParams):
    """Seed 002's readout values."""

    v_sense: float = 0.9
    gain: float = 10.0
    noise_nV_rtHz: float = 80.0
    bandwidth_hz: float = 1000.0  # conversion bandwidth seen by the input noise
    adc_bits: int = 12  # sign + 11 bits
    adc_range_V: float = 1.18
    frame_hz: float = 60.0

    def __post_init__(self) -> None:
        if self.gain not in GAINS:
            raise ValueError(f"gain must be one of {GAINS}, got {self.gain}")
        for name in ("v_sense", "noise_nV_rtHz", "bandwidth_hz", "adc_range_V", "frame_hz"):
            check_positive(getattr(self, name), name)

    @property
    def sensitivity_mV_per_MPa(self) -> float:
        """Output per MPa along [100] at 0 degrees (|pi11| dominated)."""
        return self.v_sense * self.gain * abs(PI11) * 1e6 * 1e3

    @property
    def kPa_per_lsb(self) -> float:
        lsb = self.adc_range_V / 2 ** (self.adc_bits - 1)
        return lsb / (self.sensitivity_mV_per_MPa * 1e-3) * 1e3


@register_sensor("piezoresistive")
class ChipArray:
    """5 x 5 piezoresistive chips polled at 60 Hz with one frame of latency."""

    units: ClassVar[str] = "drho / rho"
    scene_type: ClassVar[type] = StressSeries

    @property
    def channel_names(self) -> tuple[str, ...]:
        """Chip-major: ``chip<k>:<angle>deg`` for each resistor orientation."""
        return tuple(f"chip{k}:{a:g}deg" for k in range(len(self.chips_mm)) for a in ANGLES_DEG)

    def output_rate_hz(self, scene: StressSeries) -> float:
        return float(self.params.frame_hz)

    def read_scene(self, scene: StressSeries, rng: np.random.Generator | None = None) -> np.ndarray:
        """The :class:`~..sensors.base.SensorModel` form of :meth:`read`. Channels: chip-major,
        its four resistor orientations."""
        check_scene(self, scene)
        out = self.read(scene.sigma_Pa, scene.lambda_rad, scene.fs_in_hz, rng)  # [chips, 4, frames]
        return out.reshape(-1, out.shape[-1])

    def __init__(self, params: ChipArrayParams | None = None) -> None:
        self.params = params or ChipArrayParams()
        self.chips_mm = chip_positions()
        self.phis = np.deg2rad(ANGLES_DEG)

    def read(
        self,
        sigma_Pa: np.ndarray,
        lambda_rad: np.ndarray,
        fs_in_hz: float,
        rng: np.random.Generator | None = None,
    ) -> np.ndarray:
        p = self.params
        s = as_float_array(sigma_Pa, "sigma_Pa", ndim=2).astype(np.float64)
        lam = as_float_array(lambda_rad, "lambda_rad", ndim=2).astype(np.float64)
        if s.shape != lam.shape or s.shape[1] != len(self.chips_mm):
            raise ValueError(
                f"sigma_Pa and lambda_rad must both be [samples, {len(self.chips_mm)}], "
                f"got {s.shape} and {lam.shape}"
            )
        check_finite(s, "sigma_Pa")
        check_finite(lam, "lambda_rad")
        fs = check_positive(fs_in_hz, "fs_in_hz")
        n_frames = int(s.shape[0] / fs * p.frame_hz)
        # frame k reports the stress sensed at the start of frame k - 1 (send-first, sense-later)
        sensed = np.clip(((np.arange(n_frames) - 1) / p.frame_hz * fs).astype(int), 0, None)
        rel = relative_resistance(
            s[sensed][:, :, None], lam[sensed][:, :, None], self.phis[None, None, :]
        )  # [frames, 25, 4]
        v = p.v_sense * p.gain * rel
        if rng is not None:
            v = v + p.gain * p.noise_nV_rtHz * 1e-9 * np.sqrt(p.bandwidth_hz) * rng.standard_normal(
                v.shape
            )
        lsb = p.adc_range_V / 2 ** (p.adc_bits - 1)
        code = np.clip(np.round(v / lsb), -(2 ** (p.adc_bits - 1) - 1), 2 ** (p.adc_bits - 1) - 1)
        out = code * lsb / (p.v_sense * p.gain)
        out[0] = 0.0  # the first frame has nothing sensed yet
        return np.transpose(out, (1, 2, 0)).astype(np.float32)
