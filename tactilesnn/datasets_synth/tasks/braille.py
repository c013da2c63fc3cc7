"""Braille task: an iCub capacitive fingertip slid over Braille cells (seed 003 technology).

Scene: a plate carrying one Braille cell (standard dot geometry: spherical-cap dots of 1.44 mm
base diameter and 0.48 mm height, 2.34 mm apart within the cell) slides under the fingertip
(:class:`~tactilesnn.datasets_synth.sensors.capacitive_fingertip.CapacitiveFingertip`) along the
fingertip's long axis, as the robot arm of ``../shared/data/braille_icub_abc`` does: 38 mm at
about 10 mm/s (3.75 s, the cell under the fingertip mid-slide), pressed with about 1.5 N at a
set height (position control: the force rises as the dots pass), the fingertip's centre running
along the cell's first row (dots 1 and 4; ``row_mm``); frames at 93.3 Hz (the real file's median
rate). The dots are in the standard order (1-2-3 down the first column, 4-5-6 down the second);
the slide runs across the columns.

Array contract: ``X [N, 12, 350]`` float32 iCub taxel values (counts 0..255) at 93.3 Hz; classes
are letters (``letters``, default ``"abc"``: the real file's A, B, C).

Randomisation knobs (each also a difficulty axis of the sim-to-real study; 0 switches it off):
``gain_spread`` (sd of each taxel's log gain, drawn per trial), ``offset_counts`` (sd of each
taxel's calibration offset, counts), ``drift_counts`` (rms of a random-walk baseline drift over
the slide, counts), ``speed_spread`` (relative sd of the slide speed), ``force_spread`` (relative
half-range of the pressing force around ``force_N``, and a 10 % ripple along the slide),
``position_mm`` (sd of the cell's placement across and along the slide, and of the fingertip's
contact point: the real file's sub-millimetre offsets), ``taxel_noise`` (scales the CDC's 4 LSB
rms noise and the readout's 0.7 counts rms). ``force_ramp``: the relative rise of the pressing
force along the slide (a plate not level with the arm's path; the real file's robot state shows
+32 %), drawn +-50 % around its value per trial. ``difficulty`` scales every knob at once.

``calibration``: a sensor fit file (:class:`~..calibration.SensorFit`, written by ``tactilesnn
calibrate`` from a user's slides, :meth:`BrailleTask.calibrate`): the fingertip's fitted
parameters (its pads where the fit put them, in the recordings' channel order), the scene's
fitted force, ramp, speed, timing and track, each channel's fitted gain, offset and noise; the
randomisation then draws around those values with the file's widths (timing, gain, per-channel
offset; the knobs above keep scaling them: 0 switches one off, ``difficulty`` scales all).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from functools import cached_property
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ..calibration import SensorFit
from ..scenes.braille_cell import (
    BRAILLE_DOTS,
    DOT_HEIGHT_MM,
    DOT_SPACING_MM,
    cell_dots_mm,
    scaled_dot_diameter_mm,
)
from ..scenes.inputs import FingertipPress
from ..sensors.capacitive_fingertip import CapacitiveFingertip, FingertipParams
from .base import register_task
from .trial import TrialTask

#: what a Braille fit file must hold (each channel list: 12 values)
FIT_SCENE = ("row_mm", "t_mid_offset_s", "speed_mm_s", "force_N", "force_ramp")
FIT_RANDOMISATION = ("position_mm", "force_spread", "gain_spread", "speed_spread", "drift_counts",
                     "time_jitter_s")  # fmt: skip
FIT_CHANNELS = ("pad_x_mm", "pad_y_mm", "gain", "offset", "noise")


def check_fit(fit: SensorFit, where: str) -> None:
    """ValueError unless ``fit`` is a Braille fingertip fit the task can render."""
    if fit.task != "braille" or fit.sensor != "capacitive_fingertip":
        raise ValueError(f"{where} fits {fit.task}/{fit.sensor}, not braille")
    for group, keys in (("scene", FIT_SCENE), ("randomisation", FIT_RANDOMISATION),
                        ("channels", FIT_CHANNELS)):  # fmt: skip
        missing = [k for k in keys if k not in getattr(fit, group)]
        if missing:
            raise ValueError(f"{where}: {group} lacks {', '.join(missing)}")
    for k in FIT_CHANNELS:
        if len(fit.channels[k]) != 12:
            raise ValueError(f"{where}: channels.{k} must hold 12 values")
    sc, rz = fit.scene, fit.randomisation
    for k in ("dot_spacing_mm", "row_spacing_mm"):
        if not 1.0 <= sc.get(k, DOT_SPACING_MM) <= 10.0:
            raise ValueError(f"{where}: {k} must be in [1, 10] mm")
    if sc["speed_mm_s"] <= 0 or sc["force_N"] <= 0 or sc["force_ramp"] < 0:
        raise ValueError(f"{where}: speed and force must be > 0 and the ramp >= 0")
    if min(rz.values()) < 0 or min(fit.channels["noise"]) < 0:
        raise ValueError(f"{where}: randomisation widths and noise must be >= 0")


#: where a slide drawn without its letter (``sample(i, class_signal=True)``) puts the cell:
#: far out of any fingertip's reach (mm)
CELL_AWAY_MM = 1.0e4


@register_task
@dataclass(frozen=True)
class BrailleTask(TrialTask):
    """Letters read by sliding an iCub fingertip over a Braille cell; ``X [N, 12, 350]`` counts."""

    n_samples: int = 300
    letters: str = "abc"
    fs_frames_hz: float = 93.3
    duration_s: float = 3.75
    slide_mm: float = 38.0
    # the real file's robot state (columns 6-8 read as a force in N): 1.47 N (1.40-1.54 over
    # slides) before the letter; the arm holds its height, so the force rises over the dots
    force_N: float = 1.47
    # ... and it grows along the slide (the plate is not level with the arm's path): force over
    # the last 10 % of a slide / over the first 10 %, minus 1: median 0.32 (0.27-0.36)
    force_ramp: float = 0.32
    gain_spread: float = 0.25
    offset_counts: float = 4.0
    drift_counts: float = 2.0
    speed_spread: float = 0.1
    force_spread: float = 0.2
    dot_spacing_mm: float = DOT_SPACING_MM  # the cell's dot pitch (a printed cell may be larger)
    row_mm: float = DOT_SPACING_MM  # the track's offset from the cell's middle row (to dots 1, 4)
    position_mm: float = 0.5
    taxel_noise: float = 1.0
    calibration: str = ""  # a sensor fit file (tactilesnn calibrate); "" = the model's own values

    name: ClassVar[str] = "braille"
    task_id: ClassVar[int] = 6
    units: ClassVar[str] = "iCub taxel counts (8-bit, 0 = calibrated rest)"

    def __post_init__(self) -> None:
        bad = sorted(set(self.letters) - set(BRAILLE_DOTS))
        if bad or len(set(self.letters)) != len(self.letters) or len(self.letters) < 2:
            raise ValueError(f"letters must be >= 2 distinct letters a-z, got {self.letters!r}")
        for knob in ("gain_spread", "offset_counts", "drift_counts", "speed_spread",
                     "force_spread", "position_mm", "taxel_noise", "force_ramp"):  # fmt: skip
            v = getattr(self, knob)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{knob} must be a finite number >= 0, got {v}")
        if not 0 <= self.force_spread < 1:
            raise ValueError(f"force_spread must be in [0, 1), got {self.force_spread}")
        for name in ("fs_frames_hz", "duration_s", "slide_mm", "force_N", "dot_spacing_mm"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a finite number > 0, got {v}")
        super().__post_init__()
        if self.calibration:
            check_fit(self.fit, str(self.calibration))

    @cached_property
    def fit(self) -> SensorFit | None:
        """The sensor fit file's content (None without one)."""
        return SensorFit.load(Path(self.calibration)) if self.calibration else None

    @classmethod
    def calibrate(cls, X: np.ndarray, y: np.ndarray, fs_hz: float, class_names: tuple[str, ...],
                  budget_s: float = 540.0, seed: int = 0, progress: bool = False,
                  max_evals: int | None = None, optimiser: str = "cma",
                  known: dict[str, float] | None = None) -> SensorFit:  # fmt: skip
        """Fit the fingertip and the scene to real slides ``X [N, 12, samples]`` of the letters
        ``class_names[y]`` (see :mod:`.braille_fit`); ``known``: measured values held fixed."""
        from . import braille_fit

        letters = "".join(str(c).strip().lower() for c in class_names)
        task = cls(letters=letters, fs_frames_hz=fs_hz, duration_s=X.shape[-1] / fs_hz)
        return braille_fit.fit(
            task,
            X,
            y,
            fs_hz,
            budget_s=budget_s,
            seed=seed,
            progress=progress,
            max_evals=max_evals or braille_fit.MAX_EVALS,
            optimiser=optimiser,
            known=known,
        )

    @property
    def class_names(self) -> tuple[str, ...]:  # type: ignore[override]
        return tuple(self.letters)

    @property
    def sensor(self) -> CapacitiveFingertip:
        scale = self.taxel_noise * self.difficulty
        if self.fit is not None:
            known = {f.name for f in fields(FingertipParams)}
            params: dict[str, Any] = {k: v for k, v in self.fit.params.items() if k in known}
            ch = self.fit.channels
            params["pads_mm"] = tuple(zip(ch["pad_x_mm"], ch["pad_y_mm"], strict=True))
            return CapacitiveFingertip(FingertipParams(**params))
        base = FingertipParams()
        return CapacitiveFingertip(
            FingertipParams(
                noise_lsb=base.noise_lsb * scale, noise_counts=base.noise_counts * scale
            )
        )

    @property
    def fs_hz(self) -> float:
        return float(self.fs_frames_hz)

    def _render_without_class(self, label: int, rng: np.random.Generator) -> np.ndarray:
        # the same draw with the cell moved out of the fingertip's reach: every random number is
        # drawn as before, so what differs from the slide is the letter's own response
        return self._render(label, rng, away=True)[0]

    def _render(self, label: int, rng: np.random.Generator,
                away: bool = False) -> tuple[np.ndarray, dict]:  # fmt: skip
        if self.fit is not None:
            return self._render_fitted(label, rng, away)
        d = self.difficulty
        sensor = self.sensor
        n = self.window
        t = np.arange(n) / self.fs_hz
        speed = (
            self.slide_mm / self.duration_s * np.exp(self.speed_spread * d * rng.standard_normal())
        )
        place = self.position_mm * d * rng.standard_normal(2)  # cell: along, across the slide
        contact = self.position_mm * d * rng.standard_normal(2)  # the fingertip's lowest point
        pitch = self.dot_spacing_mm
        diameter = scaled_dot_diameter_mm(pitch)
        dots = cell_dots_mm(self.class_names[label], pitch) + place - [0.0, self.row_mm]
        dots = dots + (CELL_AWAY_MM if away else 0.0)
        shift = speed * (t - self.duration_s / 2)  # the plate moves towards -x

        bumps = dots[None] - np.stack([shift, np.zeros(n)], 1)[:, None]  # [frames, k, 2]
        fs = self.force_spread * min(d, 1.0)
        force = self.force_N * np.exp(fs * rng.uniform(-1, 1))
        ripple = 1 + 0.1 * min(d, 1.0) * np.sin(
            2 * np.pi * t / rng.uniform(1.0, 4.0) + rng.uniform(0, 2 * np.pi)
        )
        ramp = self.force_ramp * (1 + 0.5 * min(d, 1.0) * rng.uniform(-1, 1))
        ripple = ripple * (1 + ramp * t / self.duration_s)
        gain = np.exp(self.gain_spread * d * rng.standard_normal(12))
        offset = self.offset_counts * d * rng.standard_normal(12)
        drift = np.cumsum(rng.standard_normal((12, n)), 1) * (self.drift_counts * d / np.sqrt(n))
        press = FingertipPress(force * ripple, bumps, DOT_HEIGHT_MM, diameter, contact, gain,
                               offset[:, None] + drift, self.fs_hz)  # fmt: skip
        counts = sensor.read_scene(press, rng)
        load = sensor.last_force_N
        info = {"speed_mm_s": float(speed), "force_N": float(force), "cell_offset_mm": place.tolist(),
                "contact_mm": contact.tolist(),
                "force_rise_N": float(load.max() - load[: max(1, n // 10)].mean())}  # fmt: skip
        return counts, info

    def _render_fitted(self, label: int, rng: np.random.Generator,
                       away: bool = False) -> tuple[np.ndarray, dict]:  # fmt: skip
        """A slide of the fitted fingertip and scene, drawn around the fit's values."""
        fit = self.fit
        assert fit is not None
        d = self.difficulty
        sc, rz, ch = fit.scene, fit.randomisation, fit.channels
        defaults = {f.name: f.default for f in fields(type(self))}

        def knob(name: str, width: float) -> float:  # the task's knob scales the fitted width
            base = defaults[name]
            return width * d * (getattr(self, name) / base if base else 1.0)

        sensor = self.sensor
        n = self.window
        t = np.arange(n) / self.fs_hz
        speed = sc["speed_mm_s"] * np.exp(
            knob("speed_spread", rz["speed_spread"]) * rng.standard_normal()
        )
        t_mid = n / self.fs_hz / 2 + sc["t_mid_offset_s"] + knob(
            "speed_spread", rz["time_jitter_s"]) * rng.standard_normal()  # fmt: skip
        place = knob("position_mm", rz["position_mm"]) * rng.standard_normal(2)
        contact = knob("position_mm", rz["position_mm"]) * rng.standard_normal(2)
        pitch = float(sc.get("dot_spacing_mm", DOT_SPACING_MM))
        rows = float(sc.get("row_spacing_mm", pitch))
        diameter = scaled_dot_diameter_mm(pitch, rows)
        dots = cell_dots_mm(self.class_names[label], pitch, rows) + place - [0.0, sc["row_mm"]]
        dots = dots + (CELL_AWAY_MM if away else 0.0)
        shift = speed * (t - t_mid)
        bumps = dots[None] - np.stack([shift, np.zeros(n)], 1)[:, None]
        fs = min(knob("force_spread", rz["force_spread"]), 0.9)
        letter = self.class_names[label]
        force = sc["force_N"] * sc.get(f"force_scale_{letter}", 1.0) * np.exp(fs * rng.uniform(-1, 1)) * (
            1 + sc["force_ramp"] * t / (n / self.fs_hz))  # fmt: skip
        gain = np.asarray(ch["gain"]) * np.exp(
            knob("gain_spread", rz["gain_spread"]) * rng.standard_normal(12))  # fmt: skip
        off_scale = d * self.offset_counts / defaults["offset_counts"]
        off_sd = np.asarray(ch.get("offset_sd", [0.0] * 12)) * off_scale
        offset = np.asarray(ch["offset"]) + off_sd * rng.standard_normal(12)
        drift = np.cumsum(rng.standard_normal((12, n)), 1) * (
            knob("drift_counts", rz["drift_counts"]) / np.sqrt(n))  # fmt: skip
        noise = (
            np.asarray(ch["noise"])[:, None] * self.taxel_noise * d * rng.standard_normal((12, n))
        )
        press = FingertipPress(force, bumps, DOT_HEIGHT_MM, diameter, contact, gain,
                               offset[:, None] + drift + noise, self.fs_hz)  # fmt: skip
        counts = sensor.read_scene(press, rng)
        load = sensor.last_force_N
        info = {"speed_mm_s": float(speed), "force_N": float(force[0]), "cell_offset_mm": place.tolist(),
                "contact_mm": contact.tolist(),
                "force_rise_N": float(load.max() - load[: max(1, n // 10)].mean())}  # fmt: skip
        return counts, info
