"""The encoders' settings: one frozen dataclass per registered encoder, declared without torch.

The command line, settings files and sweeps are built from these declarations
(:mod:`tactilesnn.core.settings`), so a mistyped flag is answered before torch is imported. Each
encoder's module (:mod:`tactilesnn.encoders`) registers its class under the name declared here
(:data:`ENCODERS`); adding an encoder is its module, its settings class below and one
``ENCODERS.declare`` line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..core.checks import check_choice, check_int, check_positive
from ..core.registry import Registry
from ..core.settings import ComponentSettings, setting

ENCODERS: Registry = Registry("encoder")

#: per-band statistics of the latency code (:mod:`tactilesnn.encoders.latency`)
LATENCY_STATS = ("mean", "std", "max")
#: amplitude -> latency mappings
MAPPINGS = ("log", "linear")
#: the LIF population's reference level
NORMS = ("train", "window")
#: which spikes a fixed number of slots keeps (LIF population, events)
KEEPS = ("spread", "first")
#: filter banks of the band code (``tactilesnn.encoders.band_code.TRANSFORMS``; a test keeps
#: them equal)
TRANSFORM_NAMES = ("cgwt", "gwt", "stft")
#: encoders of analog channels that code band envelopes (``codes_envelopes``; a test keeps them)
ENVELOPE_CODES = ("delta", "lif")
#: the level code's scales (:mod:`tactilesnn.encoders.level`)
LEVEL_SCALES = ("rank", "linear", "rank+linear", "wide")


def check_bands(f_lo_hz: float, f_hi_hz: float, n_bands: int, most: int) -> None:
    """A band range (Hz, ``0 < f_lo_hz < f_hi_hz``) of ``1..most`` bands, else ValueError."""
    check_positive(f_lo_hz, "f_lo_hz")
    check_positive(f_hi_hz, "f_hi_hz")
    if not f_lo_hz < f_hi_hz:
        raise ValueError(f"f_lo_hz ({f_lo_hz}) must be below f_hi_hz ({f_hi_hz})")
    check_int(n_bands, "n_bands", 1)
    if n_bands > most:
        raise ValueError(f"n_bands must be <= {most}, got {n_bands}")


@dataclass(frozen=True)
class ScalogramLatencySettings(ComponentSettings):
    """Bands (Hz) and the latency code; shared by the GWT and STFT encoders."""

    f_lo_hz: float = setting(3.0, help="lowest band centre (Hz)")
    # capped at 0.45 fs (the Gabor bands' unit-sinusoid convention)
    f_hi_hz: float = setting(
        90.0, help="highest band centre (Hz; capped at 0.45 x the sampling rate)"
    )
    n_bands: int = setting(20, help="number of log-spaced bands")
    stats: tuple[str, ...] = setting(
        ("mean", "std"), choices=LATENCY_STATS,
        help=f"per-band statistics, each one afferent ({', '.join(LATENCY_STATS)})",
    )  # fmt: skip
    mapping: str = setting(
        "log", choices=MAPPINGS, help=f"amplitude -> latency mapping ({', '.join(MAPPINGS)})"
    )
    dynamic_range_db: float = setting(
        30.0, help="log mapping: dB below the strongest band that still spike"
    )
    gate: float = setting(
        0.0,
        help="activity gate: a window's channel whose RMS about its mean is below gate x the "
        "channel's median training RMS is not transformed and stays silent (0 = off)",
    )
    passband_lo_hz: float = setting(
        0.0,
        help="band restriction: bands centred below the sensor's lower passband edge (Hz) are "
        "not transformed and stay silent (0 = none)",
    )
    passband_hi_hz: float = setting(
        0.0,
        help="band restriction: bands centred above the sensor's upper passband edge (Hz) are "
        "not transformed and stay silent (0 = none)",
    )

    follows_data: ClassVar[bool] = True

    @classmethod
    def data_defaults(cls, fs_hz: float, window: int, median_hz: float | None = None) -> dict:
        """Settings for windows of ``window`` samples at ``fs_hz`` whose training power has its
        median at ``median_hz`` (used by ``train --data`` when it picks the encoder): bands up
        to 0.45 fs (not the default task's 90 Hz), down to the median power frequency when that
        lies below the default 3 Hz (never below one cycle per window), at the default density
        (20 bands per 30x in frequency; 20 to 128 bands), and a 60 dB dynamic range instead of
        30 dB, so slow and weak parts of the spectrum still spike. The synthetic TENG material
        presses (3 s at 500 S/s, median power at 0.67 Hz) get 0.67-225 Hz in 34 bands; a window
        whose power lies above 3 Hz keeps 3 Hz."""
        f_lo = cls.f_lo_hz
        if median_hz is not None and median_hz < f_lo:
            f_lo = max(float(median_hz), float(fs_hz) / int(window))
        f_hi = 0.45 * float(fs_hz)
        density = cls.n_bands / math.log(cls.f_hi_hz / cls.f_lo_hz)  # bands per e-fold
        n = max(cls.n_bands, round(density * math.log(f_hi / f_lo)))
        return {"f_lo_hz": f_lo, "f_hi_hz": f_hi, "n_bands": int(min(n, 128)),
                "dynamic_range_db": 60.0}  # fmt: skip

    def __post_init__(self) -> None:
        check_bands(self.f_lo_hz, self.f_hi_hz, self.n_bands, 512)
        object.__setattr__(self, "stats", tuple(self.stats))
        if not self.stats:
            raise ValueError("stats must name at least one statistic")
        for st in self.stats:
            check_choice(st, "statistic", LATENCY_STATS)
        check_choice(self.mapping, "mapping", MAPPINGS)
        check_positive(self.dynamic_range_db, "dynamic_range_db")
        if not (np.isfinite(self.gate) and self.gate >= 0):
            raise ValueError(f"gate must be a finite number >= 0, got {self.gate}")
        for name in ("passband_lo_hz", "passband_hi_hz"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number of Hz >= 0, got {v}")
        if 0 < self.passband_hi_hz <= self.passband_lo_hz:
            raise ValueError(
                f"passband_hi_hz ({self.passband_hi_hz}) must be above passband_lo_hz "
                f"({self.passband_lo_hz})"
            )

    @property
    def passband_hz(self) -> tuple[float, float] | None:
        """The sensor's passband ``(lo, hi)`` in Hz, None if no edge is set."""
        if not (self.passband_lo_hz or self.passband_hi_hz):
            return None
        return (self.passband_lo_hz, self.passband_hi_hz or math.inf)


@dataclass(frozen=True)
class GWTConfig(ScalogramLatencySettings):
    """Gabor (complex Morlet, cmor1.5-1.0) scalogram -> latency code; the statistics are taken
    over the scalogram's frames, one every ``hop`` samples (exact decimation; 1 = every sample).
    The exported graph's scalogram matrices shrink by ``hop`` (``bench pareto``, GWT + SNN on
    1,000-sample windows of 12 taxels: 5.2 ms per window at hop 1, 0.58 ms at hop 10); the torch
    training path still transforms at full rate and decimates."""

    hop: int = setting(
        1, flag="gwt_hop",
        help="scalogram frame every hop samples (1 = every sample); the exported graph shrinks h "
        "times",
    )  # fmt: skip

    def __post_init__(self) -> None:
        super().__post_init__()
        check_int(self.hop, "hop", 1)


@dataclass(frozen=True)
class STFTConfig(ScalogramLatencySettings):
    """Hann STFT (frames of ``frame_samples``, 0 = the whole window) -> latency code."""

    frame_samples: int = setting(
        0, flag="stft_frame_samples",
        help="STFT frame length in samples (0 = the whole window, seed 001)",
    )  # fmt: skip
    level_off: bool = setting(
        True, flat=False, saved_before=False,
        help="each window less its first sample before the STFT (runs saved before the level "
        "was taken off load with it on: their spikes as they were)",
    )  # fmt: skip
    float64: bool = setting(
        True, flat=False, saved_before=False,
        help="the transform in float64, in torch and in the exported graph (runs saved before "
        "load with float32, as they were trained)",
    )  # fmt: skip

    def __post_init__(self) -> None:
        super().__post_init__()
        check_int(self.frame_samples, "frame_samples", 0)


@dataclass(frozen=True)
class CausalGWTConfig(ScalogramLatencySettings):
    """Causal recursive Gabor bank -> latency code. ``hop``: a frame every ``hop`` samples
    (0 = :func:`auto_hop`: from the highest band's envelope bandwidth); ``order``: poles per band."""

    hop: int = setting(
        0, flag="cgwt_hop",
        help="frame every hop samples (0 = from the highest band's envelope bandwidth)",
    )  # fmt: skip
    order: int = setting(
        4, flag="cgwt_order", help="poles per band of the causal Gabor bank (4: gammatone-like)"
    )
    level_off: bool = setting(
        True, flat=False, saved_before=False,
        help="each window less its first sample before the bank (runs saved before the level "
        "was taken off load with it on: their spikes as they were)",
    )  # fmt: skip

    def __post_init__(self) -> None:
        super().__post_init__()
        check_int(self.hop, "hop", 0)
        check_int(self.order, "order", 1)
        if self.order > 16:
            raise ValueError(f"order must be <= 16, got {self.order}")


@dataclass(frozen=True)
class BandCodeConfig(ComponentSettings):
    transform: str = setting(
        "gwt", flag="bands_transform", choices=TRANSFORM_NAMES,
        help="filter bank whose band envelopes are coded (gwt, cgwt, stft)",
    )  # fmt: skip
    code: str = setting(
        "lif", flag="bands_code", choices=ENVELOPE_CODES,
        help="encoder of analog channels that codes the envelopes (lif, delta)",
    )  # fmt: skip
    f_lo_hz: float = setting(3.0, help="lowest band centre (Hz)")
    f_hi_hz: float = setting(  # capped at 0.45 fs
        90.0, help="highest band centre (Hz; capped at 0.45 x the sampling rate)"
    )
    n_bands: int = setting(8, help="number of log-spaced bands")
    frames: int = setting(
        100, flag="bands_frames",
        help="envelope frames per window (the code's samples; at most one per sample)",
    )  # fmt: skip

    follows_data: ClassVar[bool] = True

    @classmethod
    def data_defaults(cls, fs_hz: float, window: int, median_hz: float | None = None) -> dict:
        """The scalogram encoders' band range for the data (:meth:`GWTConfig.data_defaults`) in
        at most ``n_bands`` bands, and at most one frame per sample."""
        d = GWTConfig.data_defaults(fs_hz, window, median_hz)
        return {"f_lo_hz": d["f_lo_hz"], "f_hi_hz": d["f_hi_hz"],
                "n_bands": min(int(d["n_bands"]), cls.n_bands),
                "frames": min(cls.frames, int(window))}  # fmt: skip

    def __post_init__(self) -> None:
        check_choice(self.transform, "transform", TRANSFORM_NAMES)
        check_choice(self.code, "code", ENVELOPE_CODES)
        check_bands(self.f_lo_hz, self.f_hi_hz, self.n_bands, 128)
        check_int(self.frames, "frames", 2)


@dataclass(frozen=True)
class DeltaConfig(ComponentSettings):
    threshold: float = setting(
        1.0, flag="delta_threshold",
        help="level step in multiples of the channel's RMS sample-to-sample change",
    )  # fmt: skip
    max_spikes: int = setting(
        16, flag="delta_max_spikes", help="spike times kept per ON / OFF afferent"
    )

    def __post_init__(self) -> None:
        check_positive(self.threshold, "threshold")
        check_int(self.max_spikes, "max_spikes", 1)


@dataclass(frozen=True)
class EventsConfig(ComponentSettings):
    max_spikes: int = setting(
        16, flag="events_max_spikes", help="spike times kept per afferent (channel)"
    )
    keep: str = setting(
        "spread", flag="events_keep", choices=KEEPS,
        help="spread (default): every m-th event (m fitted per afferent) so the slots span the "
        "trial; first: the first max_spikes",
    )  # fmt: skip

    def __post_init__(self) -> None:
        check_int(self.max_spikes, "max_spikes", 1)
        check_choice(self.keep, "keep", KEEPS)


@dataclass(frozen=True)
class FrameCodeConfig(ComponentSettings):
    f_lo_hz: float = setting(3.0, help="lowest band centre (Hz)")
    f_hi_hz: float = setting(  # capped at 0.45 fs
        90.0, help="highest band centre (Hz; capped at 0.45 x the sampling rate)"
    )
    n_bands: int = setting(8, help="number of log-spaced bands")
    frame_ms: float = setting(
        5.0, flag="frame_ms",
        help="frame period (ms): the code's step, one hop of round(frame_ms x fs / 1000) samples "
        "(at least one sample)",
    )  # fmt: skip
    neurons: int = setting(
        5, flag="frame_neurons", help="LIF converters per band envelope (thresholds lo..hi)"
    )
    lo: float = setting(
        0.25, flag="frame_lo", help="lowest converter threshold, in multiples of the row's level"
    )
    hi: float = setting(
        4.0, flag="frame_hi", help="highest converter threshold, in multiples of the row's level"
    )
    # hook_loop, frames + stream, 15 epochs, seed 0: tau 4 / 2 / 1 frames 97.3 (40 epochs) /
    # 98.6 / 98.6 %; with 5 converters from 0.25 to 4 x the level 99.1 % (3 from 0.5 to 8: 98.8)
    tau_frames: float = setting(
        1.0, flag="frame_tau", help="converter membrane time constant, in frames"
    )
    sustained: bool = setting(
        True, flag="frame_sustained",
        help="also code each channel's level against its training median (an ON and an OFF "
        "row: what a held press keeps, which band envelopes drop)",
    )  # fmt: skip

    follows_data: ClassVar[bool] = True

    @classmethod
    def data_defaults(cls, fs_hz: float, window: int, median_hz: float | None = None) -> dict:
        """The scalogram encoders' band range for the data (:meth:`GWTConfig.data_defaults`) in
        at most ``n_bands`` bands."""
        d = GWTConfig.data_defaults(fs_hz, window, median_hz)
        return {"f_lo_hz": d["f_lo_hz"], "f_hi_hz": d["f_hi_hz"],
                "n_bands": min(int(d["n_bands"]), cls.n_bands)}  # fmt: skip

    def __post_init__(self) -> None:
        check_bands(self.f_lo_hz, self.f_hi_hz, self.n_bands, 128)
        check_positive(self.frame_ms, "frame_ms")
        check_int(self.neurons, "neurons", 1)
        check_positive(self.lo, "lo")
        check_positive(self.hi, "hi")
        if self.hi < self.lo:
            raise ValueError(f"hi ({self.hi}) must be >= lo ({self.lo})")
        check_positive(self.tau_frames, "tau_frames")


@dataclass(frozen=True)
class LIFPopulationConfig(ComponentSettings):
    neurons: int = setting(
        8, flag="lif_neurons", help="LIF converters per channel (thresholds graded from lo to hi)"
    )
    lo: float = setting(
        0.25, flag="lif_lo", help="lowest threshold, in multiples of the reference level"
    )
    hi: float = setting(
        4.0, flag="lif_hi", help="highest threshold, in multiples of the reference level"
    )
    tau_ms: float = setting(10.0, flag="lif_tau_ms", help="converter membrane time constant (ms)")
    max_spikes: int = setting(8, flag="lif_max_spikes", help="spike times kept per converter")
    norm: str = setting(
        "train", flag="lif_norm", choices=NORMS,
        help="reference level: train (channel RMS on training data) or window (peak |x|)",
    )  # fmt: skip
    keep: str = setting(
        "spread", flag="lif_keep", choices=KEEPS,
        help="spread (default): every m-th spike (m fitted) so the slots span the window; first: "
        "the first max_spikes",
    )  # fmt: skip

    def __post_init__(self) -> None:
        check_int(self.neurons, "neurons", 1)
        check_int(self.max_spikes, "max_spikes", 1)
        check_positive(self.lo, "lo")
        check_positive(self.hi, "hi")
        check_positive(self.tau_ms, "tau_ms")
        if self.hi < self.lo:
            raise ValueError(f"hi ({self.hi}) must be >= lo ({self.lo})")
        check_choice(self.norm, "norm", NORMS)
        check_choice(self.keep, "keep", KEEPS)


ENCODERS.declare("gwt", GWTConfig, "tactilesnn.encoders.scalogram_latency")
ENCODERS.declare("stft", STFTConfig, "tactilesnn.encoders.scalogram_latency")
ENCODERS.declare("cgwt", CausalGWTConfig, "tactilesnn.encoders.causal_gwt")
ENCODERS.declare("bands", BandCodeConfig, "tactilesnn.encoders.band_code")
ENCODERS.declare("delta", DeltaConfig, "tactilesnn.encoders.delta")
ENCODERS.declare("events", EventsConfig, "tactilesnn.encoders.events")
ENCODERS.declare("frames", FrameCodeConfig, "tactilesnn.encoders.frame_code")
ENCODERS.declare("lif", LIFPopulationConfig, "tactilesnn.encoders.lif_population")
