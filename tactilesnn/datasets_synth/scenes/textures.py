"""Surface textures as spatial asperity-pressure profiles, seen through fingerprint ridges.

A texture realisation is a function of position along the scan strip, sampled on a regular grid of
``dx_mm``. Forward and reverse strides traverse the same physical strip, so one realisation serves
both; stick-slip (catch-and-release) is direction dependent, so textures return one profile per
direction. Profiles are dimensionless shape functions (O(1) amplitude); the scene scales them to
pressure in Pa with the normal load.

Fingerprint ridges (seed 001): 500 um wide, 2 mm long, vertical pitch 1.5 mm (along the scan),
horizontal pitch 3 mm with alternate rows staggered. Along the scan direction they act as a comb of
``n_rows`` boxes 0.5 mm wide at 1.5 mm pitch: the force on the stack is the texture profile
convolved with that comb, which emphasises spatial periods near the ridge pitch (temporal
frequency v / 1.5 mm, 67 Hz at 10 cm/s) and their neighbourhood.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RIDGE_WIDTH_MM = 0.5
RIDGE_PITCH_MM = 1.5


def ridge_comb_kernel(n_rows: int, dx_mm: float) -> np.ndarray:
    """Spatial kernel of ``n_rows`` fingerprint ridges (boxes 0.5 mm wide, 1.5 mm pitch), sum 1."""
    if n_rows < 1:
        raise ValueError(f"n_rows must be >= 1, got {n_rows}")
    length = round(((n_rows - 1) * RIDGE_PITCH_MM + RIDGE_WIDTH_MM) / dx_mm) + 1
    x = np.arange(length) * dx_mm
    k = (np.mod(x, RIDGE_PITCH_MM) < RIDGE_WIDTH_MM).astype(np.float64)
    return k / k.sum()


def _bumps(n: int, dx_mm: float, centres_mm: np.ndarray, amps: np.ndarray, width_mm: float):
    """Sum of raised-cosine bumps of full width ``width_mm`` on a grid of ``n`` points."""
    out = np.zeros(n)
    half = max(1, round(width_mm / (2 * dx_mm)))
    offs = np.arange(-half, half + 1)
    shape = 0.5 * (1 + np.cos(np.pi * offs / (half + 1)))
    idx = np.round(centres_mm / dx_mm).astype(int)[:, None] + offs[None, :]
    ok = (idx >= 0) & (idx < n)
    np.add.at(out, idx[ok], (amps[:, None] * shape[None, :])[ok])
    return out


def _sawtooth_events(
    n: int, dx_mm: float, starts_mm: np.ndarray, lengths_mm: np.ndarray, amps: np.ndarray
) -> np.ndarray:
    """Catch-and-release: force ramps over the catch length, then drops at release."""
    out = np.zeros(n)
    for s, ln, a in zip(starts_mm, lengths_mm, amps, strict=True):
        i0 = int(s / dx_mm)
        i1 = min(n, int((s + ln) / dx_mm))
        if i1 > i0 >= 0:
            out[i0:i1] += a * np.linspace(0.0, 1.0, i1 - i0, endpoint=False)
    return out


@dataclass(frozen=True)
class HookTexture:
    """Hook side of a hook-and-loop fastener: rows of stiff, fine hooks.

    Stiff asperities give short, regular taps: a quasi-periodic train of narrow bumps at the hook-row
    pitch (71 Hz at 10 cm/s for 1.4 mm), with row-to-row jitter and amplitude spread, over a faint
    fine roughness. Amplitude grows weakly with normal load (stiff hooks barely deform).
    """

    row_pitch_mm: float = 1.4  # ~50 hooks per cm^2, typical of hook tape
    pitch_jitter: float = 0.08  # sd of row spacing, fraction of the pitch
    amp_spread: float = 0.2  # sd of log row amplitude
    hook_width_mm: float = 0.35
    roughness: float = 0.08
    load_exponent: float = 0.5
    name: str = "hook"

    def profiles(
        self, length_mm: float, dx_mm: float, rng: np.random.Generator, irregularity: float = 1.0
    ) -> tuple[np.ndarray, np.ndarray]:
        n = int(np.ceil(length_mm / dx_mm))
        gaps = self.row_pitch_mm * (
            1 + irregularity * self.pitch_jitter * rng.standard_normal(int(length_mm / 1.0) + 4)
        )
        centres = np.cumsum(np.maximum(gaps, 0.3 * self.row_pitch_mm)) - rng.uniform(0, 2.5)
        centres = centres[centres < length_mm]
        amps = np.exp(irregularity * self.amp_spread * rng.standard_normal(centres.size))
        prof = _bumps(n, dx_mm, centres, amps, self.hook_width_mm)
        prof += irregularity * self.roughness * _smooth_noise(n, dx_mm, 0.3, rng)
        return prof, prof  # stiff hooks: same taps in both directions


@dataclass(frozen=True)
class LoopTexture:
    """Loop side: soft pile of loops that catch the ridges and release (stick-slip bursts).

    Loops catch at random positions (mean spacing ``event_spacing_mm``), stretch over a catch length
    and release abruptly: a train of sawtooth events with a heavy-tailed amplitude distribution,
    larger than the hook taps on average (seed 001: loop gives the higher amplitude), over a soft,
    low-pass pile roughness. Catch direction flips with the stride direction.
    """

    event_spacing_mm: float = 4.0
    catch_mm: tuple[float, float] = (0.5, 3.0)
    amp_shape: float = 0.7  # gamma shape of release amplitudes: heavy tail = bursts
    mean_amp: float = 2.5
    pile_roughness: float = 0.35
    load_exponent: float = 0.8
    name: str = "loop"

    def profiles(
        self, length_mm: float, dx_mm: float, rng: np.random.Generator, irregularity: float = 1.0
    ) -> tuple[np.ndarray, np.ndarray]:
        n = int(np.ceil(length_mm / dx_mm))
        out = []
        pile = self.pile_roughness * _smooth_noise(n, dx_mm, 1.5, rng)
        for _direction in range(2):
            count = rng.poisson(length_mm / self.event_spacing_mm)
            starts = rng.uniform(0, length_mm, count)
            lo, hi = self.catch_mm
            lengths = rng.uniform(lo, hi, count)
            k = self.amp_shape
            amps = self.mean_amp * rng.gamma(k, 1.0 / k, count)
            saw = _sawtooth_events(n, dx_mm, starts, lengths, amps)
            out.append(saw + pile)
        forward, reverse_raw = out
        # a loop stretched by a reverse stride ramps the other way along x
        reverse = reverse_raw[::-1].copy()
        return forward, reverse


def _smooth_noise(n: int, dx_mm: float, corr_mm: float, rng: np.random.Generator) -> np.ndarray:
    """Unit-variance Gaussian noise with Gaussian spatial correlation length ``corr_mm``."""
    w = rng.standard_normal(n + 64)
    sigma = max(corr_mm / dx_mm, 1.0)
    half = int(3 * sigma)
    g = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma) ** 2)
    sm = np.convolve(w, g / np.sqrt((g**2).sum()), mode="same")[32 : 32 + n]
    return sm


@dataclass(frozen=True)
class Grating:
    """Parametric grating: raised-cosine ridges of ``period_mm`` and relative ``depth``.

    Duty cycle ``duty`` (ridge width / period); irregularity jitters the period by 3 % and the
    ridge heights by 10 % (machining / printing tolerance).
    """

    name: str
    period_mm: float
    depth: float = 1.0
    duty: float = 0.5
    load_exponent: float = 0.5

    def profiles(
        self, length_mm: float, dx_mm: float, rng: np.random.Generator, irregularity: float = 1.0
    ) -> tuple[np.ndarray, np.ndarray]:
        n = int(np.ceil(length_mm / dx_mm))
        count = int(length_mm / self.period_mm) + 3
        gaps = self.period_mm * (1 + 0.03 * irregularity * rng.standard_normal(count))
        centres = np.cumsum(gaps) - rng.uniform(0, self.period_mm)
        amps = self.depth * (1 + 0.1 * irregularity * rng.standard_normal(count))
        prof = _bumps(n, dx_mm, centres, amps, self.duty * self.period_mm)
        return prof, prof


@dataclass(frozen=True)
class RandomRough:
    """Random rough surface with a power-law height spectrum ``S(k) ~ k^-(2H+1)`` above
    ``1 / corr_mm`` (self-affine, Hurst exponent ``hurst``) and flat below it; unit rms x ``rms``.
    """

    name: str
    corr_mm: float
    hurst: float = 0.8
    rms: float = 0.6
    load_exponent: float = 0.7

    def profiles(
        self, length_mm: float, dx_mm: float, rng: np.random.Generator, irregularity: float = 1.0
    ) -> tuple[np.ndarray, np.ndarray]:
        n = int(np.ceil(length_mm / dx_mm))
        k = np.fft.rfftfreq(n, dx_mm)  # cycles / mm
        k0 = 1.0 / self.corr_mm
        amp = np.where(k < k0, 1.0, (np.maximum(k, 1e-12) / k0) ** (-(2 * self.hurst + 1) / 2))
        amp[0] = 0.0
        spec = amp * (rng.standard_normal(k.size) + 1j * rng.standard_normal(k.size))
        h = np.fft.irfft(spec, n)
        h = self.rms * h / (h.std() + 1e-12)
        prof = np.maximum(h + self.rms, 0.0)  # only asperities above the mean plane touch
        return prof, prof


@dataclass(frozen=True)
class Fabric:
    """Woven / piled fabric: a weave of ``periods_mm`` (thread and float repeats) with relative
    ``weights``, soft fibres (low-pass ``fibre_mm``) and fuzz; knits/piles add stick-slip."""

    name: str
    periods_mm: tuple[float, ...]
    weights: tuple[float, ...]
    fuzz: float = 0.2
    fibre_mm: float = 0.15
    stick_slip: float = 0.0
    load_exponent: float = 0.8

    def profiles(
        self, length_mm: float, dx_mm: float, rng: np.random.Generator, irregularity: float = 1.0
    ) -> tuple[np.ndarray, np.ndarray]:
        n = int(np.ceil(length_mm / dx_mm))
        x = np.arange(n) * dx_mm
        prof = np.zeros(n)
        for per, w in zip(self.periods_mm, self.weights, strict=True):
            wobble = 0.02 * irregularity * per * _smooth_noise(n, dx_mm, 5 * per, rng)
            prof += w * (1 + np.cos(2 * np.pi * (x + wobble) / per + rng.uniform(0, 2 * np.pi)))
        prof += self.fuzz * _smooth_noise(n, dx_mm, self.fibre_mm, rng)
        k = max(1, round(self.fibre_mm / dx_mm))
        prof = np.convolve(prof, np.ones(k) / k, mode="same")
        fwd, rev = prof.copy(), prof.copy()
        if self.stick_slip:
            count = rng.poisson(length_mm / 3.0)
            for out in (fwd, rev):
                starts = rng.uniform(0, length_mm, count)
                lengths = rng.uniform(0.3, 1.5, count)
                amps = self.stick_slip * rng.gamma(1.0, 1.0, count)
                out += _sawtooth_events(n, dx_mm, starts, lengths, amps)
            rev = rev[::-1].copy()
        return np.maximum(fwd, 0.0), np.maximum(rev, 0.0)


TEXTURES = {
    t.name: t
    for t in (
        HookTexture(),
        LoopTexture(),
        Grating("grating_1mm", 1.0),
        Grating("grating_2mm", 2.0),
        Grating("grating_4mm", 4.0),
        Grating("grating_2mm_shallow", 2.0, depth=0.35, duty=0.3),
        RandomRough("rough_fine", corr_mm=0.3),
        RandomRough("rough_coarse", corr_mm=2.0),
        Fabric("denim", periods_mm=(0.8, 2.4), weights=(1.0, 0.5)),
        Fabric("corduroy", periods_mm=(3.0,), weights=(1.5,), fuzz=0.3),
        Fabric("knit", periods_mm=(1.2,), weights=(0.6,), fuzz=0.3, stick_slip=1.0),
        Fabric("felt", periods_mm=(), weights=(), fuzz=0.8, fibre_mm=0.5),
    )
}
