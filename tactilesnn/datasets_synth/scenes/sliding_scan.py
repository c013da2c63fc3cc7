"""Closed-loop sliding-scan scene (seed 001 protocol): what the fingertip presses on, and when.

A scan visits two textures in turn. For each: approach until the closed loop reaches the normal
pressure set point, 9 strides of 6 cm at ~10 cm/s alternating forward and reverse, retract, then a
transition to the next texture. The scene returns the pressure on the tandem stack at the
simulation rate and per-sample labels; it knows nothing about the sensor's readout.

Array contract of :meth:`SlidingScanScene.render`:
    ``pressure_Pa``: ``[samples]`` float64, Pa, at ``fs_sim_hz`` (2 kHz);
    ``labels``: ``[samples]`` int8, texture index in the scene's ``textures`` order, or -1 for no
    texture (no contact, transitions, and the 250 ms null bands at texture on/offsets).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import filtfilt

from .textures import TEXTURES, ridge_comb_kernel

SURFACES = ("planar", "concave", "convex")


@dataclass(frozen=True)
class ScanProtocol:
    """Timing and motion of one scan (seed 001 section 2.5); lengths in mm, times in s."""

    fs_sim_hz: float = 2000.0
    baseline_s: float = 2.0  # no contact: the readout's 1.5 s baseline fits inside
    approach_s: float = 0.4
    retract_s: float = 0.3
    transition_s: float = 0.8
    tail_s: float = 0.5
    stride_mm: float = 60.0
    n_strides: int = 9
    speed_mm_s: float = 100.0
    accel_mm_s2: float = 3000.0  # stride reversal: 33 ms to reach 10 cm/s
    dwell_s: float = 0.03  # pause at each turnaround
    null_band_s: float = 0.25  # seed 001: 250 ms null labels at texture on/offsets
    dx_mm: float = 0.02  # spatial grid of texture profiles


@dataclass(frozen=True)
class ScanVariability:
    """Scan-to-scan and within-scan variability.

    Amplitude nuisances (what defeats an amplitude-only classifier; scaled by the task's
    ``amplitude_spread``): ``pressure_log_range``: set point = centre * exp(U(-r, r)) (1 kPa), held per scan
    by the closed loop; ``gain_log_sd``: sd of the log coupling gain (mounting, curvature, wear).

    Spectral nuisances (scaled by the task's ``difficulty``): ``speed_sd``: stride-to-stride speed
    sd, fraction (UR5 trajectory); ``speed_jitter``: within-stride PID jitter; ``ripple``: normal
    load ripple of the Z loop, fraction, planar / curved; ``irregularity``: texture irregularity
    (hook-row jitter and amplitude spread, pile roughness).
    """

    pressure_log_range: float = 0.7
    gain_log_sd: float = 0.35
    speed_sd: float = 0.04
    speed_jitter: float = 0.02
    ripple_planar: float = 0.01
    ripple_curved: float = 0.04
    irregularity: float = 0.5

    def scaled(self, difficulty: float, amplitude_spread: float) -> ScanVariability:
        """Copy with spectral nuisances times ``difficulty``, amplitude ones times the spread."""
        return ScanVariability(
            pressure_log_range=self.pressure_log_range * amplitude_spread,
            gain_log_sd=self.gain_log_sd * amplitude_spread,
            speed_sd=self.speed_sd * difficulty,
            speed_jitter=self.speed_jitter * difficulty,
            ripple_planar=self.ripple_planar * difficulty,
            ripple_curved=self.ripple_curved * difficulty,
            irregularity=self.irregularity * difficulty,
        )


@dataclass(frozen=True)
class SlidingScanScene:
    """Fingertip with fingerprint ridges sliding over textures on a planar/concave/convex surface."""

    textures: tuple[str, ...] = ("hook", "loop")
    surface: str = "planar"
    protocol: ScanProtocol = field(default_factory=ScanProtocol)
    variability: ScanVariability = field(default_factory=ScanVariability)
    base_dynamic_Pa: float = 40.0  # asperity pressure of a unit texture profile at 1 kPa load
    #: the load set point's centre (Pa); each scan's set point varies about it
    #: (``ScanVariability.pressure_log_range``)
    set_point_Pa: float = 1000.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.set_point_Pa) and self.set_point_Pa > 0):
            raise ValueError(f"set_point_Pa must be a finite pressure > 0, got {self.set_point_Pa}")
        if self.surface not in SURFACES:
            raise ValueError(f"unknown surface {self.surface!r}; choose one of: {SURFACES}")
        for t in self.textures:
            if t not in TEXTURES:
                raise ValueError(f"unknown texture {t!r}; choose one of: {sorted(TEXTURES)}")

    def _stride_velocity(self, v: float, rng: np.random.Generator) -> np.ndarray:
        """Speed profile (mm/s, >= 0) of one stride: trapezoid + PID jitter, then a dwell."""
        pr = self.protocol
        fs = pr.fs_sim_hz
        t_acc = v / pr.accel_mm_s2
        d_acc = v * t_acc  # accel + decel distance
        t_cruise = max(pr.stride_mm - d_acc, 0.0) / v
        t = np.arange(0, 2 * t_acc + t_cruise, 1 / fs)
        prof = np.minimum.reduce([t / t_acc, np.ones_like(t), (2 * t_acc + t_cruise - t) / t_acc])
        vel = v * np.clip(prof, 0, 1)
        jitter = self.variability.speed_jitter * _lowpass_noise(vel.size, fs, 5.0, rng)
        vel = vel * (1 + jitter)
        vel *= pr.stride_mm / (vel.sum() / fs)  # the stage travels exactly one stride
        return np.concatenate([vel, np.zeros(int(pr.dwell_s * fs))])

    def render(
        self, rng: np.random.Generator, order: tuple[int, ...] | None = None
    ) -> tuple[np.ndarray, np.ndarray, dict]:
        """Return ``(pressure_Pa, labels, info)`` for one scan; ``order`` = texture visiting order."""
        pr, var = self.protocol, self.variability
        fs = pr.fs_sim_hz
        order = tuple(range(len(self.textures))) if order is None else order
        p_set = self.set_point_Pa * np.exp(rng.uniform(-1, 1) * var.pressure_log_range)
        ripple = var.ripple_planar if self.surface == "planar" else var.ripple_curved
        # contact length (rows of ridges touching): a concave surface wraps the fingertip
        base_rows = {"planar": 4, "concave": 5, "convex": 3}[self.surface]
        pieces_p: list[np.ndarray] = [np.zeros(int(pr.baseline_s * fs))]
        pieces_l: list[np.ndarray] = [np.full(pieces_p[0].size, -1, np.int8)]
        info: dict = {"pressure_set_Pa": p_set, "surface": self.surface, "segments": []}
        strip_len = pr.stride_mm + 20.0
        for k, tex_idx in enumerate(order):
            tex = TEXTURES[self.textures[tex_idx]]
            n_rows = int(np.clip(base_rows + rng.integers(-1, 2), 2, 6))
            gain = np.exp(var.gain_log_sd * rng.standard_normal())
            fwd, rev = tex.profiles(strip_len, pr.dx_mm, rng, var.irregularity)
            comb = ridge_comb_kernel(n_rows, pr.dx_mm)
            fwd = np.convolve(fwd, comb, mode="same")
            rev = np.convolve(rev, comb, mode="same")
            x0 = 10.0  # strip margin, mm
            vels, dirs = [], []
            for s in range(pr.n_strides):
                v = pr.speed_mm_s * (1 + var.speed_sd * rng.standard_normal())
                vel = self._stride_velocity(max(v, 0.3 * pr.speed_mm_s), rng)
                vels.append(vel)
                dirs.append(np.full(vel.size, 1 if s % 2 == 0 else -1, np.int8))
            vel = np.concatenate(vels)
            direction = np.concatenate(dirs)
            x = x0 + np.cumsum(np.where(direction > 0, vel, -vel)) / fs
            grid = np.arange(fwd.size) * pr.dx_mm
            prof = np.where(direction > 0, np.interp(x, grid, fwd), np.interp(x, grid, rev))
            # normal load under closed-loop control: set point + slow ripple of the Z loop
            n_slide = x.size
            load = p_set * (1 + ripple * _lowpass_noise(n_slide, fs, 2.0, rng))
            dyn = (
                self.base_dynamic_Pa
                * gain
                * (load / 1000.0) ** tex.load_exponent
                * np.maximum(prof, 0.0)
            )
            n_app = int(pr.approach_s * fs)
            ramp_up = p_set * 0.5 * (1 - np.cos(np.linspace(0, np.pi, n_app)))
            ramp_dn = ramp_up[::-1] * load[-1] / p_set
            seg_p = np.concatenate([ramp_up, load + dyn, ramp_dn])
            seg_l = np.full(seg_p.size, -1, np.int8)
            nb = int(pr.null_band_s * fs)
            seg_l[n_app + nb : n_app + n_slide - nb] = tex_idx
            start = sum(p.size for p in pieces_p)
            info["segments"].append(
                {
                    "texture": tex.name,
                    "t_on_s": (start + n_app) / fs,
                    "t_off_s": (start + n_app + n_slide) / fs,
                    "ridge_rows": n_rows,
                    "gain": float(gain),
                }
            )
            pieces_p.append(seg_p)
            pieces_l.append(seg_l)
            gap = pr.transition_s if k < len(order) - 1 else pr.tail_s
            pieces_p.append(np.zeros(int(gap * fs)))
            pieces_l.append(np.full(int(gap * fs), -1, np.int8))
        return np.concatenate(pieces_p), np.concatenate(pieces_l), info


def _lowpass_noise(n: int, fs: float, cutoff_hz: float, rng: np.random.Generator) -> np.ndarray:
    """Unit-rms Gaussian noise band-limited to ``cutoff_hz`` (first-order, run both ways)."""
    a = np.exp(-2 * np.pi * cutoff_hz / fs)
    w = rng.standard_normal(n + 400)
    y = filtfilt([1 - a], [1, -a], w)[400:]
    return y / (y.std() + 1e-12)
