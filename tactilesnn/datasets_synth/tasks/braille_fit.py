"""Fitting the Braille scene's fingertip to real slides (:meth:`BrailleTask.calibrate`).

What is fitted, from the recordings alone (a file as ``train --data`` reads it: whole slides
``X [N, 12, samples]`` of known letters):

* **Black-box (CMA-ES, the ``cma`` package)**, 13 values in physical units within stated bounds
  (:data:`BOUNDS`) and one force scale per letter: the cell's dot pitch between its columns and
  between its rows (mm: a printed cell need not be the standard's 2.34 mm; the real iCub
  file's C is its A twice, 0.44 s apart at the arm's 10.07 mm/s), the cover's spread (mm), the
  track's offset from the cell's middle row (mm), when the cell's centre passes the contact
  point (s) and the slide's speed (mm/s), the set force (N) and its ramp along the slide, the
  mount's normal and rotational stiffness (N/mm, N mm/rad: the dip), the fingertip's two radii
  of curvature (mm) and the foam's half-strain pressure (Pa). The search starts from the best
  of a grid of pitches at the task's speed (:func:`pitch_start`) and evaluates each round's
  points on the CPUs other work leaves free (:func:`search_workers`; the same fit on any
  number).
* **Exactly, inside every evaluation**: the taxel layout and channel map (each channel's pad
  centre, from 1,053 candidate centres 0.5 mm apart over the fingertip: the one whose response
  to the letters best correlates with the channel's, pads kept >= ``MIN_PAD_SEPARATION_MM``
  apart, channels with the most variance placed first) and per channel gain and offset (least
  squares; gain >= 0). A pad's response is linear in neither the layout nor the stiffnesses,
  but it is linear in gain and offset, so these 36 values need no search.
* **From the rest segments** (first 10 % of each slide): per channel noise (rms of the first
  differences / sqrt 2) and the spread of the rest level over slides (counts); from the slides
  of one letter, when there are two or more: the spread of the response's timing (s) and of its
  amplitude (log gain). These are the randomisation's widths; what the recordings cannot tell
  (the cell's placement, the force's spread) keeps the task's defaults.

The objective is :func:`~..calibration.statistic_distances`' ``mean_response`` (the fraction of
the real class means' variance left unexplained) plus half its ``correlation`` distance,
computed on noise-free renders at half the recordings' rate (one render per letter per
evaluation, ~0.1 s each); the other statistics (rest, range, band power) are reported.
"""

from __future__ import annotations

import logging
import os
import time
from contextlib import contextmanager
from dataclasses import fields
from typing import Any

import numpy as np

from ..calibration import SensorFit, rest_level, slide_statistics, statistic_distances
from ..scenes.braille_cell import (
    DOT_HEIGHT_MM,
    DOT_SPACING_MM,
    cell_dots_mm,
    scaled_dot_diameter_mm,
)
from ..sensors.capacitive_fingertip import CapacitiveFingertip, FingertipParams

log = logging.getLogger("tactilesnn")

#: the black-box values: name -> (low, high, log-scale), physical units in the name's doc above
BOUNDS: dict[str, tuple[float, float, bool]] = {
    "cover_spread_mm": (0.0, 4.0, False),
    # the cell's dot pitch between its columns (along the slide) and its rows (across), mm; the
    # dots' diameter scales with them (a printed cell need not be the standard's)
    "dot_spacing_mm": (2.0, 6.0, False),
    "row_spacing_mm": (1.5, 6.0, False),
    "row_mm": (-3.0, 7.0, False),
    "t_mid_offset_s": (-1.2, 1.2, False),  # from the recording's middle
    "speed_mm_s": (5.0, 16.0, False),
    "force_N": (0.5, 4.0, False),
    "force_ramp": (0.0, 0.8, False),
    "mount_N_per_mm": (0.3, 1000.0, True),
    "tilt_Nmm_per_rad": (10.0, 30000.0, True),
    "radius_along_mm": (6.0, 14.0, False),
    "radius_across_mm": (4.0, 10.0, False),
    "p_half_Pa": (10e3, 200e3, True),
}
#: the fingertip parameters among :data:`BOUNDS` (the rest are the scene's)
SENSOR_FIELDS = ("cover_spread_mm", "mount_N_per_mm", "tilt_Nmm_per_rad", "radius_along_mm",
                 "radius_across_mm", "p_half_Pa")  # fmt: skip
#: candidate pad centres: a 0.5 mm grid over this box (mm, fingertip frame)
CANDIDATE_BOX_MM = ((-8.0, 8.0), (-6.5, 6.5))
CANDIDATE_STEP_MM = 0.5
#: pads are 3 mm discs: two channels' centres no closer than this
MIN_PAD_SEPARATION_MM = 2.5
#: a channel whose class means vary less than this (counts rms) carries nothing to fit
SILENT_COUNTS = 0.05
#: the objective's weight on the offsets (squared, relative to the largest mean level)
OFFSET_WEIGHT = 1.0
#: the search's evaluations (a fit is reproducible for a seed; the seconds budget only caps it
#: on a slow machine): ~0.3 s each on one core. On k = 2 real slides per letter, two seeds'
#: best objective after 400 / 1200 evaluations: 0.635 / 0.459 and 0.573 / 0.313 (not
#: converged at 400)
MAX_EVALS = 1200
#: the evaluation renders every ``DECIMATE``-th frame
DECIMATE = 2
#: quadrature of the force balance during the search (mm; the fit file keeps the default 0.25)
SEARCH_GRID_MM = 0.5


#: each letter's force relative to the set force (the plate under each letter sits at its own
#: height: the real file's rest levels before the letter differ by letter)
LETTER_FORCE_BOUNDS = (0.6, 1.6, True)


def bounds_for(letters: str) -> dict[str, tuple[float, float, bool]]:
    """:data:`BOUNDS` and one force scale per letter (``force_scale_<letter>``)."""
    return {**BOUNDS, **{f"force_scale_{c}": LETTER_FORCE_BOUNDS for c in letters}}


def dot_geometry(values: dict[str, float]) -> tuple[float, float, float]:
    """The cell's column and row pitches and its dots' diameter (mm) at ``values`` (the
    standard cell without fitted pitches; fitted pitches scale the diameter with them)."""
    pitch = float(values.get("dot_spacing_mm", DOT_SPACING_MM))
    rows = float(values.get("row_spacing_mm", pitch))
    return pitch, rows, scaled_dot_diameter_mm(pitch, rows)


def letter_force(values: dict[str, float], letter: str) -> float:
    """The set force (N) under ``letter``'s plate."""
    return values["force_N"] * values.get(f"force_scale_{letter}", 1.0)


def _to_unit(values: dict[str, float], bounds: dict[str, tuple[float, float, bool]]) -> np.ndarray:
    out = []
    for k, (lo, hi, lg) in bounds.items():
        v = float(np.clip(values[k], lo, hi))
        out.append((np.log(v / lo) / np.log(hi / lo)) if lg else (v - lo) / (hi - lo))
    return np.asarray(out)


def _from_unit(u: np.ndarray, bounds: dict[str, tuple[float, float, bool]]) -> dict[str, float]:
    out = {}
    for x, (k, (lo, hi, lg)) in zip(np.clip(u, 0.0, 1.0), bounds.items(), strict=True):
        out[k] = float(lo * (hi / lo) ** x) if lg else float(lo + x * (hi - lo))
    return out


def candidates_mm() -> np.ndarray:
    """Candidate pad centres ``[P, 2]`` (mm)."""
    (x0, x1), (y0, y1) = CANDIDATE_BOX_MM
    gx = np.arange(x0, x1 + 1e-9, CANDIDATE_STEP_MM)
    gy = np.arange(y0, y1 + 1e-9, CANDIDATE_STEP_MM)
    return np.stack(np.meshgrid(gx, gy, indexing="ij"), -1).reshape(-1, 2)


def start_values(task: Any, duration_s: float) -> dict[str, float]:
    """The task's own values as the search's start."""
    p = FingertipParams()
    return {"cover_spread_mm": p.cover_spread_mm, "dot_spacing_mm": task.dot_spacing_mm,
            "row_spacing_mm": task.dot_spacing_mm, "row_mm": task.row_mm, "t_mid_offset_s": 0.0,
            "speed_mm_s": task.slide_mm / task.duration_s, "force_N": task.force_N,
            "force_ramp": task.force_ramp, "mount_N_per_mm": 30.0, "tilt_Nmm_per_rad": 1000.0,
            "radius_along_mm": p.radius_along_mm, "radius_across_mm": p.radius_across_mm,
            "p_half_Pa": p.p_half_Pa}  # fmt: skip


def sensor_params(values: dict[str, float], **extra: Any) -> FingertipParams:
    return FingertipParams(**{k: values[k] for k in SENSOR_FIELDS}, **extra)


def _disc_kernel(step_mm: float, diameter_mm: float) -> np.ndarray:
    """A pad's area on the candidate grid: weights summing to 1 (a disc, 4 x 4 sub-samples a cell)."""
    r = diameter_mm / 2
    half = int(np.ceil(r / step_mm))
    sub = (np.arange(4) + 0.5) / 4 - 0.5
    off = np.arange(-half, half + 1)
    cx = (off[:, None] + sub[None, :]).reshape(-1) * step_mm
    inside = (cx[:, None] ** 2 + cx[None, :] ** 2 <= r * r).astype(np.float64)
    k = inside.reshape(len(off), 4, len(off), 4).sum((1, 3))
    return k / k.sum()


def letter_states(sensor: CapacitiveFingertip, values: dict[str, float], letters: str,
                  fs_hz: float, n_frames: int):  # fmt: skip
    """The fingertip's pose per frame (:meth:`CapacitiveFingertip.contact_state`) as each letter's
    cell passes, centred on the track, at the scene ``values`` (no randomisation)."""
    duration = n_frames / fs_hz
    t = np.arange(n_frames) / fs_hz
    shift = values["speed_mm_s"] * (t - duration / 2 - values["t_mid_offset_s"])
    ramp = 1 + values["force_ramp"] * t / duration
    pitch, rows, diameter = dot_geometry(values)
    for letter in letters:
        dots = cell_dots_mm(letter, pitch, rows) - [0.0, values["row_mm"]]
        bumps = dots[None] - np.stack([shift, np.zeros(n_frames)], 1)[:, None]
        yield sensor.contact_state(letter_force(values, letter) * ramp, bumps, DOT_HEIGHT_MM,
                                   diameter, np.zeros(2))  # fmt: skip


def letter_codes(values: dict[str, float], letters: str, fs_hz: float, n_frames: int,
                 grid_mm: float = SEARCH_GRID_MM) -> np.ndarray:  # fmt: skip
    """Noise-free codes above rest ``[letters, P, n_frames]`` of pads at every candidate centre
    (:func:`candidates_mm`), the cell centred on the track, at the scene ``values``: the
    capacitance field on the candidate grid (extended by a pad's radius) averaged over each
    pad's disc (a correlation with the disc's kernel), then converted."""
    from scipy.ndimage import correlate

    sensor = CapacitiveFingertip(sensor_params(values, grid_mm=grid_mm))
    kern = _disc_kernel(CANDIDATE_STEP_MM, sensor.params.pad_diameter_mm)
    half = kern.shape[0] // 2
    (x0, x1), (y0, y1) = CANDIDATE_BOX_MM
    step = CANDIDATE_STEP_MM
    gx = np.arange(x0 - half * step, x1 + half * step + 1e-9, step)
    gy = np.arange(y0 - half * step, y1 + half * step + 1e-9, step)
    pts = np.stack(np.meshgrid(gx, gy, indexing="ij"), -1).reshape(-1, 2)
    out = []
    for state in letter_states(sensor, values, letters, fs_hz, n_frames):
        field = sensor.capacitance_field_pF(pts, state).reshape(n_frames, gx.size, gy.size)
        pad = correlate(field, kern[None], mode="constant")[:, half:-half, half:-half]
        out.append(sensor.code_of(pad.reshape(n_frames, -1)).T)
    return np.stack(out)


def pad_codes(values: dict[str, float], letters: str, fs_hz: float, n_frames: int,
              centres_mm: np.ndarray) -> np.ndarray:  # fmt: skip
    """As the task renders them: codes ``[letters, C, n_frames]`` of the pads at
    ``centres_mm [C, 2]`` (the sensor's own pad quadrature and force balance grid)."""
    sensor = CapacitiveFingertip(
        sensor_params(values, grid_mm=FIT_GRID_MM, pad_rings=FIT_PAD_RINGS)
    )
    return np.stack([sensor.codes_at(centres_mm, state)
                     for state in letter_states(sensor, values, letters, fs_hz, n_frames)])  # fmt: skip


def place_pads(codes: np.ndarray, means: np.ndarray, centres_mm: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Each channel's pad (index into ``centres_mm``), gain and offset: ``codes [P, T]`` (the
    candidates' responses, letters joined), ``means [C, T]`` (the channels' class means, joined).
    The channels with the most variance choose first; a candidate within
    :data:`MIN_PAD_SEPARATION_MM` of a placed pad is no longer free."""
    r = codes - codes.mean(1, keepdims=True)
    m = means - means.mean(1, keepdims=True)
    rn = np.sqrt((r * r).sum(1))
    mn = np.sqrt((m * m).sum(1))
    live_r = rn > 1e-9
    corr = np.zeros((codes.shape[0], means.shape[0]))
    corr[live_r] = (r[live_r] / rn[live_r, None]) @ (m / np.maximum(mn, 1e-12)[:, None]).T
    free = np.ones(codes.shape[0], bool)
    pad = np.zeros(means.shape[0], np.int64)
    gain = np.zeros(means.shape[0])
    energy = (codes**2).sum(1)
    t = means.shape[1]
    for c in np.argsort(-mn):
        silent = mn[c] / np.sqrt(t) < SILENT_COUNTS
        # a silent channel goes where nothing presses (a pad off the contact)
        score = -energy if silent else corr[:, c]
        score = np.where(free, score, -np.inf)
        p = int(np.argmax(score))
        pad[c] = p
        if not silent and rn[p] > 1e-9:
            gain[c] = max(0.0, float(r[p] @ m[c]) / float(rn[p] ** 2))
        free &= np.linalg.norm(centres_mm - centres_mm[p], axis=1) >= MIN_PAD_SEPARATION_MM
    offset = means.mean(1) - gain * codes[pad].mean(1)
    return pad, gain, offset


def activity(means: np.ndarray) -> np.ndarray:
    """How much the channels move ``[T]``: the summed absolute change of ``means [L, C, T]``
    about each channel's baseline, the line through its levels over the first and the last
    10 % of the frames (a force that grows along the slide raises every pad: a ramp, not the
    letter)."""
    t_n = means.shape[-1]
    q = max(2, t_n // 10)
    first = np.median(means[..., :q], -1, keepdims=True)
    last = np.median(means[..., -q:], -1, keepdims=True)
    frac = (np.arange(t_n) - (q - 1) / 2) / max(t_n - q, 1)
    return np.abs(means - (first + (last - first) * frac)).sum((0, 1))


def response_lag_s(values: dict[str, float], letters: str, fs_hz: float, n: int,
                   real_means: np.ndarray) -> float:  # fmt: skip
    """When the letters pass, as a timing offset (s) for ``values``: the lag that best aligns the
    model's activity (every candidate pad, unit gains) with the recordings' (the search's start:
    a wrong start leaves the timing in a local optimum). The model's activity is shifted, not
    rolled: what leaves the window does not come back at its other end."""
    model = activity(letter_codes({**values, "t_mid_offset_s": 0.0}, letters, fs_hz, n))
    real = activity(real_means)
    lo, hi = BOUNDS["t_mid_offset_s"][:2]
    lags = np.arange(int(np.ceil(lo * fs_hz)), int(hi * fs_hz) + 1)
    score = []
    for lag in lags:
        shifted = np.zeros_like(model)
        if lag >= 0:
            shifted[lag:] = model[: model.size - lag]
        else:
            shifted[:lag] = model[-lag:]
        a, b = shifted - shifted.mean(), real - real.mean()
        score.append(float(a @ b) / max(float(np.sqrt((a @ a) * (b @ b))), 1e-12))
    return float(lags[int(np.argmax(score))] / fs_hz)


#: the cell pitches (mm) the search's start is chosen from: between columns, between rows
START_PITCHES_MM = tuple(np.round(np.arange(2.0, 6.01, 0.5), 2))
START_ROW_PITCHES_MM = (2.0, 2.5, 3.0, 4.0)


def _start_candidate(values: dict[str, float], letters: str, fs_hz: float, n: int,
                     cands: np.ndarray, real_dec: np.ndarray,
                     known: dict[str, float]) -> tuple[float, dict[str, float]]:  # fmt: skip
    v = {**values, "t_mid_offset_s": response_lag_s(values, letters, fs_hz, n, real_dec), **known}
    return _objective(v, letters, fs_hz, n, cands, real_dec)[0], v


def pitch_start(values: dict[str, float], letters: str, fs_hz: float, n: int, cands: np.ndarray,
                real_dec: np.ndarray, pool: Any = None,
                known: dict[str, float] | None = None) -> dict[str, float]:  # fmt: skip
    """The search's start: ``values`` at the cell pitches (:data:`START_PITCHES_MM` between
    columns, :data:`START_ROW_PITCHES_MM` between rows; the track on the first row, the timing
    aligned by :func:`response_lag_s`) whose objective is lowest. The column pitch and the
    speed trade off in time (a larger cell, a slower slide): the start keeps the task's speed,
    so that a search started at the wrong pitch does not settle in the slower slide's local
    optimum; the row pitch sets which pads the second row reaches. ``pool``: an executor the
    candidates are evaluated on (the same answer as without). ``known``: held values (see
    :func:`fit`), kept in every candidate; a held pitch is not gridded."""
    known = dict(known or {})
    cols = [known["dot_spacing_mm"]] if "dot_spacing_mm" in known else START_PITCHES_MM
    rows = [known["row_spacing_mm"]] if "row_spacing_mm" in known else START_ROW_PITCHES_MM
    grid = [{**values, "dot_spacing_mm": float(p), "row_spacing_mm": float(r), "row_mm": float(r)}
            for p in cols for r in rows]  # fmt: skip
    args = [(v, letters, fs_hz, n, cands, real_dec, known) for v in grid]
    tried = list(pool.map(_start_candidate, *zip(*args, strict=True)) if pool else
                 (_start_candidate(*a) for a in args))  # fmt: skip
    return tried[int(np.argmin([loss for loss, _ in tried]))][1]


#: the black-box optimisers :func:`fit` can use (``calibrate --optimiser``), measured against
#: each other in docs/sim2real.md: CMA-ES is the default
OPTIMISERS = {"cma": "cma-es (cma)", "optuna-tpe": "tpe (optuna)", "random": "uniform random"}


class _Round:
    """One round of an ask / tell search: ``points`` (unit-box vectors), :meth:`tell` the losses."""

    def __init__(self, points: list, tell: Any, done: bool = False) -> None:
        self.points, self._tell, self.done = points, tell, done

    def tell(self, losses: list[float]) -> None:
        self._tell(losses)


def ask_tell(kind: str, x0: np.ndarray, seed: int, popsize: int = 10):
    """Rounds of ``popsize`` points in the unit box from the optimiser ``kind``
    (:data:`OPTIMISERS`), started at ``x0``; the caller stops when its budget is spent."""
    if kind not in OPTIMISERS:
        raise ValueError(f"unknown optimiser {kind!r}; choose from {', '.join(OPTIMISERS)}")
    if kind == "cma":
        import cma

        es = cma.CMAEvolutionStrategy(x0, 0.25, {"bounds": [0.0, 1.0], "seed": int(seed) + 1,
                                                 "verbose": -9, "popsize": popsize})  # fmt: skip
        while True:
            xs = es.ask()
            yield _Round(xs, lambda losses, xs=xs: es.tell(xs, losses), bool(es.stop()))
    elif kind == "optuna-tpe":
        import optuna

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        study = optuna.create_study(sampler=optuna.samplers.TPESampler(seed=int(seed)))
        names = [f"x{i}" for i in range(len(x0))]
        study.enqueue_trial(dict(zip(names, map(float, x0), strict=True)))
        while True:
            trials = [study.ask({n: optuna.distributions.FloatDistribution(0.0, 1.0)
                                 for n in names}) for _ in range(popsize)]  # fmt: skip
            points = [np.array([t.params[n] for n in names]) for t in trials]

            def tell(losses: list[float], trials: list = trials) -> None:
                for t, v in zip(trials, losses, strict=True):
                    study.tell(t, v)

            yield _Round(points, tell)
    else:
        rng = np.random.default_rng(seed)
        first = True
        while True:
            pts = [rng.random(len(x0)) for _ in range(popsize)]
            if first:
                pts[0], first = np.asarray(x0), False
            yield _Round(pts, lambda losses: None)


def fit_levels(codes: np.ndarray, means: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per channel gain (>= 0, counts per code LSB) and offset (counts) of ``codes [C, T]`` that
    best fit ``means [C, T]`` (least squares)."""
    r = codes - codes.mean(1, keepdims=True)
    m = means - means.mean(1, keepdims=True)
    den = (r * r).sum(1)
    gain = np.where(den > 1e-12, np.maximum((r * m).sum(1), 0.0) / np.maximum(den, 1e-12), 0.0)
    return gain, means.mean(1) - gain * codes.mean(1)


def _predict(codes: np.ndarray, gain: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Counts ``[..., C, T]`` of pads' codes ``[..., C, T]`` (gain per code LSB folded)."""
    return np.clip(gain[:, None] * codes + offset[:, None], 0, 255)


def _objective(values: dict[str, float], letters: str, fs: float, n: int, cands: np.ndarray,
               real_dec: np.ndarray) -> tuple[float, dict]:  # fmt: skip
    codes = letter_codes(values, letters, fs, n)  # [L, P, T]
    joined = codes.transpose(1, 0, 2).reshape(len(cands), -1)
    means = real_dec.transpose(1, 0, 2).reshape(real_dec.shape[1], -1)
    pad, gain, offset = place_pads(joined, means, cands)
    pred = _predict(codes[:, pad], gain, offset)  # [L, C, T]
    d = _distances(real_dec, pred)
    # 0 counts is the pad's calibrated rest in air: a level the physics leaves to the offset is
    # a level the model does not explain (and a steep gain on a small pressure is fragile)
    off = OFFSET_WEIGHT * float(np.mean((offset / max(float(np.abs(means).max()), 1.0)) ** 2))
    return d["mean_response"] + 0.5 * d["correlation"] + off, {"pad": pad, "gain": gain,
                                                              "offset": offset}  # fmt: skip


def _distances(real_means: np.ndarray, synth_means: np.ndarray) -> dict[str, float]:
    def stats(m: np.ndarray) -> dict:
        flat = m.transpose(1, 0, 2).reshape(m.shape[1], -1)
        sd = flat.std(1)
        live = sd > 1e-9
        corr = np.zeros((m.shape[1], m.shape[1]))
        if live.any():
            corr[np.ix_(live, live)] = np.corrcoef(flat[live])
        rest = np.median(m[..., : max(2, m.shape[-1] // 10)], -1).mean(0)
        rng_ = (m.max(-1) - m.min(-1)).mean(0)
        return {"mean": m, "correlation": corr, "rest": rest, "range": rng_, "spectrum": [0.0]}

    return statistic_distances(stats(real_means), stats(synth_means))


#: the randomisation's sources whose widths are fitted, with the width each is measured at
SPREAD_SOURCES = {"position_mm": 0.2, "force_spread": 0.1, "gain_spread": 0.1, "speed_spread": 0.05}
#: the largest width the fit may give each (beyond: not a jitter but a different experiment)
SPREAD_MAX = {"position_mm": 1.0, "force_spread": 0.5, "gain_spread": 0.5, "speed_spread": 0.3}
#: the resolution fitted files render at (force balance grid mm, pad quadrature rings): half the
#: default's cost; the fit's gains and offsets are solved at it
FIT_GRID_MM, FIT_PAD_RINGS = 0.35, 2


def render_counts(values: dict[str, float], pads_mm: np.ndarray, gain: np.ndarray,
                  offset: np.ndarray, letter: str, fs_hz: float, n_frames: int,
                  jitter: dict[str, float], rng: np.random.Generator,
                  grid_mm: float = SEARCH_GRID_MM, pad_rings: int = 1) -> np.ndarray:  # fmt: skip
    """One noise-free slide ``[C, n_frames]`` (counts) with the randomisation of ``jitter``
    (widths of :data:`SPREAD_SOURCES`, absent = 0) drawn as the task draws it."""
    w = {k: float(jitter.get(k, 0.0)) for k in SPREAD_SOURCES}
    sensor = CapacitiveFingertip(sensor_params(values, grid_mm=grid_mm, pad_rings=pad_rings))
    duration = n_frames / fs_hz
    t = np.arange(n_frames) / fs_hz
    speed = values["speed_mm_s"] * np.exp(w["speed_spread"] * rng.standard_normal())
    place = w["position_mm"] * rng.standard_normal(2)
    contact = w["position_mm"] * rng.standard_normal(2)
    force = letter_force(values, letter) * np.exp(w["force_spread"] * rng.uniform(-1, 1))
    force = force * (1 + values["force_ramp"] * t / duration)
    g = gain * np.exp(w["gain_spread"] * rng.standard_normal(len(gain)))
    pitch, rows, diameter = dot_geometry(values)
    dots = cell_dots_mm(letter, pitch, rows) + place - [0.0, values["row_mm"]]
    shift = speed * (t - duration / 2 - values["t_mid_offset_s"])
    bumps = dots[None] - np.stack([shift, np.zeros(n_frames)], 1)[:, None]
    state = sensor.contact_state(force, bumps, DOT_HEIGHT_MM, diameter, contact)
    return np.clip(g[:, None] * sensor.codes_at(pads_mm, state) + offset[:, None], 0, 255)


def spread_of(X: np.ndarray, y: np.ndarray, rest_only: bool) -> np.ndarray:
    """Per channel variance ``[C]``: of the rest levels over recordings (``rest_only``), else
    of every sample about its class's mean recording (classes with >= 2 recordings)."""
    if rest_only:
        return rest_level(X).var(0, ddof=1)
    out, dof = np.zeros(X.shape[1]), 0
    for k in np.unique(y):
        xs = X[y == k]
        if len(xs) < 2:
            continue
        out += ((xs - xs.mean(0)) ** 2).sum((0, 2)) / X.shape[-1]
        dof += len(xs) - 1
    return out / max(dof, 1)


def fit_spreads(values: dict[str, float], pads_mm: np.ndarray, gain: np.ndarray,
                offset: np.ndarray, letters: str, X: np.ndarray, y: np.ndarray, fs_hz: float,
                noise: np.ndarray, defaults: dict[str, float], draws: int = 4, seed: int = 0
                ) -> tuple[dict[str, float], np.ndarray, str]:  # fmt: skip
    """The widths of :data:`SPREAD_SOURCES` whose spread matches the real recordings', and the
    per-channel level spread (counts) left over.

    The recordings' spread per channel (:func:`spread_of`: about the class means where a class
    has two or more recordings, else of the rest levels) is modelled as the sum of each
    source's variance (measured once, ``draws`` slides per letter at the source's reference
    width; a variance grows as the width squared) and the measured noise's; the squared scale
    of each width is the non-negative least-squares solution (channels weighted alike in
    relative terms), clipped at :data:`SPREAD_MAX`; a source the statistic does not see keeps
    its width in ``defaults`` (the task's)."""
    from scipy.optimize import nnls

    rest_only = not any((y == k).sum() >= 2 for k in np.unique(y))
    target = spread_of(np.asarray(X, np.float64), y, rest_only) - noise**2
    n = X.shape[-1] // DECIMATE
    fs = fs_hz / DECIMATE
    cols = []
    for j, (name, ref) in enumerate(SPREAD_SOURCES.items()):
        rng = np.random.default_rng([seed, j])
        S = np.stack([render_counts(values, pads_mm, gain, offset, letter, fs, n, {name: ref}, rng)
                      for letter in letters for _ in range(draws)])  # fmt: skip
        ys = np.repeat(np.arange(len(letters)), draws)
        cols.append(spread_of(S, ys, rest_only))
    a = np.stack(cols, 1)  # [C, sources]
    # a source that moves nothing the statistic sees (the speed, for rest levels) cannot be
    # told by it: it keeps the task's default width instead of an arbitrary solution
    seen = a.sum(0) > 1e-3 * max(float(np.maximum(target, 0.0).sum()), 1e-9)
    wt = 1.0 / (1.0 + np.sqrt(np.maximum(target, 0.0)))
    scale = np.zeros(a.shape[1])
    if seen.any():
        scale[seen], _ = nnls((a * wt[:, None])[:, seen], np.maximum(target, 0.0) * wt)
    widths = {name: float(min(np.sqrt(sc) * ref, SPREAD_MAX[name])) if ok else float(defaults[name])
              for sc, ok, (name, ref) in zip(scale, seen, SPREAD_SOURCES.items(), strict=True)}  # fmt: skip
    used = np.array([(widths[k] / ref) ** 2 if ok else 0.0
                     for ok, (k, ref) in zip(seen, SPREAD_SOURCES.items(), strict=True)])  # fmt: skip
    left = np.sqrt(np.maximum(target - a @ used, 0.0))
    return widths, left, "rest levels" if rest_only else "about the class means"


def timing_jitter_s(X: np.ndarray, y: np.ndarray, fs_hz: float) -> float | None:
    """The spread (s) of the slides' timing about their letter's mean (each slide's summed rise
    above rest aligned to the mean's by the lag that best matches it); None without two slides
    of a letter."""
    jit = []
    for k in np.unique(y):
        xs = np.asarray(X[y == k], np.float64)
        if len(xs) < 2:
            continue
        rise = (xs - rest_level(xs)[..., None]).clip(0).sum(1)  # [n, T]
        mean = rise.mean(0)
        for r in rise:
            lags = np.arange(-len(r) // 4, len(r) // 4 + 1)
            cc = [np.dot(np.roll(r, -lag), mean) for lag in lags]
            jit.append(lags[int(np.argmax(cc))] / fs_hz)
    return float(np.std(jit, ddof=1)) if len(jit) > 2 else None


def search_workers() -> int:
    """Processes the search evaluates its points on: the CPUs this process may use less those
    other processes keep busy now (:func:`~tactilesnn.core.perf.other_runnable`), 1 to 4."""
    from ...core.perf import other_runnable, usable_cpus

    return int(np.clip(usable_cpus() - (other_runnable() or 0), 1, 4))


@contextmanager
def _pool(workers: int):
    """A process pool of ``workers`` (None for one: the evaluations run here); each worker
    single-threaded, so that two workers on two CPUs do not oversubscribe them."""
    if workers <= 1:
        yield None
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from ...core.perf import limit_blas

    ctx = multiprocessing.get_context("fork" if os.name == "posix" else "spawn")
    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=limit_blas,
                             initargs=(1,)) as pool:  # fmt: skip
        yield pool


def check_known(known: dict[str, float] | None, letters: str) -> dict[str, float]:
    """``known`` (values the user measured, held fixed: name -> value in the unit of
    :data:`BOUNDS`) checked: a searched name, a finite value within its bounds."""
    bounds = bounds_for(letters)
    out = {}
    for name, v in (known or {}).items():
        if name not in bounds:
            raise ValueError(f"unknown fitted value {name!r}; values that can be held fixed: "
                             f"{', '.join(bounds)}")  # fmt: skip
        lo, hi, _ = bounds[name]
        v = float(v)
        if not (np.isfinite(v) and lo <= v <= hi):
            raise ValueError(f"{name} = {v} is outside the model's range [{lo:g}, {hi:g}]")
        out[name] = v
    if len(out) == len(bounds):
        raise ValueError("every fitted value is held fixed: nothing is left to search")
    return out


def _checked_slides(X: np.ndarray, y: np.ndarray, letters: str) -> tuple[np.ndarray, np.ndarray]:
    """``(X float64 [N, 12, samples], y int64 [N])``, refused (ValueError) unless finite, one
    label per slide in range, every letter present."""
    X = np.asarray(X, np.float64)
    if X.ndim != 3 or X.shape[1] != 12:
        raise ValueError(f"the Braille fingertip has 12 taxels: X must be [N, 12, samples], "
                         f"got {X.shape}")  # fmt: skip
    if not np.isfinite(X).all():
        raise ValueError("X holds NaN or Inf")
    y = np.asarray(y, np.int64)
    if y.shape != (len(X),) or y.min(initial=0) < 0 or y.max(initial=0) >= len(letters):
        raise ValueError(f"y must hold one label in 0..{len(letters) - 1} per recording")
    missing = [letters[k] for k in range(len(letters)) if not (y == k).any()]
    if missing:
        raise ValueError(f"no recording of letter(s) {', '.join(missing)}: each class needs one")
    return X, y


def _search(start: dict, bounds: dict, known: dict, problem: tuple, pool, optimiser: str,
            seed: int, limits: tuple[float, float, int], progress: bool) -> tuple:  # fmt: skip
    """The optimiser's rounds from ``start`` over ``bounds`` (``known`` held), each round's
    points evaluated on ``pool`` (or here), until ``limits`` (start time, seconds, evaluations)
    or the optimiser stops -> ``((loss, values, extra) of the best, evaluations, best loss per
    round)``."""
    t0, budget_s, max_evals = limits
    best: tuple = (np.inf, start, None)
    evals = 0
    history: list[float] = []
    for us in ask_tell(optimiser, _to_unit(start, bounds), seed):
        vs = [{**known, **_from_unit(np.asarray(u), bounds)} for u in us.points]
        args = [(v, *problem) for v in vs]
        done = list(pool.map(_objective, *zip(*args, strict=True)) if pool else
                    (_objective(*a) for a in args))  # fmt: skip
        for v, (loss, extra) in zip(vs, done, strict=True):
            evals += 1
            if loss < best[0]:
                best = (loss, v, extra)
        us.tell([loss for loss, _ in done])
        history.append(float(best[0]))
        elapsed = time.perf_counter() - t0
        if progress:
            log.info("calibrate: %d evaluations, best %.4f, %.0f s", evals, best[0], elapsed)
        if elapsed > budget_s or evals >= max_evals or us.done:
            break
    return best, evals, history


def fit(task: Any, X: np.ndarray, y: np.ndarray, fs_hz: float, budget_s: float = 540.0,
        max_evals: int = MAX_EVALS, seed: int = 0, progress: bool = False,
        optimiser: str = "cma", workers: int | None = None,
        known: dict[str, float] | None = None) -> SensorFit:  # fmt: skip
    """The Braille scene's fingertip fitted to slides ``X [N, 12, samples]`` of the letters
    ``task.letters[y]`` (see the module doc); stops at ``budget_s`` seconds or ``max_evals``.
    ``workers``: processes each round's points are evaluated on (default
    :func:`search_workers`); the fit is the same for any number. ``known``: values of
    :data:`BOUNDS` (or a letter's force scale) the user measured, held fixed and not searched
    (e.g. ``{"speed_mm_s": 10.07}`` from the arm's encoder: the speed trades against the
    contact's width in time, which one or two slides per letter cannot tell apart)."""
    letters = task.letters
    X, y = _checked_slides(X, y, letters)
    n = X.shape[-1]
    fs = fs_hz / DECIMATE
    n_dec = n // DECIMATE
    real_means = np.stack([X[y == k].mean(0) for k in range(len(letters))])  # [L, C, T]
    real_dec = (
        real_means[..., : n_dec * DECIMATE].reshape(len(letters), 12, n_dec, DECIMATE).mean(-1)
    )
    known = check_known(known, letters)
    cands = candidates_mm()
    bounds = {k: b for k, b in bounds_for(letters).items() if k not in known}
    start = {**start_values(task, n / fs_hz), **{f"force_scale_{c}": 1.0 for c in letters},
             **known}  # fmt: skip
    t0 = time.perf_counter()
    n_workers = search_workers() if workers is None else max(1, int(workers))
    with _pool(n_workers) as pool:
        start = pitch_start(start, letters, fs, n_dec, cands, real_dec, pool, known)
        problem = (letters, fs, n_dec, cands, real_dec)
        best, evals, history = _search(start, bounds, known, problem, pool, optimiser, seed,
                                       (t0, budget_s, max_evals), progress)  # fmt: skip
    values = best[1]
    # the layout chosen on the search's grid, then the pads' gains and offsets again as the
    # task will render them (every frame, the sensor's own quadrature)
    codes = letter_codes(values, letters, fs_hz, n)
    joined = codes.transpose(1, 0, 2).reshape(len(cands), -1)
    means = real_means.transpose(1, 0, 2).reshape(12, -1)
    pad, _, _ = place_pads(joined, means, cands)
    codes = pad_codes(values, letters, fs_hz, n, cands[pad])  # [L, C, T]
    gain, offset = fit_levels(codes.transpose(1, 0, 2).reshape(12, -1), means)
    shift = 2 ** FingertipParams().shift_bits
    real_stats = slide_statistics(X, y, fs_hz, len(letters))
    defaults = {f.name: f.default for f in fields(task)}
    widths, offset_sd, spread_on = fit_spreads(values, cands[pad], gain, offset, letters, X, y,
                                               fs_hz, real_stats["noise"], defaults, seed=seed)  # fmt: skip
    channels = {"pad_x_mm": cands[pad, 0].tolist(), "pad_y_mm": cands[pad, 1].tolist(),
                "gain": (gain * shift).tolist(), "offset": offset.tolist(),
                "noise": real_stats["noise"].tolist(), "offset_sd": offset_sd.tolist()}  # fmt: skip
    pred = _predict(codes, gain, offset)
    dist = _distances(real_means, pred)
    scene = {k: values[k] for k in ("dot_spacing_mm", "row_spacing_mm", "row_mm", "t_mid_offset_s",
                                    "speed_mm_s", "force_N", "force_ramp",
                                    *(f"force_scale_{c}" for c in letters))}  # fmt: skip
    randomisation = {**widths, "drift_counts": 0.0,
                     "time_jitter_s": timing_jitter_s(X, y, fs_hz) or 0.0}  # fmt: skip
    params = {k: values[k] for k in SENSOR_FIELDS}
    # the channels' measured noise replaces the model's; the resolution the levels were fitted at
    params.update(noise_lsb=0.0, noise_counts=0.0, grid_mm=FIT_GRID_MM, pad_rings=FIT_PAD_RINGS)
    return SensorFit(
        task="braille", sensor="capacitive_fingertip", params=params, channels=channels,
        scene=scene, randomisation=randomisation,
        objective={"value": float(best[0]), "evaluations": evals,
                   "seconds": time.perf_counter() - t0, "optimiser": OPTIMISERS[optimiser],
                   "history": history, "distances": dist, "seed": int(seed), "held_fixed": known,
                   "spreads_from": spread_on},
        fitted_on={"recordings": len(X), "per_class": np.bincount(y).tolist(),
                   "letters": letters, "fs_hz": float(fs_hz), "samples": int(n)},
    )  # fmt: skip
