"""Capacitive-piezoelectric tandem sensor stack (seed 001, SPEC 2.1).

Array contract of :meth:`CapacitivePiezoStack.read`:
    in:  ``pressure_Pa`` ``[samples_in]`` (float, Pa) at ``fs_in_hz`` (the scene's simulation rate,
         an integer multiple of the 200 samples/s readout rate);
    out: ``[2, samples_out]`` float32 at ``fs_hz`` = 200 samples/s:
         channel 0 ``static``: relative capacitance change ``(C - C_base) / C_base`` (dimensionless)
         of the capacitive (SA-like) channel read through the CTMU and a 10-bit ADC;
         channel 1 ``dynamic``: baseline-corrected, rectified piezo amplifier output, relative to the
         amplifier's bias voltage (dimensionless, FA-like), 10-bit ADC.
    Baselines are the mean of the first ``baseline_s`` = 1.5 s of each channel, as in the seed.

Static channel physics: two elastomer layers in series, ``1/C_SG = 2 (1/C_LME + 1/C_HME)``, each a
parallel-plate capacitor ``C = eps0 eps_r A / (2 d)`` whose gap shrinks with strain. The low-modulus
layer (LME) compresses first and saturates at ``lme_max_strain``; the high-modulus layer (HME) stays
linear. The defaults reproduce the seed's measured relative sensitivity, 0.25 kPa^-1 below 100 Pa
falling to 0.002 kPa^-1 near 2.5 kPa. Viscoelastic creep is a first-order lag (settles ~300 ms
after a step). Readout: CTMU charges the sensor with ``I_C`` = 55 uA for ``dt`` = 10 us,
``dV = I_C dt / C``, digitised by a 10-bit ADC, and ``C = I_C dt / dV`` is recovered from the code.

Dynamic channel physics: piezo charge ``Q = d33 F`` on the extended gate, leaking through the gate
resistance (high-pass, responds only to change), scaled to the seed's 2.28 kPa^-1 relative
sensitivity, then a common-source MOSFET amplifier that is linear on the positive half-cycle and
compresses the negative half-cycle towards cut-off, its output pole, and a 10-bit ADC sampling at
200 samples/s.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from scipy import signal

from ...core.checks import as_float_array, check_decimation, check_finite, check_positive
from ..scenes.inputs import PressureSeries
from .base import SensorParams, check_scene, register_sensor

EPS0_F_PER_M = 8.8541878128e-12


@dataclass(frozen=True)
class CapacitivePiezoParams(SensorParams):
    """Parameters of the stack and its readout chain; defaults are seed 001's values."""

    #: electronic-noise fields, scaled together by :func:`~.base.noise_scaled`
    NOISE_FIELDS: ClassVar[tuple[str, ...]] = ("static_noise_rel", "dynamic_noise_rel")

    # --- dual-elastomer capacitive channel ---
    # area and gaps put C_SG(0) ~ 220 pF, inside the CTMU's range (dV = I_C dt / C < Vref)
    area_m2: float = 4.0e-4
    lme_thickness_m: float = 6e-6
    lme_eps_r: float = 3.0
    lme_modulus_Pa: float = 2.0e3  # initial (small-strain) modulus of the low-modulus elastomer
    lme_max_strain: float = 0.2  # LME compression saturates at this strain
    hme_thickness_m: float = 6e-6
    hme_eps_r: float = 3.0
    hme_modulus_Pa: float = 4.5e5
    creep_tau_s: float = 0.1  # first-order viscoelastic lag: 95 % settled after 3 tau = 300 ms
    parasitic_F: float = 0.0
    # --- CTMU readout (PIC18F45K22) ---
    ctmu_current_A: float = 55e-6
    ctmu_time_s: float = 10e-6
    adc_bits: int = 10
    adc_vref_V: float = 3.3
    # --- piezoelectric channel ---
    piezo_sensitivity_per_kPa: float = 2.28  # relative output change per kPa (seed 001)
    piezo_leak_tau_s: float = 0.02  # extended-gate leakage: high-pass at 1/(2 pi tau) ~ 8 Hz
    mosfet_negative_knee: float = 0.6  # relative swing at which the negative half compresses
    amplifier_pole_hz: float = 90.0  # output pole of the common-source stage
    amplifier_bias_V: float = 1.65  # relative units are (V - bias) / bias
    # --- noise (relative units, rms) ---
    static_noise_rel: float = 2e-4
    dynamic_noise_rel: float = 1.5e-3  # ~0.8 LSB of the 10-bit ADC
    # --- sampling ---
    fs_hz: float = 200.0
    baseline_s: float = 1.5
    channel_names: tuple[str, str] = field(default=("static", "dynamic"))

    def __post_init__(self) -> None:
        for name in (
            "area_m2",
            "lme_thickness_m",
            "lme_modulus_Pa",
            "hme_thickness_m",
            "hme_modulus_Pa",
            "creep_tau_s",
            "ctmu_current_A",
            "ctmu_time_s",
            "adc_vref_V",
            "piezo_leak_tau_s",
            "mosfet_negative_knee",
            "amplifier_pole_hz",
            "fs_hz",
            "baseline_s",
        ):
            check_positive(getattr(self, name), name)
        if not 0 < self.lme_max_strain < 1:
            raise ValueError(f"lme_max_strain must be in (0, 1), got {self.lme_max_strain}")


@register_sensor("capacitive_piezo")
class CapacitivePiezoStack:
    """One tandem stack (one taxel) -> two channels (static capacitive, dynamic piezo)."""

    units: ClassVar[str] = "relative units ((V - bias) / bias)"
    scene_type: ClassVar[type] = PressureSeries

    def output_rate_hz(self, scene: PressureSeries) -> float:
        return self.fs_hz

    def read_scene(
        self, scene: PressureSeries, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        """The :class:`~..sensors.base.SensorModel` form of :meth:`read`."""
        check_scene(self, scene)
        return self.read(scene.pressure_Pa, scene.fs_in_hz, rng)

    n_channels = 2

    def __init__(self, params: CapacitivePiezoParams | None = None) -> None:
        self.params = params or CapacitivePiezoParams()

    @classmethod
    def with_noise_scale(cls, scale: float) -> CapacitivePiezoStack:
        """Seed 001's stack with both channels' electronic noise multiplied by ``scale``."""
        from .base import noise_scaled

        return cls(noise_scaled(CapacitivePiezoParams(), scale))

    @property
    def fs_hz(self) -> float:
        return self.params.fs_hz

    @property
    def channel_names(self) -> tuple[str, str]:
        return self.params.channel_names

    # ------------------------------------------------------------------ static channel physics
    def lme_strain(self, pressure_Pa: np.ndarray) -> np.ndarray:
        """Strain of the low-modulus layer: slope 1/Y at small P, saturating at max strain."""
        p = self.params
        s = p.lme_max_strain
        return s * -np.expm1(-np.maximum(pressure_Pa, 0.0) / (p.lme_modulus_Pa * s))

    def hme_strain(self, pressure_Pa: np.ndarray) -> np.ndarray:
        """Strain of the high-modulus layer (linear, capped below full compression)."""
        p = self.params
        return np.minimum(np.maximum(pressure_Pa, 0.0) / p.hme_modulus_Pa, 0.9)

    def capacitance_F(self, pressure_Pa: np.ndarray | float) -> np.ndarray:
        """Quasi-static signal-ground capacitance C_SG(P) in farads (SPEC 2.1 equations)."""
        p = self.params
        pr = np.asarray(pressure_Pa, dtype=np.float64)
        c_lme = EPS0_F_PER_M * p.lme_eps_r * p.area_m2 / (2 * p.lme_thickness_m)
        c_hme = EPS0_F_PER_M * p.hme_eps_r * p.area_m2 / (2 * p.hme_thickness_m)
        # C_XME(P) = eps0 eps A / (2 d0 (1 - strain))
        inv = 2 * ((1 - self.lme_strain(pr)) / c_lme + (1 - self.hme_strain(pr)) / c_hme)
        return 1.0 / inv + p.parasitic_F

    def relative_sensitivity_per_kPa(self, pressure_Pa: np.ndarray | float) -> np.ndarray:
        """(1/C0) dC/dP in kPa^-1, by a central difference of :meth:`capacitance_F`."""
        pr = np.asarray(pressure_Pa, dtype=np.float64)
        h = np.maximum(1e-3 * pr, 1e-3)
        c0 = self.capacitance_F(0.0)
        dc = (self.capacitance_F(pr + h) - self.capacitance_F(np.maximum(pr - h, 0.0))) / (
            pr + h - np.maximum(pr - h, 0.0)
        )
        return dc / c0 * 1e3

    def ctmu_code(self, capacitance_F: np.ndarray) -> np.ndarray:
        """10-bit ADC code of the CTMU voltage dV = I_C dt / C (clipped at the reference)."""
        p = self.params
        dv = p.ctmu_current_A * p.ctmu_time_s / capacitance_F
        levels = 2**p.adc_bits - 1
        return np.clip(np.round(dv / p.adc_vref_V * levels), 1, levels)

    def capacitance_from_code(self, code: np.ndarray) -> np.ndarray:
        """Invert the CTMU reading: C = I_C dt / dV (SPEC 2.1, seed 001 eq. 1)."""
        p = self.params
        dv = code / (2**p.adc_bits - 1) * p.adc_vref_V
        return p.ctmu_current_A * p.ctmu_time_s / dv

    # ------------------------------------------------------------------ dynamic channel physics
    def piezo_relative(self, pressure_Pa: np.ndarray, fs_in_hz: float) -> np.ndarray:
        """Extended-gate piezo voltage, relative units, before the amplifier nonlinearity.

        Q = d33 F leaks through the gate resistance: a first-order high-pass with time constant
        ``piezo_leak_tau_s``, scaled so a fast pressure step of dP kPa peaks at 2.28 * dP.
        """
        p = self.params
        alpha = np.exp(-1.0 / (fs_in_hz * p.piezo_leak_tau_s))
        # y[n] = alpha (y[n-1] + x[n] - x[n-1]): exact response of the RC high-pass to steps
        dx = np.diff(pressure_Pa, prepend=pressure_Pa[..., :1], axis=-1)
        y = signal.lfilter([1.0], [1.0, -alpha], dx, axis=-1)
        return y * (p.piezo_sensitivity_per_kPa / 1e3)

    def mosfet_amplifier(self, v_rel: np.ndarray) -> np.ndarray:
        """Common-source stage: linear for positive swings, soft compression of the negative half."""
        k = self.params.mosfet_negative_knee
        return np.where(v_rel >= 0, v_rel, k * np.tanh(v_rel / k))

    def adc_relative(self, v_rel: np.ndarray) -> np.ndarray:
        """10-bit ADC over 0..Vref of the amplifier output, returned in relative units."""
        p = self.params
        levels = 2**p.adc_bits - 1
        volts = p.amplifier_bias_V * (1.0 + v_rel)
        code = np.clip(np.round(volts / p.adc_vref_V * levels), 0, levels)
        return code / levels * p.adc_vref_V / p.amplifier_bias_V - 1.0

    # ------------------------------------------------------------------ full readout
    def read(
        self, pressure_Pa: np.ndarray, fs_in_hz: float, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        """Pressure time course at ``fs_in_hz`` -> ``[2, samples]`` float32 at 200 samples/s.

        ``rng`` draws the electronic noise; pass ``None`` for a noise-free reading.
        """
        p = self.params
        pr = as_float_array(pressure_Pa, "pressure_Pa", ndim=1).astype(np.float64)
        check_finite(pr, "pressure_Pa")
        fs_in = float(fs_in_hz)
        decim = check_decimation(fs_in_hz, p.fs_hz)
        n_base = round(p.baseline_s * p.fs_hz)
        if pr.size // decim <= n_base:
            raise ValueError(
                f"stimulus too short: {pr.size / fs_in:.3f} s, need more than the "
                f"{p.baseline_s} s baseline"
            )
        # static: creep lag -> C(P) -> CTMU -> ADC (sampled)
        a = np.exp(-1.0 / (fs_in * p.creep_tau_s))
        p_lag = signal.lfilter([1 - a], [1, -a], pr, zi=[a * pr[0]])[0]
        c = self.capacitance_F(p_lag[::decim])
        if rng is not None:
            c = c * (1.0 + p.static_noise_rel * rng.standard_normal(c.shape))
        c_read = self.capacitance_from_code(self.ctmu_code(c))
        c_base = c_read[:n_base].mean()
        static = (c_read - c_base) / c_base
        # dynamic: piezo high-pass -> MOSFET -> output pole -> sample -> noise -> ADC
        v = self.mosfet_amplifier(self.piezo_relative(pr, fs_in))
        b = np.exp(-2 * np.pi * p.amplifier_pole_hz / fs_in)
        v = signal.lfilter([1 - b], [1, -b], v)[::decim]
        if rng is not None:
            v = v + p.dynamic_noise_rel * rng.standard_normal(v.shape)
        v = self.adc_relative(v)
        dynamic = np.abs(v - v[:n_base].mean())
        return np.stack([static, dynamic]).astype(np.float32)
