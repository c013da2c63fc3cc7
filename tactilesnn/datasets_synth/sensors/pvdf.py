"""PVDF piezoelectric triangle (seed 004, SPEC 2.5): Boussinesq stress, d33 charge, charge amplifier.

Array contract of :meth:`PVDFTriangle.read`: a contact described per simulation sample by its
total normal force ``force_N [samples]``, centre ``center_mm [samples, 2]`` and diameter
``diameter_mm`` (uniform pressure over the disc) at ``fs_in_hz`` -> ``[12, samples_out]`` float32
at ``fs_hz`` (4 kS/s, >= 2 kS/s per taxel), in pC of equivalent input charge (the readout's output
divided by its gain), after the charge amplifier's band (high-pass at 1 / (2 pi R_f C_f), low-pass
1 kHz).

Physics: a vertical point force F on the cover surface (PDMS, thickness h = 2.5 mm) gives at the
sensor plane ``T3 = -3 F h^3 / (2 pi (r^2 + h^2)^(5/2))`` (Boussinesq; integrates to -F over the
plane). A taxel (5 x 5 mm PVDF film, 110 um, eps_r 12: C_p = 24 pF) produces
``q = d33 * integral of T3 over its area`` with d33 = -20 pC/N. The charge amplifier (seed 004:
C_f = 100 pF, R_f = 100 MOhm) gives ``V = -q / C_f`` above ``f_L = 1 / (2 pi R_f C_f)`` = 16 Hz,
saturating at the +-5 V supply (25 N on one taxel, as the seed states). Touch spans 5 decades
(50 Pa - 5 MPa, ~0.01 pC - 5 nC), more than one gain can hold, so the readout is dual-range: the
same charge is also read through a 10 nF feedback capacitor (its resistor scaled to keep the same
corner), and each sample takes the
high-gain reading unless it is within 10 % of saturation. A 24-bit ADC digitises both.

Inverse problem (seed 004): point forces on a grid (here the 12 taxel sites) give ``b = C x`` with
C the superposed Boussinesq kernels; :func:`reconstruct_forces` solves it with the Moore-Penrose
pseudo-inverse under the physical constraint that normal forces are compressive (non-negative),
via non-negative least squares.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import optimize, signal

from ...core.checks import as_float_array, check_decimation, check_finite, check_positive
from ..scenes.inputs import ContactSeries
from .base import SensorParams, check_scene, register_sensor

EPS0 = 8.8541878128e-12


def triangle_layout(pitch_mm: float = 6.0) -> np.ndarray:
    """12 taxel centres (mm) on a triangular patch: rows of 5, 4, 2 and 1 at 60-degree offsets."""
    pts = []
    for row, count in enumerate((5, 4, 2, 1)):
        y = row * pitch_mm * np.sqrt(3) / 2
        x0 = row * pitch_mm / 2 + (1.0 if row == 2 else 0.0) * pitch_mm / 2
        pts += [(x0 + i * pitch_mm, y) for i in range(count)]
    return np.array(pts, dtype=np.float64)


def boussinesq_t3(force_N: np.ndarray, r_mm: np.ndarray, cover_mm: float) -> np.ndarray:
    """Normal stress T3 (Pa) at depth ``cover_mm`` and radial distance ``r_mm`` from point forces."""
    h = cover_mm * 1e-3
    r = np.asarray(r_mm) * 1e-3
    return -3.0 * np.asarray(force_N) * h**3 / (2 * np.pi * (r * r + h * h) ** 2.5)


@functools.lru_cache(maxsize=16)
def _lowpass_sos(cutoff_hz: float, fs_hz: float) -> np.ndarray:
    """The readout's 2nd-order Butterworth low-pass as second-order sections (designed once per
    rate: the design took 2 of the touch task's 16 s of rendering)."""
    return signal.butter(2, cutoff_hz, fs=fs_hz, output="sos")


def contact_positions(center_mm: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Distinct contact centres ``[U, 2]`` (mm, to 0.1 um) and each sample's index into them.

    ``center_mm`` is one centre ``[2]`` or one per sample ``[n, 2]``; only distinct positions need
    the (costly) spatial quadrature of a contact.
    """
    c = np.asarray(center_mm, dtype=np.float64).reshape(-1, 2)
    if c.shape[0] == 1:
        c = np.repeat(c, n, 0)
    if c.shape[0] != n:
        raise ValueError(f"center_mm has {c.shape[0]} rows for {n} samples")
    r = np.round(c, 4)
    if n and (r == r[0]).all():  # a contact that stays put: np.unique's row sort costs 3 ms
        return r[:1], np.zeros(n, np.intp)
    uniq, inv = np.unique(r, axis=0, return_inverse=True)
    return uniq, inv.ravel()


def disc_points(diameter_mm: float, n_ring: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Sub-point offsets (mm) and weights summing to 1 for a uniform-pressure disc."""
    rad = diameter_mm / 2
    pts, w = [np.zeros((1, 2))], [np.ones(1)]
    for k in range(1, n_ring + 1):
        r = rad * (k - 0.5) / n_ring
        m = 6 * k
        a = 2 * np.pi * (np.arange(m) + 0.5 * (k % 2)) / m
        pts.append(np.stack([r * np.cos(a), r * np.sin(a)], 1))
        w.append(np.full(m, 2 * np.pi * r * (rad / n_ring)))  # ring area
    wts = np.concatenate(w)
    wts[0] = np.pi * (rad / n_ring / 2) ** 2
    return np.concatenate(pts), wts / wts.sum()


@dataclass(frozen=True)
class PVDFParams(SensorParams):
    """Seed 004's values; every field can be overridden."""

    #: electronic-noise fields, scaled together by :func:`~.base.noise_scaled`
    NOISE_FIELDS: ClassVar[tuple[str, ...]] = ("noise_uV",)

    d33_pC_per_N: float = -20.0
    eps_r: float = 12.0
    film_mm: float = 5.0
    thickness_um: float = 110.0
    cover_mm: float = 2.5  # PDMS
    cf_pF: float = 100.0  # charge amplifier feedback capacitor C1
    rf_Mohm: float = 100.0  # feedback resistor R1
    cf_low_range_pF: float = 10_000.0  # second, low-gain range (dynamic range extension)
    lowpass_hz: float = 1000.0
    supply_V: float = 5.0
    adc_bits: int = 24
    noise_uV: float = 5.0  # rms at the amplifier output
    fs_hz: float = 4000.0
    pitch_mm: float = 6.0
    quad: int = 5  # quadrature points per taxel side

    def __post_init__(self) -> None:
        for name in ("eps_r", "film_mm", "thickness_um", "cover_mm", "cf_pF", "rf_Mohm",
                     "cf_low_range_pF", "lowpass_hz", "supply_V", "fs_hz", "pitch_mm"):  # fmt: skip
            check_positive(getattr(self, name), name)
        if self.lowpass_hz >= self.fs_hz / 2:
            raise ValueError(f"lowpass {self.lowpass_hz} Hz must be below Nyquist {self.fs_hz / 2}")

    @property
    def capacitance_pF(self) -> float:
        """Film capacitance C_p = eps0 eps_r A / t (seed 004: 24 pF)."""
        area = (self.film_mm * 1e-3) ** 2
        return EPS0 * self.eps_r * area / (self.thickness_um * 1e-6) * 1e12

    @property
    def highpass_hz(self) -> float:
        return 1.0 / (2 * np.pi * self.rf_Mohm * 1e6 * self.cf_pF * 1e-12)

    @property
    def passband_hz(self) -> tuple[float, float]:
        """-3 dB band of the readout (Hz): the charge amplifier's R_f C_f high-pass (15.9 Hz)
        to the anti-alias low-pass (1 kHz). As a band restriction (``--passband-lo-hz/hi-hz``)
        it is too tight for the touch task: its first-order edge still passes what tells the
        modalities apart below 15.9 Hz (``bench skip``: 81.9 % instead of 97.5 %)."""
        return (self.highpass_hz, self.lowpass_hz)


@register_sensor("pvdf")
class PVDFTriangle:
    """Twelve PVDF taxels under a PDMS cover with a dual-range charge-amplifier readout."""

    units: ClassVar[str] = "pC"
    scene_type: ClassVar[type] = ContactSeries

    def output_rate_hz(self, scene: ContactSeries) -> float:
        return self.fs_hz

    def read_scene(
        self, scene: ContactSeries, rng: np.random.Generator | None = None, *, skip: bool = True
    ) -> np.ndarray:
        """The :class:`~..sensors.base.SensorModel` form of :meth:`read` (``skip`` as there)."""
        check_scene(self, scene)
        return self.read(scene.force_N, scene.center_mm, scene.diameter_mm, scene.fs_in_hz, rng,
                         skip=skip)  # fmt: skip

    n_channels = 12
    # charge below which a taxel is not simulated (read(skip=True)); 1/5 of the noise rms
    skip_tol_pC: float = 1e-4

    def __init__(self, params: PVDFParams | None = None) -> None:
        self.params = params or PVDFParams()
        self.taxels_mm = triangle_layout(self.params.pitch_mm)
        p = self.params
        g = (np.arange(p.quad) + 0.5) / p.quad - 0.5
        qx, qy = np.meshgrid(g * p.film_mm, g * p.film_mm)
        self._quad = np.stack([qx.ravel(), qy.ravel()], 1)  # offsets inside a taxel, mm
        self._cell_m2 = (p.film_mm * 1e-3 / p.quad) ** 2

    @property
    def fs_hz(self) -> float:
        return self.params.fs_hz

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(f"taxel{i}" for i in range(self.n_channels))

    # ------------------------------------------------------------------ mechanics -> charge
    def influence(self, points_mm: np.ndarray) -> np.ndarray:
        """Charge (pC) on each taxel per newton at each surface point: ``[12, points]``."""
        pts = np.asarray(points_mm, dtype=np.float64).reshape(-1, 2)
        q = self.taxels_mm[:, None, :] + self._quad[None, :, :]  # [12, Q, 2]
        h = self.params.cover_mm * 1e-3
        # Boussinesq's T3 (Pa per N, :func:`boussinesq_t3`) summed over each taxel's quadrature,
        # in place: (r^2 + h^2)^(5/2) as s * s * sqrt(s), not a float power (9x faster; it was
        # 25 of the touch task's 34 s of rendering), equal to it within 1 ulp
        s = q[:, :, None, 0] - pts[None, None, :, 0]  # [12, Q, P], mm
        s *= s
        dy = q[:, :, None, 1] - pts[None, None, :, 1]
        dy *= dy
        s += dy
        del dy
        s *= 1e-6  # m^2
        s += h * h
        den = np.sqrt(s)
        den *= s
        den *= s
        np.reciprocal(den, out=den)
        t3 = den.sum(1) * (-3.0 * h**3 / (2 * np.pi))
        return self.params.d33_pC_per_N * (t3 * self._cell_m2)

    def disc_points(self, diameter_mm: float, n_ring: int = 6) -> tuple[np.ndarray, np.ndarray]:
        return disc_points(diameter_mm, n_ring)

    def charge_pC(
        self, force_N: np.ndarray, center_mm: np.ndarray, diameter_mm: float
    ) -> np.ndarray:
        """Taxel charges ``[12, samples]`` (pC) for a disc contact moving over the triangle."""
        f = np.asarray(force_N, dtype=np.float64)
        offs, wts = self.disc_points(diameter_mm)
        uniq, inv = contact_positions(center_mm, f.size)
        per_pos = np.empty((self.n_channels, len(uniq)))
        for k in range(0, len(uniq), 32):  # 32 positions x disc points per vectorised call
            u = uniq[k : k + 32]
            inf = self.influence((u[:, None, :] + offs[None]).reshape(-1, 2))
            per_pos[:, k : k + len(u)] = inf.reshape(self.n_channels, len(u), -1) @ wts
        return per_pos[:, inv] * f[None, :]

    # ------------------------------------------------------------------ readout
    def amplify(self, q_pC: np.ndarray, fs_in_hz: float, cf_pF: float) -> np.ndarray:
        """Charge amplifier V/q = -s R_f / (1 + s C_f R_f) then the 1 kHz low-pass (volts).

        Both ranges share the high-pass corner: the low range's feedback resistor is scaled by
        C_f / C_f,low so that R_f C_f stays the seed's 10 ms.
        """
        p = self.params
        tau = p.rf_Mohm * 1e6 * p.cf_pF * 1e-12
        a = np.exp(-1.0 / (fs_in_hz * tau))
        dq = np.diff(q_pC, prepend=q_pC[..., :1], axis=-1)
        v = -signal.lfilter([1.0], [1.0, -a], dq, axis=-1) / cf_pF  # pC / pF = V
        sos = _lowpass_sos(p.lowpass_hz, float(fs_in_hz)).copy()  # (sosfilt wants it writable)
        return signal.sosfilt(sos, v, axis=-1)

    def read(
        self,
        force_N: np.ndarray,
        center_mm: np.ndarray,
        diameter_mm: float,
        fs_in_hz: float,
        rng: np.random.Generator | None = None,
        skip: bool = True,
    ) -> np.ndarray:
        """Contact time course -> ``[12, samples]`` float32 equivalent charge (pC) at ``fs_hz``.

        ``skip``: simulate only what the scene needs: taxels whose charge is provably below
        :attr:`skip_tol_pC` for the whole contact (Boussinesq bound from the nearest contact
        point and the peak force) and time outside the contact plus 12 amplifier time constants
        (the response has decayed below 1e-5 of its value) output zeros plus noise. The noise
        draws are the same either way, so outputs agree within ``skip_tol_pC`` (tested).
        """
        p = self.params
        f = as_float_array(force_N, "force_N", ndim=1).astype(np.float64)
        check_finite(f, "force_N")
        fs_in = float(fs_in_hz)
        decim = check_decimation(fs_in_hz, p.fs_hz)
        check_positive(diameter_mm, "diameter_mm")
        uniq, inv = contact_positions(center_mm, f.size)
        c = uniq[inv]  # [samples, 2]
        n_out = -(-f.size // decim)
        spans, taxels = [slice(0, f.size)], np.arange(self.n_channels)
        if skip:
            spans, taxels = self._needed(f, c, diameter_mm, fs_in, decim)
        lsb = 2 * p.supply_V / 2**p.adc_bits
        outs = [np.zeros((self.n_channels, n_out)) for _ in range(2)]
        for span in spans if taxels.size else []:
            q = self.charge_pC(f[span], c[span], diameter_mm)[taxels]
            j0 = span.start // decim
            for out, cf in zip(outs, (p.cf_pF, p.cf_low_range_pF), strict=True):
                amp = self.amplify(q, fs_in, cf)[:, ::decim]
                out[taxels, j0 : j0 + amp.shape[1]] = amp
        for k, cf in enumerate((p.cf_pF, p.cf_low_range_pF)):
            v = outs[k]
            if rng is not None:
                v = v + p.noise_uV * 1e-6 * rng.standard_normal(v.shape)
            v = np.clip(np.round(v / lsb) * lsb, -p.supply_V, p.supply_V)
            outs[k] = -v * cf  # back to equivalent charge, pC
        high, low = outs
        saturated = np.abs(high) >= 0.9 * p.supply_V * p.cf_pF
        return np.where(saturated, low, high).astype(np.float32)

    def _needed(
        self, f: np.ndarray, c: np.ndarray, diameter_mm: float, fs_in: float, decim: int
    ) -> tuple[list[slice], np.ndarray]:
        """Active time spans (aligned to the decimation) and the taxels that can carry charge.

        A span runs from the zero-force sample before a contact to 12 amplifier time constants
        (+ 20 low-pass periods) after it; spans closer than that are merged.
        """
        active = np.flatnonzero(f != 0)
        if active.size == 0:
            return [], np.arange(0)
        p = self.params
        tau = p.rf_Mohm * 1e6 * p.cf_pF * 1e-12
        tail = int(12 * tau * fs_in) + int(20 * fs_in / p.lowpass_hz)
        breaks = np.flatnonzero(np.diff(active) > tail + 2 * decim)
        spans = []
        for first, last in zip(
            active[np.r_[0, breaks + 1]], active[np.r_[breaks, -1]], strict=True
        ):
            # start on a zero-force sample: the amplifier sees the first step in full
            start = ((first - 1) // decim) * decim if first > 0 else 0
            spans.append(slice(int(start), int(min(f.size, last + 1 + tail))))
        # nearest approach of the contact disc to each taxel's film (corner), mm
        reach = diameter_mm / 2 + p.film_mm / np.sqrt(2)
        dist = np.linalg.norm(self.taxels_mm[:, None, :] - c[active][None], axis=-1).min(1)
        r = np.maximum(dist - reach, 0.0)
        bound = boussinesq_t3(np.abs(f).max(), r, p.cover_mm) * (p.film_mm * 1e-3) ** 2
        bound = np.abs(p.d33_pC_per_N * bound)
        return spans, np.flatnonzero(bound >= self.skip_tol_pC)


def reconstruct_forces(
    sensor: PVDFTriangle, charges_pC: np.ndarray, grid_mm: np.ndarray | None = None
) -> np.ndarray:
    """Point forces (N, >= 0) on ``grid_mm`` (default: the taxel sites) from taxel charges.

    ``b = C x`` with C the Boussinesq influence matrix; the unconstrained solution is the
    Moore-Penrose pseudo-inverse; where it yields tensile (negative) forces, the compressive
    constraint is enforced by non-negative least squares.
    """
    grid = sensor.taxels_mm if grid_mm is None else np.asarray(grid_mm, dtype=np.float64)
    c = sensor.influence(grid)  # [12, G] pC per N
    b = np.asarray(charges_pC, dtype=np.float64)
    x = np.linalg.pinv(c) @ b
    if np.all(x >= -1e-12):
        return np.maximum(x, 0.0)
    return optimize.nnls(c, b)[0]
